#![no_main]
//! The cell manifest (`cell.toml`) reader, and what it writes back must read again.
use depthcal::cell::CellManifest;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz/cell.toml");
    match CellManifest::from_toml_str(text, path) {
        Ok(m) => {
            let _ = m.validate();
            if let Ok(t) = m.to_toml_string() {
                let _ = CellManifest::from_toml_str(&t, path);
            }
        }
        Err(e) => assert!(e.to_string().contains("fuzz/cell.toml"), "{e}"),
    }
});
