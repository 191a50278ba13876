#![no_main]
//! The 4x4 transform reader (text, JSON array, `--json` output).
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(t) = depthcal::io::parse_matrix(text, "fuzz/T.txt") {
        assert!(t.to_homogeneous().iter().all(|v| v.is_finite()));
    }
});
