//! The image stages of the marker and 2D-feature methods (cargo feature `vision`): AprilTag detection on a
//! real photo, ArUco detection on a simulated cell image, SIFT on a 640x480 image, and matching pooled SIFT
//! descriptors of several images (what `calibrate --method features` does per robot pair).
//!
//! `cargo bench --features vision --bench vision` (set `RAYON_NUM_THREADS=2` to pin the thread count).
//! The real images come from `../shared/data`; a bench whose data is missing is skipped.

use criterion::{criterion_group, criterion_main, Criterion};
use depthcal::cell::MarkerDictionary;
use depthcal::sim::{SimCell, SimConfig, SimMarkersConfig};
use depthcal::vision::features::{detect_features, knn_match, FeatureConfig};
use depthcal::vision::markers::{detect_markers, MarkerConfig};
use depthcal::vision::{read_grey_image, GreyImage};
use std::hint::black_box;
use std::path::Path;

fn shared(rel: &str) -> Option<GreyImage> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(rel);
    p.is_file().then(|| read_grey_image(&p).unwrap())
}

/// One colour frame of a simulated cell with three 4x4_50 markers and textured objects, as grey.
fn sim_image() -> GreyImage {
    let mut cfg = SimConfig {
        seed: 3,
        frames: 2,
        ..SimConfig::default()
    };
    cfg.scene.markers = Some(SimMarkersConfig::default());
    cfg.scene.textured = true;
    let cell = SimCell::generate(&cfg).unwrap();
    let f = cell.render(0, 0).unwrap();
    let c = f.color.unwrap();
    let grey = c
        .data
        .chunks(3)
        .map(|p| (0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64).round() as u8)
        .collect();
    GreyImage::new(c.width, c.height, grey).unwrap()
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("vision");
    g.sample_size(10);
    if let Some(img) = shared("apriltag-detection-regression/34085369442_304b6bafd9_c.jpg") {
        let cfg = MarkerConfig::default();
        g.bench_function("markers/tag36h11_real_photo", |b| {
            b.iter(|| black_box(detect_markers(&img, &cfg).unwrap()))
        });
    }
    let sim = sim_image();
    let aruco = MarkerConfig {
        dictionary: MarkerDictionary::Aruco4x4_50,
        ..MarkerConfig::default()
    };
    g.bench_function("markers/aruco_4x4_sim_640x480", |b| {
        b.iter(|| black_box(detect_markers(&sim, &aruco).unwrap()))
    });
    let fcfg = FeatureConfig {
        max_features: 800,
        ..FeatureConfig::default()
    };
    g.bench_function("features/sift_sim_640x480", |b| {
        b.iter(|| black_box(detect_features(&sim, &fcfg).unwrap()))
    });
    // Pooled descriptors of ten images against ten others (~6000 x 6000).
    if let (Some(a), Some(b)) = (
        shared("opencv-graffiti-homography/graf1.png"),
        shared("opencv-graffiti-homography/graf3.png"),
    ) {
        let big = FeatureConfig {
            max_features: 6000,
            ..FeatureConfig::default()
        };
        let (fa, fb) = (
            detect_features(&a, &big).unwrap(),
            detect_features(&b, &big).unwrap(),
        );
        g.bench_function("features/knn12_sift_pooled", |bch| {
            bch.iter(|| black_box(knn_match(&fb.descriptors, &fa.descriptors, 12).unwrap()))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
