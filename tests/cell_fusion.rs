//! Cell datasets and fusion on real depth data (7-Scenes, Redwood) and bad-input handling of `fuse` and
//! `convert`.
//!
//! The real-data tests need `../shared/data` beside the repository; they print a message and pass when it
//! is absent.

mod common;
#[allow(unused_imports)]
use common::{data as shared_data, iso, scratch as tmpdir, seven_scenes_frame_ids};
use depthcal::camera::{read_depth_png, DeprojectConfig, DepthImage, Intrinsics, RayTable};
use depthcal::cell::{Cell, CellManifest, HandEyeSpec, RobotEntry};
use depthcal::fusion::{
    frame_points_in_base, fuse_frames, fuse_robot, FrameInput, FuseConfig, FusedCloud,
};
use depthcal::geometry::transform::{isometry_from_rows, pose_error};
use depthcal::index::KdIndex;
use depthcal::io::poses::{write_poses, PoseFormat, PoseRecord};
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use std::path::{Path, PathBuf};
use std::process::Command;

fn read_matrix_txt(path: &Path) -> Isometry3<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    isometry_from_rows(&v[..16].try_into().unwrap(), "pose").unwrap()
}

/// Point-to-plane residuals of `query` against `reference` (with normals): for each query point whose
/// nearest reference point is within `max_dist`, `|n·(q − p)|`. Returns (median, rms, inlier fraction).
fn point_to_plane(
    reference: &depthcal::PointCloud,
    index: &KdIndex,
    query: &[[f32; 3]],
    max_dist: f32,
) -> (f64, f64, f64) {
    let normals = reference.normals.as_ref().expect("reference normals");
    let mut r: Vec<f64> = query
        .iter()
        .filter_map(|q| {
            let (i, d2) = index.nearest(q)?;
            (d2 <= max_dist * max_dist).then(|| {
                let (p, n) = (reference.points[i], normals[i]);
                (0..3)
                    .map(|k| n[k] as f64 * (q[k] - p[k]) as f64)
                    .sum::<f64>()
                    .abs()
            })
        })
        .collect();
    let frac = r.len() as f64 / query.len().max(1) as f64;
    if r.is_empty() {
        return (f64::INFINITY, f64::INFINITY, 0.0);
    }
    let rms = (r.iter().map(|x| x * x).sum::<f64>() / r.len() as f64).sqrt();
    let mid = r.len() / 2;
    let med = *r.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
    (med, rms, frac)
}

/// Point-to-plane Gauss-Newton alignment of `source` onto `target` (with normals), starting at `init`;
/// returns the refined transform mapping source coordinates into target coordinates.
fn refine_point_to_plane(
    target: &depthcal::PointCloud,
    index: &KdIndex,
    source: &[[f32; 3]],
    init: Isometry3<f64>,
    max_dist: f64,
) -> Isometry3<f64> {
    let normals = target.normals.as_ref().unwrap();
    let mut t = init;
    for _ in 0..30 {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for s in source.iter().step_by(3) {
            let q = t * nalgebra::Point3::new(s[0] as f64, s[1] as f64, s[2] as f64);
            let qf = [q.x as f32, q.y as f32, q.z as f32];
            let Some((i, d2)) = index.nearest(&qf) else {
                continue;
            };
            if (d2 as f64) > max_dist * max_dist {
                continue;
            }
            let p = target.points[i];
            let n = Vector3::new(
                normals[i][0] as f64,
                normals[i][1] as f64,
                normals[i][2] as f64,
            );
            let r = n.dot(&(q.coords - Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)));
            let j =
                Vector6::from_iterator(q.coords.cross(&n).iter().copied().chain(n.iter().copied()));
            h += j * j.transpose();
            g += j * r;
        }
        let Some(xi) = h.cholesky().map(|c| c.solve(&(-g))) else {
            break;
        };
        let d = Isometry3::from_parts(
            Translation3::new(xi[3], xi[4], xi[5]),
            UnitQuaternion::from_scaled_axis(Vector3::new(xi[0], xi[1], xi[2])),
        );
        t = d * t;
        if xi.norm() < 1e-9 {
            break;
        }
    }
    t
}

// ---------------------------------------------------------------------------------------------------------
// 7-Scenes

struct SevenScenes {
    dir: PathBuf,
    ids: Vec<String>,
    t_world_cam: Vec<Isometry3<f64>>,
    intr: Intrinsics,
}

fn seven_scenes() -> Option<SevenScenes> {
    let dir = shared_data("7scenes-rgbd-tsdf-fusion")?;
    let ids = seven_scenes_frame_ids(&dir.join("frames"));
    let t_world_cam = ids
        .iter()
        .map(|id| read_matrix_txt(&dir.join(format!("frames/frame-{id}.pose.txt"))))
        .collect();
    // camera-intrinsics.txt: K = [[585,0,320],[0,585,240],[0,0,1]], no distortion, depth in mm.
    let k: Vec<f64> = std::fs::read_to_string(dir.join("camera-intrinsics.txt"))
        .unwrap()
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    let intr = Intrinsics::pinhole(640, 480, k[0], k[4], k[2], k[5]);
    Some(SevenScenes {
        dir,
        ids,
        t_world_cam,
        intr,
    })
}

/// Robot definitions of the 7-Scenes cell: (name, T_base_world, T_ee_cam, pose format).
fn robots() -> Vec<(&'static str, Isometry3<f64>, Isometry3<f64>, PoseFormat)> {
    vec![
        (
            "left",
            iso([0.4, -0.2, 0.75], [2.0, -1.0, 30.0]),
            iso([0.032, -0.018, 0.105], [-3.0, 2.0, 91.0]),
            PoseFormat::Kuka,
        ),
        (
            "right",
            iso([-1.3, 0.9, 0.7], [-4.0, 3.0, -140.0]),
            iso([-0.02, 0.05, 0.09], [1.0, 178.0, -45.0]),
            PoseFormat::Kuka,
        ),
    ]
}

/// Builds a two-robot cell from the 7-Scenes frames: each robot's camera follows the recorded trajectory,
/// `T_base_ee = T_base_world · T_world_cam · T_ee_cam⁻¹`, written as KUKA rows. Depth PNGs are copied in.
fn build_seven_scenes_cell(s: &SevenScenes, dir: &Path) {
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    for id in &s.ids {
        let name = format!("frame-{id}.depth.png");
        std::fs::copy(
            s.dir.join("frames").join(&name),
            dir.join("frames").join(&name),
        )
        .unwrap();
    }
    s.intr.write_json_file(dir.join("intrinsics.json")).unwrap();
    let mut m = CellManifest::new("left");
    for (name, t_base_world, t_ee_cam, fmt) in robots() {
        let recs: Vec<PoseRecord> = s
            .ids
            .iter()
            .zip(&s.t_world_cam)
            .map(|(id, t)| PoseRecord {
                frame: id.clone(),
                pose: t_base_world * t * t_ee_cam.inverse(),
                line: 0,
            })
            .collect();
        write_poses(dir.join(format!("{name}.csv")), &recs, fmt).unwrap();
        m.robots.push(RobotEntry {
            poses: format!("{name}.csv"),
            intrinsics: "intrinsics.json".into(),
            depth: "frames/frame-{frame}.depth.png".into(),
            ..RobotEntry::standard(name, t_ee_cam)
        });
    }
    m.write(dir).unwrap();
}

fn load_images(s: &SevenScenes) -> Vec<DepthImage> {
    use rayon::prelude::*;
    s.ids
        .par_iter()
        .map(|id| read_depth_png(s.dir.join(format!("frames/frame-{id}.depth.png"))).unwrap())
        .collect()
}

fn index_of(c: &FusedCloud) -> KdIndex {
    KdIndex::new(&c.cloud.points)
}

#[test]
fn seven_scenes_cell_fuses_consistently_and_moves_with_the_base() {
    let Some(s) = seven_scenes() else { return };
    assert_eq!(s.ids.len(), 50);
    let dir = tmpdir("7scenes");
    build_seven_scenes_cell(&s, &dir);
    let cell = Cell::open(&dir).unwrap();
    let left = cell.robot("left").unwrap();
    assert_eq!(left.frames.len(), 50);
    // 1 cm voxels keep this test quick (~0.9 M points; 5 mm gives ~3.8 M).
    let cfg = FuseConfig {
        voxel_size_m: Some(0.01),
        ..Default::default()
    };
    let fused = fuse_robot(left, &cfg, &|_| {}).unwrap();
    let n = fused.cloud.len();
    eprintln!("7-Scenes left: {:?}", fused.stats);
    assert!(n > 100_000, "{n} points");

    // (1) Through the cell (KUKA rows, hand-eye) equals fusing with the raw poses.
    let images = load_images(&s);
    let (_, t_base_world, _, _) = robots()[0];
    let raw: Vec<FrameInput> = images
        .iter()
        .zip(&s.t_world_cam)
        .map(|(d, t)| FrameInput {
            depth: d,
            t_base_cam: t_base_world * t,
        })
        .collect();
    let vcfg = FuseConfig {
        voxel_size_m: Some(0.01),
        ..FuseConfig::voxels_only()
    };
    let direct = fuse_frames(&raw, &s.intr, &vcfg).unwrap();
    let via_cell = fuse_robot(left, &vcfg, &|_| {}).unwrap();
    let mut worst_pose = (0.0f64, 0.0f64);
    for (i, t) in s.t_world_cam.iter().enumerate() {
        let (r, d) = pose_error(&left.t_base_cam(i), &(t_base_world * t));
        worst_pose = (worst_pose.0.max(r), worst_pose.1.max(d));
    }
    eprintln!(
        "cell vs raw T_base_cam: worst {:.2e} deg, {:.2e} mm",
        worst_pose.0,
        worst_pose.1 * 1e3
    );
    assert!(worst_pose.0 < 1e-5 && worst_pose.1 < 1e-6);
    let m = via_cell.cloud.len();
    let count_diff = (direct.cloud.len() as f64 - m as f64).abs() / m as f64;
    let didx = index_of(&direct);
    let far = via_cell
        .cloud
        .points
        .iter()
        .filter(|p| didx.nearest(p).is_none_or(|(_, d2)| d2 > 1e-5 * 1e-5))
        .count();
    eprintln!(
        "cell vs raw fusion: {m} vs {} points, {far} without a twin within 0.01 mm",
        direct.cloud.len()
    );
    assert!(count_diff < 1e-3, "{count_diff}");
    assert!((far as f64) < 1e-3 * m as f64, "{far} of {m} points differ");

    // (2) Consecutive frames agree: frame i+1's points against frame i's fused cloud, point to plane.
    let rays = RayTable::new(&s.intr);
    let single = FuseConfig {
        voxel_size_m: Some(0.004),
        outlier: None,
        ..Default::default()
    };
    let mut medians = Vec::new();
    for i in [0usize, 10, 20, 30, 40] {
        let a = fuse_frames(
            &[FrameInput {
                depth: &images[i],
                t_base_cam: left.t_base_cam(i),
            }],
            &s.intr,
            &single,
        )
        .unwrap();
        let b = frame_points_in_base(
            &images[i + 1],
            &rays,
            &DeprojectConfig::default(),
            &left.t_base_cam(i + 1),
        )
        .unwrap();
        let q: Vec<[f32; 3]> = b.into_iter().step_by(5).collect();
        let (med, rms, frac) = point_to_plane(&a.cloud, &index_of(&a), &q, 0.02);
        eprintln!(
            "frames {i}->{}: median {:.2} mm, rms {:.2} mm, {:.1}% within 2 cm",
            i + 1,
            med * 1e3,
            rms * 1e3,
            frac * 100.0
        );
        assert!(
            frac > 0.6,
            "only {frac} of frame {} overlaps frame {i}",
            i + 1
        );
        assert!(
            med < 0.006,
            "frames {i}->{}: point-to-plane median {:.2} mm",
            i + 1,
            med * 1e3
        );
        medians.push(med);
        // Negative control: the inverse pose convention (world-to-camera) does not agree.
        if i == 0 {
            let wrong = frame_points_in_base(
                &images[i + 1],
                &rays,
                &DeprojectConfig::default(),
                &left.t_base_cam(i + 1).inverse(),
            )
            .unwrap();
            let q: Vec<[f32; 3]> = wrong.into_iter().step_by(5).collect();
            let (wmed, _, wfrac) = point_to_plane(&a.cloud, &index_of(&a), &q, 0.02);
            eprintln!(
                "control (inverted pose): median {:.2} mm, {:.1}% within 2 cm",
                wmed * 1e3,
                wfrac * 100.0
            );
            assert!(wfrac < 0.5 || wmed > 0.006);
        }
    }
    let mean = medians.iter().sum::<f64>() / medians.len() as f64;
    eprintln!(
        "consecutive frames: mean of point-to-plane medians {:.2} mm",
        mean * 1e3
    );
    assert!(
        mean < 0.0045,
        "consecutive-frame point-to-plane median {:.2} mm",
        mean * 1e3
    );
    // The fused cloud agrees with every 10th frame at the same level.
    let fidx = index_of(&fused);
    for i in (0..50).step_by(10) {
        let p = frame_points_in_base(
            &images[i],
            &rays,
            &DeprojectConfig::default(),
            &left.t_base_cam(i),
        )
        .unwrap();
        let q: Vec<[f32; 3]> = p.into_iter().step_by(7).collect();
        let (med, _, frac) = point_to_plane(&fused.cloud, &fidx, &q, 0.02);
        eprintln!(
            "frame {i} vs fused: median {:.2} mm, {:.1}% within 2 cm",
            med * 1e3,
            frac * 100.0
        );
        assert!(
            med < 0.005 && frac > 0.9,
            "frame {i} vs fused: median {:.2} mm, {frac}",
            med * 1e3
        );
    }

    // (3) The second robot's cloud is the first one moved by T_base2_base1.
    let right = cell.robot("right").unwrap();
    let fused2 = fuse_robot(right, &vcfg, &|_| {}).unwrap();
    let (_, t_base2_world, _, _) = robots()[1];
    let t_base1_base2 = t_base_world * t_base2_world.inverse();
    let moved: Vec<[f32; 3]> = fused2.cloud.transformed(&t_base1_base2).points;
    let (med, rms, frac) = point_to_plane(&fused.cloud, &fidx, &moved, 0.01);
    eprintln!(
        "right moved into base1 vs left: median {:.3} mm, rms {:.3} mm, {:.1}% within 1 cm",
        med * 1e3,
        rms * 1e3,
        frac * 100.0
    );
    assert!(
        med < 0.003 && frac > 0.95,
        "voxel means of the two robots disagree"
    );
    // The count-weighted centroid of the voxel means is the mean of all samples, whatever the voxel grid:
    // it must move exactly with the base.
    let weighted = |f: &FusedCloud, t: &Isometry3<f64>| {
        let mut s = Vector3::zeros();
        let mut n = 0.0;
        for (p, &c) in f.cloud.points.iter().zip(&f.counts) {
            s += (t * nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).coords
                * c as f64;
            n += c as f64;
        }
        s / n
    };
    let c1 = weighted(&via_cell, &Isometry3::identity());
    let c2 = weighted(&fused2, &t_base1_base2);
    eprintln!(
        "sample centroid difference {:.4} mm",
        (c1 - c2).norm() * 1e3
    );
    assert!((c1 - c2).norm() < 1e-5);
    // Aligning the clouds from a perturbed start recovers exactly T_base1_base2.
    let start = iso([0.01, -0.008, 0.006], [0.8, -0.6, 1.0]) * t_base1_base2;
    let est = refine_point_to_plane(&fused.cloud, &fidx, &fused2.cloud.points, start, 0.05);
    let (rdeg, dm) = pose_error(&est, &t_base1_base2);
    let (r0, d0) = pose_error(&start, &t_base1_base2);
    eprintln!(
        "T_base1_base2 from the clouds: {rdeg:.4} deg, {:.3} mm (start {r0:.2} deg, {:.1} mm)",
        dm * 1e3,
        d0 * 1e3
    );
    assert!(rdeg < 0.05 && dm < 0.0005, "{rdeg} deg {dm} m");
    let _ = std::fs::remove_dir_all(dir);
}

// ---------------------------------------------------------------------------------------------------------
// Redwood living-room1 (Open3D test data): Open3D pinhole JSON and a .log trajectory.

fn read_log(path: &Path) -> Vec<Isometry3<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    lines
        .chunks(5)
        .map(|c| {
            let v: Vec<f64> = c[1..]
                .iter()
                .flat_map(|l| l.split_whitespace().map(|s| s.parse::<f64>().unwrap()))
                .collect();
            isometry_from_rows(&v[..].try_into().unwrap(), "trajectory").unwrap()
        })
        .collect()
}

#[test]
fn redwood_frames_fuse_in_a_matrix_pose_cell() {
    let Some(src) = shared_data("open3d-redwood-livingroom1-rgbd") else {
        return;
    };
    let traj = read_log(&src.join("trajectory.log"));
    assert_eq!(traj.len(), 5);
    let dir = tmpdir("redwood");
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    for i in 0..5 {
        std::fs::copy(
            src.join(format!("depth/{i:05}.png")),
            dir.join(format!("depth/{i:05}.png")),
        )
        .unwrap();
    }
    // The Open3D intrinsics JSON is used as is.
    std::fs::copy(
        src.join("camera_primesense.json"),
        dir.join("camera_primesense.json"),
    )
    .unwrap();
    std::fs::write(
        dir.join("hand_eye.json"),
        r#"{"T_ee_cam": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#,
    )
    .unwrap();
    let recs: Vec<PoseRecord> = traj
        .iter()
        .enumerate()
        .map(|(i, t)| PoseRecord {
            frame: format!("{i:05}"),
            pose: *t,
            line: 0,
        })
        .collect();
    write_poses(dir.join("trajectory.csv"), &recs, PoseFormat::Matrix).unwrap();
    let mut m = CellManifest::new("cam");
    m.robots.push(RobotEntry {
        poses: "trajectory.csv".into(),
        pose_format: PoseFormat::Matrix,
        intrinsics: "camera_primesense.json".into(),
        hand_eye: HandEyeSpec::File("hand_eye.json".into()),
        depth: "depth/{frame}.png".into(),
        ..RobotEntry::standard("cam", Isometry3::identity())
    });
    m.write(&dir).unwrap();
    let cell = Cell::open(&dir).unwrap();
    let r = cell.robot("cam").unwrap();
    assert_eq!((r.intrinsics.fx, r.intrinsics.ppx), (525.0, 319.5));
    let fused = fuse_robot(
        r,
        &FuseConfig {
            voxel_size_m: Some(0.005),
            ..Default::default()
        },
        &|_| {},
    )
    .unwrap();
    eprintln!("Redwood: {:?}", fused.stats);
    // Frame 4 against frame 0 alone (SOURCE.md: 91% within 1 cm, RMSE 4.8 mm).
    let rays = RayTable::new(&r.intrinsics);
    let single = FuseConfig {
        voxel_size_m: Some(0.004),
        outlier: None,
        ..Default::default()
    };
    let f0 = fuse_frames(
        &[FrameInput {
            depth: &r.load_depth(0).unwrap(),
            t_base_cam: r.t_base_cam(0),
        }],
        &r.intrinsics,
        &single,
    )
    .unwrap();
    let p4 = frame_points_in_base(
        &r.load_depth(4).unwrap(),
        &rays,
        &DeprojectConfig::default(),
        &r.t_base_cam(4),
    )
    .unwrap();
    let q: Vec<[f32; 3]> = p4.into_iter().step_by(5).collect();
    let (med, rms, frac) = point_to_plane(&f0.cloud, &index_of(&f0), &q, 0.01);
    eprintln!(
        "Redwood frame 4 vs 0: median {:.2} mm, rms {:.2} mm, {:.1}% within 1 cm",
        med * 1e3,
        rms * 1e3,
        frac * 100.0
    );
    assert!(frac > 0.85 && med < 0.003);
    // And every frame agrees with the fused cloud.
    let fidx = index_of(&fused);
    for i in 0..5 {
        let p = frame_points_in_base(
            &r.load_depth(i).unwrap(),
            &rays,
            &DeprojectConfig::default(),
            &r.t_base_cam(i),
        )
        .unwrap();
        let q: Vec<[f32; 3]> = p.into_iter().step_by(7).collect();
        let (med, _, frac) = point_to_plane(&fused.cloud, &fidx, &q, 0.01);
        assert!(med < 0.003 && frac > 0.9, "frame {i}: {med} {frac}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

// ---------------------------------------------------------------------------------------------------------
// The command line on a small synthetic cell: success, and bad input (clear errors, nothing written).

const BIN: &str = env!("CARGO_BIN_EXE_depthcal");

/// A one-robot cell of 3 frames looking down at the plane z = 0 from 0.8-1.0 m (pinhole 64x48).
fn synthetic_cell(dir: &Path) {
    let intr = Intrinsics::pinhole(64, 48, 60.0, 60.0, 31.5, 23.5);
    std::fs::create_dir_all(dir.join("r/depth")).unwrap();
    intr.write_json_file(dir.join("r/intrinsics.json")).unwrap();
    let t_ee_cam = iso([0.0, 0.0, 0.1], [180.0, 0.0, 0.0]);
    let mut recs = Vec::new();
    for i in 0..3 {
        let h = 0.8 + 0.1 * i as f64;
        let mut img = DepthImage::zeros(64, 48);
        img.data.iter_mut().for_each(|d| *d = (h * 1000.0) as u16);
        depthcal::camera::write_depth_png(dir.join(format!("r/depth/{i}.png")), &img).unwrap();
        // Camera looks down (z_cam = -z_base) from height h.
        let t_base_cam = iso([0.1 * i as f64, 0.0, h], [180.0, 0.0, 0.0]);
        recs.push(PoseRecord {
            frame: i.to_string(),
            pose: t_base_cam * t_ee_cam.inverse(),
            line: 0,
        });
    }
    write_poses(dir.join("r/poses.csv"), &recs, PoseFormat::Kuka).unwrap();
    let mut m = CellManifest::new("r");
    m.robots.push(RobotEntry::standard("r", t_ee_cam));
    m.write(dir).unwrap();
}

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(BIN).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn fuse_command_writes_a_cloud_and_reports_json() {
    let dir = tmpdir("cli-ok");
    synthetic_cell(&dir);
    let out = dir.join("plane.ply");
    let (ok, stdout, stderr) = run(&[
        "fuse",
        dir.to_str().unwrap(),
        "--robot",
        "r",
        "--output",
        out.to_str().unwrap(),
        "--voxel",
        "0.01",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    common::assert_documented(&v);
    assert_eq!(v["frames"], 3);
    let cloud = depthcal::io::read_cloud(&out).unwrap();
    assert_eq!(cloud.len() as u64, v["points"].as_u64().unwrap());
    assert!(
        cloud.points.iter().all(|p| p[2].abs() < 1e-4),
        "points off the plane z = 0"
    );
    let normals = cloud.normals.expect("normals written");
    assert!(
        normals.iter().all(|n| n[2] > 0.99),
        "normals must face the cameras above"
    );
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn bad_input_gives_clear_errors_and_writes_nothing() {
    let base = tmpdir("cli-bad");
    type Breaker = fn(&Path);
    let cases: Vec<(&str, Breaker, Vec<&str>)> = vec![
        (
            "no manifest",
            |d| std::fs::remove_file(d.join("cell.toml")).unwrap(),
            vec!["cell.toml"],
        ),
        (
            "missing depth image",
            |d| std::fs::remove_file(d.join("r/depth/1.png")).unwrap(),
            vec!["r/poses.csv", "line 3", "1.png"],
        ),
        (
            "bad pose row",
            |d| {
                let t = std::fs::read_to_string(d.join("r/poses.csv")).unwrap();
                let mut lines: Vec<String> = t.lines().map(String::from).collect();
                lines[2] = "1,100.0,2.0".into();
                std::fs::write(d.join("r/poses.csv"), lines.join("\n")).unwrap();
            },
            vec!["r/poses.csv", "line 3", "columns"],
        ),
        (
            "8-bit PNG",
            |d| {
                let f = std::fs::File::create(d.join("r/depth/2.png")).unwrap();
                let mut enc = png::Encoder::new(std::io::BufWriter::new(f), 64, 48);
                enc.set_color(png::ColorType::Grayscale);
                enc.set_depth(png::BitDepth::Eight);
                enc.write_header()
                    .unwrap()
                    .write_image_data(&[200u8; 64 * 48])
                    .unwrap();
            },
            vec!["r/depth/2.png", "8-bit greyscale"],
        ),
        (
            "wrong size",
            |d| {
                depthcal::camera::write_depth_png(
                    d.join("r/depth/0.png"),
                    &DepthImage::zeros(32, 24),
                )
                .unwrap();
            },
            vec!["r/depth/0.png", "32x24", "64x48"],
        ),
        (
            "intrinsics missing a field",
            |d| {
                let t = std::fs::read_to_string(d.join("r/intrinsics.json")).unwrap();
                let t = t
                    .lines()
                    .filter(|l| !l.contains("\"fx\""))
                    .collect::<Vec<_>>()
                    .join("\n");
                std::fs::write(d.join("r/intrinsics.json"), t).unwrap();
            },
            vec!["r/intrinsics.json", "fx"],
        ),
        (
            "bad manifest field",
            |d| {
                let t = std::fs::read_to_string(d.join("cell.toml")).unwrap();
                std::fs::write(
                    d.join("cell.toml"),
                    t.replace("pose_format = \"kuka\"", "pose_format = 3"),
                )
                .unwrap();
            },
            vec!["cell.toml", "pose_format"],
        ),
    ];
    for (i, (what, breaker, wants)) in cases.into_iter().enumerate() {
        let dir = base.join(format!("case{i}"));
        std::fs::create_dir_all(&dir).unwrap();
        synthetic_cell(&dir);
        breaker(&dir);
        let out = dir.join("out.ply");
        let (ok, _, stderr) = run(&[
            "fuse",
            dir.to_str().unwrap(),
            "--output",
            out.to_str().unwrap(),
        ]);
        assert!(!ok, "{what}: fuse succeeded");
        for w in wants {
            assert!(
                stderr.contains(w),
                "{what}: error does not mention {w:?}: {stderr}"
            );
        }
        assert!(!out.exists(), "{what}: output written");
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| {
                let n = e.unwrap().file_name().into_string().unwrap();
                n.contains("out.ply").then_some(n)
            })
            .collect();
        assert!(leftovers.is_empty(), "{what}: {leftovers:?}");
    }
    // A missing cell directory.
    let (ok, _, stderr) = run(&[
        "fuse",
        base.join("nowhere").to_str().unwrap(),
        "--output",
        base.join("x.ply").to_str().unwrap(),
    ]);
    assert!(!ok && stderr.contains("nowhere"), "{stderr}");
    assert!(!base.join("x.ply").exists());
    let _ = std::fs::remove_dir_all(base);
}

#[test]
fn convert_command_round_trips_pose_files() {
    let dir = tmpdir("convert");
    let recs: Vec<PoseRecord> = (0..5)
        .map(|i| PoseRecord {
            frame: format!("f{i}"),
            pose: iso(
                [0.1 * i as f64, -0.5, 1.2],
                [10.0 * i as f64, 90.0 * (i == 2) as u8 as f64, -30.0],
            ),
            line: 0,
        })
        .collect();
    let kuka = dir.join("poses.csv");
    write_poses(&kuka, &recs, PoseFormat::Kuka).unwrap();
    let mat = dir.join("m.csv");
    let (ok, _, stderr) = run(&[
        "convert",
        kuka.to_str().unwrap(),
        "--to",
        "matrix",
        "--output",
        mat.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let (ok, quat_text, stderr) = run(&[
        "convert",
        mat.to_str().unwrap(),
        "--from",
        "matrix",
        "--to",
        "xyzquat",
    ]);
    assert!(ok, "{stderr}");
    assert!(quat_text.starts_with("frame,x,y,z,qx,qy,qz,qw\n"));
    let quat = dir.join("q.csv");
    std::fs::write(&quat, &quat_text).unwrap();
    let (ok, back_text, _) = run(&["convert", quat.to_str().unwrap(), "--to", "kuka"]);
    assert!(ok);
    let (_, back) =
        depthcal::io::poses::parse_poses(&back_text, Some(PoseFormat::Kuka), Path::new("-"))
            .unwrap();
    for (a, b) in recs.iter().zip(&back) {
        let (r, d) = pose_error(&a.pose, &b.pose);
        assert!(
            a.frame == b.frame && r < 1e-5 && d < 1e-8,
            "{}: {r} deg {d} m",
            a.frame
        );
    }
    // A bad row: error names the file and line; nothing written.
    std::fs::write(
        &kuka,
        "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n0,1,2,3,4,5,6\n1,1,2,3,4,five,6\n",
    )
    .unwrap();
    let out = dir.join("never.csv");
    let (ok, _, stderr) = run(&[
        "convert",
        kuka.to_str().unwrap(),
        "--to",
        "matrix",
        "--output",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && stderr.contains("poses.csv") && stderr.contains("line 3"),
        "{stderr}"
    );
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(dir);
}
