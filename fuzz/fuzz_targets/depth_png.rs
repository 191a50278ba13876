#![no_main]
//! The 16-bit depth PNG reader on arbitrary bytes.
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match depthcal::camera::parse_depth_png(data, "fuzz.png") {
        Ok(img) => assert_eq!(img.data.len(), img.width as usize * img.height as usize),
        Err(e) => assert!(e.to_string().contains("fuzz.png"), "{e}"),
    }
});
