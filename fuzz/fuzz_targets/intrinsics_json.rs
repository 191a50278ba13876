#![no_main]
//! The intrinsics JSON reader; what it accepts must also build a ray table of a sane size.
use depthcal::camera::{Intrinsics, MAX_IMAGE_PIXELS};
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match Intrinsics::from_json_str(text, Path::new("fuzz/intrinsics.json")) {
        Ok(i) => {
            assert!(i.width as u64 * i.height as u64 <= MAX_IMAGE_PIXELS);
            let p = i.deproject([i.ppx, i.ppy], 1.0);
            let _ = i.project(p);
        }
        Err(e) => assert!(e.to_string().contains("fuzz/intrinsics.json"), "{e}"),
    }
});
