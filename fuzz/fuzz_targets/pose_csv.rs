#![no_main]
//! The pose CSV reader (format from the header, and each format forced).
use depthcal::io::poses::{parse_poses, PoseFormat};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz/poses.csv");
    for f in [
        None,
        Some(PoseFormat::Kuka),
        Some(PoseFormat::Matrix),
        Some(PoseFormat::Xyzquat),
    ] {
        match parse_poses(text, f, path) {
            Ok((_, rows)) => {
                for r in rows {
                    assert!(r.pose.translation.vector.iter().all(|v| v.is_finite()));
                    assert!(r.pose.rotation.coords.iter().all(|v| v.is_finite()));
                }
            }
            Err(e) => assert!(e.to_string().contains("fuzz/poses.csv"), "{e}"),
        }
    }
});
