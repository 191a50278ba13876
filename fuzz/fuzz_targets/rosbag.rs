#![no_main]
//! The ROS1 bag reader: the bytes as a whole bag (opened, then every depth frame read), and as a single
//! `sensor_msgs/Image` and `sensor_msgs/CameraInfo` message.
use depthcal::capture::rosbag::{BagImportConfig, BagRecording, RosCameraInfo, RosImage};
use depthcal::capture::Recording;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(img) = RosImage::decode(data) {
        let _ = img.to_depth(0.001);
        let _ = img.to_rgb();
    }
    if let Ok(ci) = RosCameraInfo::decode(data) {
        let _ = ci.to_intrinsics(0.001);
    }
    // The bag reader maps a file: write the bytes to one per process.
    let path = std::env::temp_dir().join(format!("depthcal-fuzz-{}.bag", std::process::id()));
    std::fs::write(&path, data).unwrap();
    for cfg in [
        BagImportConfig::default(),
        BagImportConfig {
            color: true,
            ..Default::default()
        },
    ] {
        match BagRecording::open(&path, &cfg) {
            Ok(mut bag) => {
                let n = bag.info().depth.frames.len() as u64;
                let nc = bag
                    .info()
                    .color
                    .as_ref()
                    .map_or(0, |c| c.frames.len() as u64);
                let d: Vec<u64> = (0..n.min(4)).collect();
                let c: Vec<u64> = (0..nc.min(4)).collect();
                let _ = bag.read_frames(&d, &c);
            }
            Err(e) => assert!(e.to_string().contains("depthcal-fuzz-"), "{e}"),
        }
    }
});
