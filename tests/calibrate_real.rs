//! `calibrate` on a real-depth cell built from `../shared/data/7scenes-rgbd-tsdf-fusion`: the 50 Kinect
//! frames are split between two robots, the second robot's base is moved by a known transform and each
//! robot gets its own hand-eye. The recorded camera poses are only centimetre-accurate (ICP started at the
//! true transform settles 0.2-0.3° / 2.1-2.7 cm away), so the bound is 1° / 4 cm.

mod common;
use common::*;
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::Cell;

#[test]
fn seven_scenes_cell_is_recovered() {
    let Some(data) = data("7scenes-rgbd-tsdf-fusion") else {
        return;
    };
    for (name, pick) in [
        (
            "interleaved",
            (|k: usize| k.is_multiple_of(2)) as fn(usize) -> bool,
        ),
        ("halves", |k: usize| k < 25),
    ] {
        let dir = scratch(&format!("calib-7scenes-{name}"));
        let truth = seven_scenes_cell(&data, &dir, pick);
        let cell = Cell::open(&dir).unwrap();
        let init = GlobalRegistration::default();
        let c = calibrate(&cell, &init, &CalibrateConfig::default(), &mut |_| {}).unwrap();
        let (r, t) = c.error_vs_truth.unwrap();
        let (ri, ti) = c.initial_error_vs_truth.unwrap();
        let _ = truth;
        eprintln!(
            "7-Scenes cell ({name}): initial {ri:.2} deg {:.1} mm -> {r:.3} deg, {:.1} mm; fitness {:.3}, overlap {:.3}, points {:?}, {:?}",
            ti * 1e3, t * 1e3, c.fitness.unwrap(), c.overlap.unwrap(), c.fused_points, c.timings_ms
        );
        let sigma = |k: usize| c.covariance[(k, k)].sqrt();
        eprintln!(
            "  trusted {} {:?}; 1-sigma {:.3} {:.3} {:.3} deg, {:.1} {:.1} {:.1} mm; normalised error {:?}; pose scatter {:?}",
            c.trust.trusted,
            c.trust.reasons,
            sigma(0).to_degrees(),
            sigma(1).to_degrees(),
            sigma(2).to_degrees(),
            sigma(3) * 1e3,
            sigma(4) * 1e3,
            sigma(5) * 1e3,
            c.normalised_error,
            c.pose_scatter
                .iter()
                .map(|p| (p.scatter_mm, p.scatter_deg, p.displacement_mm, p.applied))
                .collect::<Vec<_>>()
        );
        assert!(r < 1.0 && t < 0.04, "{name}: {r:.3} deg, {:.1} mm", t * 1e3);
    }
}
