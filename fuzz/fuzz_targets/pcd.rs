#![no_main]
//! The .pcd reader on arbitrary bytes: a cloud or an error naming the file, never a panic or a huge allocation.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(e) = depthcal::io::parse_cloud(data, "fuzz.pcd") {
        assert!(e.to_string().contains("fuzz.pcd"), "{e}");
    }
});
