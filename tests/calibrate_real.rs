//! `calibrate` on a real-depth cell built from `../shared/data/7scenes-rgbd-tsdf-fusion`: the 50 Kinect
//! frames are split between two robots, the second robot's base is moved by a known transform and each
//! robot gets its own hand-eye. The recorded camera poses are only centimetre-accurate (ICP started at the
//! true transform settles 0.2-0.3° / 2.1-2.7 cm away), so the bound is 1° / 4 cm.

mod common;
use common::*;
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::camera::Intrinsics;
use depthcal::cell::{Cell, CellManifest, GroundTruth, RobotEntry};
use depthcal::io::poses::{write_poses, PoseFormat, PoseRecord};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::path::Path;

fn iso(t: [f64; 3], rpy_deg: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        ),
    )
}

/// Writes the cell; frames with `pick(k)` go to the left robot, the others to the right one.
/// Returns the true T_base1_base2.
fn build_cell(data: &Path, dir: &Path, pick: impl Fn(usize) -> bool) -> Isometry3<f64> {
    let frames = data.join("frames");
    let ids = seven_scenes_frame_ids(&frames);
    let k: Vec<f64> = std::fs::read_to_string(data.join("camera-intrinsics.txt"))
        .unwrap()
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    Intrinsics::pinhole(640, 480, k[0], k[4], k[2], k[5])
        .write_json_file(dir.join("intrinsics.json"))
        .unwrap();
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    let robots = [
        (
            "left",
            iso([0.4, -0.2, 0.75], [0.0, 0.0, 30.0]),
            iso([0.032, -0.018, 0.105], [-3.0, 2.0, 91.0]),
        ),
        (
            "right",
            iso([-1.3, 0.9, 0.7], [0.0, 0.0, -140.0]),
            iso([-0.02, 0.05, 0.09], [1.0, 178.0, -45.0]),
        ),
    ];
    let mut m = CellManifest::new("left");
    for (r, (name, t_base_world, t_ee_cam)) in robots.iter().enumerate() {
        let mut recs = Vec::new();
        for (i, id) in ids.iter().enumerate() {
            if pick(i) != (r == 0) {
                continue;
            }
            let f = format!("frame-{id}.depth.png");
            std::fs::copy(frames.join(&f), dir.join("frames").join(&f)).unwrap();
            let t_world_cam =
                depthcal::io::read_matrix_file(frames.join(format!("frame-{id}.pose.txt")))
                    .unwrap();
            recs.push(PoseRecord {
                frame: id.clone(),
                pose: t_base_world * t_world_cam * t_ee_cam.inverse(),
                line: 0,
            });
        }
        write_poses(dir.join(format!("{name}.csv")), &recs, PoseFormat::Kuka).unwrap();
        m.robots.push(RobotEntry {
            poses: format!("{name}.csv"),
            intrinsics: "intrinsics.json".into(),
            depth: "frames/frame-{frame}.depth.png".into(),
            ..RobotEntry::standard(name, *t_ee_cam)
        });
    }
    m.write(dir).unwrap();
    let truth = robots[0].1 * robots[1].1.inverse();
    GroundTruth {
        t_base1_base2: Some(truth),
        ..Default::default()
    }
    .write(dir)
    .unwrap();
    truth
}

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
        let truth = build_cell(&data, &dir, pick);
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
        assert!(r < 1.0 && t < 0.04, "{name}: {r:.3} deg, {:.1} mm", t * 1e3);
    }
}
