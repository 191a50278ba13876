//! Deprojection and voxel fusion of 50 depth frames of 640x480 (the 7-Scenes frames from `../shared/data`
//! when present, otherwise a synthetic room), and deprojection of one frame.
//!
//! `cargo bench --bench fuse` (set `RAYON_NUM_THREADS=2` to pin the thread count).

use criterion::{criterion_group, criterion_main, Criterion};
use depthcal::camera::{
    deproject, read_depth_png, DeprojectConfig, DepthImage, Intrinsics, RayTable,
};
use depthcal::fusion::{fuse_frames, FrameInput, FuseConfig};
use depthcal::geometry::transform::isometry_from_rows;
use nalgebra::{Isometry3, Point3, Vector3};
use std::hint::black_box;
use std::path::Path;

/// 50 frames with their camera poses and intrinsics.
fn frames() -> (
    Vec<DepthImage>,
    Vec<Isometry3<f64>>,
    Intrinsics,
    &'static str,
) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/7scenes-rgbd-tsdf-fusion/frames");
    let intr = Intrinsics::pinhole(640, 480, 585.0, 585.0, 320.0, 240.0);
    if dir.is_dir() {
        let mut imgs = Vec::new();
        let mut poses = Vec::new();
        for i in 0..50 {
            imgs.push(read_depth_png(dir.join(format!("frame-{:06}.depth.png", i * 10))).unwrap());
            let text =
                std::fs::read_to_string(dir.join(format!("frame-{:06}.pose.txt", i * 10))).unwrap();
            let v: Vec<f64> = text
                .split_whitespace()
                .map(|s| s.parse().unwrap())
                .collect();
            poses.push(isometry_from_rows(&v[..16].try_into().unwrap(), "pose").unwrap());
        }
        return (imgs, poses, intr, "7scenes");
    }
    // Synthetic: a 4 x 4 x 2.5 m room seen from 50 poses on a circle.
    let mut imgs = Vec::new();
    let mut poses = Vec::new();
    for i in 0..50 {
        let a = i as f64 / 50.0 * std::f64::consts::TAU;
        let eye = Point3::new(0.8 * a.cos(), 0.8 * a.sin(), 1.2);
        let t = Isometry3::face_towards(
            &eye,
            &Point3::new(2.0 * (a + 0.5).cos(), 2.0 * (a + 0.5).sin(), 0.8),
            &Vector3::z(),
        );
        let mut img = DepthImage::zeros(640, 480);
        for v in 0..480u32 {
            for u in 0..640u32 {
                let [x, y] = intr.pixel_ray([u as f64, v as f64]);
                let d = t.rotation * Vector3::new(x, y, 1.0);
                let o = t.translation.vector;
                let mut best = f64::INFINITY;
                for k in 0..3 {
                    for wall in [-2.0, 2.0] {
                        let wall = if k == 2 { (wall + 2.0) * 0.625 } else { wall };
                        if d[k].abs() > 1e-9 {
                            let s = (wall - o[k]) / d[k];
                            if s > 0.0 && s < best {
                                best = s;
                            }
                        }
                    }
                }
                img.data[(v * 640 + u) as usize] = (best * 1000.0).round().min(65535.0) as u16;
            }
        }
        imgs.push(img);
        poses.push(t);
    }
    (imgs, poses, intr, "synthetic")
}

fn bench(c: &mut Criterion) {
    let (imgs, poses, intr, source) = frames();
    let inputs: Vec<FrameInput> = imgs
        .iter()
        .zip(&poses)
        .map(|(d, t)| FrameInput {
            depth: d,
            t_base_cam: *t,
        })
        .collect();
    let mut g = c.benchmark_group(format!("fuse_{source}_50x640x480"));
    g.sample_size(10);
    for (name, voxel) in [("auto_voxel", None), ("voxel_10mm", Some(0.01))] {
        let cfg = FuseConfig {
            voxel_size_m: voxel,
            ..FuseConfig::voxels_only()
        };
        g.bench_function(format!("deproject+voxel_fusion/{name}"), |b| {
            b.iter(|| black_box(fuse_frames(&inputs, &intr, &cfg).unwrap().cloud.len()))
        });
    }
    g.finish();
    let rays = RayTable::new(&intr);
    c.bench_function("deproject_one_frame_640x480", |b| {
        b.iter(|| {
            black_box(
                deproject(&imgs[0], &rays, &DeprojectConfig::default())
                    .unwrap()
                    .len(),
            )
        })
    });
}

/// The cell stages of `calibrate` on the demo cell: fusing one robot as `calibrate` does (surface
/// projection, depth views), the free-space test of one hypothesis, both robots' consistency and
/// hand-eye checks.
fn cell(c: &mut Criterion) {
    use depthcal::calibration::robot_to_robot::CalibrateConfig;
    use depthcal::calibration::visibility::{free_space_violation, RobotSight, VisibilityConfig};
    use depthcal::cell::{Cell, GroundTruth};
    use depthcal::fusion::fuse_robot;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds/demo-cell");
    let cell = Cell::open(&dir).unwrap();
    let truth = GroundTruth::read(&dir)
        .unwrap()
        .and_then(|g| g.t_base1_base2)
        .unwrap();
    let fcfg = CalibrateConfig::default().fuse;
    let mut g = c.benchmark_group("demo_cell");
    g.sample_size(10);
    g.bench_function("fuse_robot_as_calibrate", |b| {
        b.iter(|| {
            black_box(
                fuse_robot(&cell.robots[0], &fcfg, &|_| {})
                    .unwrap()
                    .cloud
                    .len(),
            )
        })
    });
    let a = fuse_robot(&cell.robots[0], &fcfg, &|_| {}).unwrap();
    let o = fuse_robot(&cell.robots[1], &fcfg, &|_| {}).unwrap();
    let vcfg = VisibilityConfig::default();
    let (sa, so) = (a.sight_directions(), o.sight_directions());
    let (ra, ro) = (RobotSight::of(&a, &sa), RobotSight::of(&o, &so));
    g.bench_function("free_space_violation", |b| {
        b.iter(|| black_box(free_space_violation(&ra, &ro, &truth, &vcfg)))
    });
    // What the global stage's prior sees: many hypotheses, each landing the points on other blocks (a
    // fixed spread of up to ±0.3 m and ±29° of yaw about the truth; the same 100 every run).
    let hypotheses: Vec<Isometry3<f64>> = (0..100)
        .map(|k| {
            let f = |m: u64| ((k as u64 * m + 17) % 101) as f64 / 100.0 - 0.5;
            Isometry3::new(
                Vector3::new(0.6 * f(37), 0.6 * f(59), 0.1 * f(71)),
                Vector3::new(0.05 * f(13), 0.05 * f(29), f(43)),
            ) * truth
        })
        .collect();
    g.bench_function("free_space_violation_100_hypotheses", |b| {
        b.iter(|| {
            hypotheses
                .iter()
                .map(|h| free_space_violation(&ra, &ro, h, &vcfg))
                .sum::<f64>()
        })
    });
    use depthcal::calibration::consistency::{robot_consistency, ConsistencyConfig};
    let ccfg = ConsistencyConfig::default();
    g.bench_function("robot_consistency_both", |b| {
        b.iter(|| {
            black_box(robot_consistency(&cell.robots[0], &a, &ccfg).consistent)
                & black_box(robot_consistency(&cell.robots[1], &o, &ccfg).consistent)
        })
    });
    use depthcal::calibration::handeye::depth::check::{check_hand_eye, HandEyeCheckConfig};
    let hcfg = HandEyeCheckConfig::default();
    g.bench_function("hand_eye_check_both", |b| {
        b.iter(|| {
            black_box(
                check_hand_eye(&cell.robots[0], Some(&a.views), &hcfg)
                    .unwrap()
                    .consistent,
            ) & black_box(
                check_hand_eye(&cell.robots[1], Some(&o.views), &hcfg)
                    .unwrap()
                    .consistent,
            )
        })
    });
    use depthcal::calibration::pose_scatter::{estimate_pose_scatter, PoseScatterConfig};
    let scfg = PoseScatterConfig::default();
    g.bench_function("pose_scatter_both", |b| {
        b.iter(|| {
            black_box(
                estimate_pose_scatter(&cell.robots[0], &a.views, &scfg)
                    .unwrap()
                    .scatter_mm,
            ) + black_box(
                estimate_pose_scatter(&cell.robots[1], &o.views, &scfg)
                    .unwrap()
                    .scatter_mm,
            )
        })
    });
    g.finish();
}

criterion_group!(benches, bench, cell);
criterion_main!(benches);
