//! Shared helpers of the integration tests: the shared data folder, ground-truth files, error checks.
#![allow(dead_code)]

use depthcal::camera::Intrinsics;
use depthcal::cell::{CellManifest, GroundTruth, RobotEntry};
use depthcal::geometry::transform::{pose_error, random_isometry};
use depthcal::geometry::Rng;
use depthcal::io::poses::{write_poses, PoseFormat, PoseRecord};
use depthcal::registration::{register, RegisterConfig, Registration};
use depthcal::PointCloud;
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use std::path::{Path, PathBuf};

/// `../shared/data/NAME` if present; prints a skip message and returns `None` otherwise.
pub fn data(name: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(name);
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!(
            "SKIP: {} not found (the shared data sits beside the repository)",
            p.display()
        );
        None
    }
}

/// Reads a 4x4 text matrix.
pub fn matrix(path: &std::path::Path) -> Isometry3<f64> {
    depthcal::io::read_matrix_file(path).unwrap()
}

/// Registers `source` moved by a seeded random transform `P` (rotation up to `max_deg`, translation up to
/// `max_t` per axis) onto `target`; returns the errors against `truth` (which maps the unmoved source into
/// the target) in degrees and cloud units, and the registration.
///
/// The errors are those of `T_est · P` against `truth`, i.e. measured in the original source frame as the
/// 3DMatch benchmark does (`E = T_gt⁻¹ · T_est`). Comparing `T_est` with `truth · P⁻¹` directly would add
/// the rotation error times the distance by which `P` moved the frame origin to the translation error.
pub fn perturbed_errors(
    source: &PointCloud,
    target: &PointCloud,
    truth: &Isometry3<f64>,
    seed: u64,
    max_deg: f64,
    max_t: f64,
    cfg: &RegisterConfig,
) -> (f64, f64, Registration) {
    let p = perturbation(seed, max_deg, max_t);
    let moved = source.transformed(&p);
    let reg = register(&moved, target, None, cfg).unwrap();
    let (r, t) = pose_error(&(reg.transform * p), truth);
    (r, t, reg)
}

/// The seeded random transform `P` of [`perturbed_errors`]: the registration of `source` moved by it
/// estimates `truth · P⁻¹`.
pub fn perturbation(seed: u64, max_deg: f64, max_t: f64) -> Isometry3<f64> {
    random_isometry(&mut Rng::new(seed), max_deg.to_radians(), max_t)
}

#[allow(unused_imports)]
pub use depthcal::sim::{demo_scene as synthetic_scene, split_overlapping};

/// A scratch directory for one test (removed first if it exists).
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("depthcal-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The frame ids (`000000`, `000010`, ...) of the 7-Scenes frames in `frames_dir`, sorted.
pub fn seven_scenes_frame_ids(frames_dir: &std::path::Path) -> Vec<String> {
    let mut ids: Vec<String> = std::fs::read_dir(frames_dir)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().into_string().unwrap();
            n.strip_suffix(".depth.png")
                .map(|s| s.trim_start_matches("frame-").to_string())
        })
        .collect();
    ids.sort();
    ids
}

/// Runs the `depthcal` binary with `args`; returns the exit code, stdout and stderr. `DEPTHCAL_BIN=PATH`
/// runs that binary instead of the one cargo built (e.g. a copy pinned for a long sweep while the shared
/// target directory is rebuilt).
pub fn depthcal(args: &[&str]) -> (i32, String, String) {
    let bin = std::env::var_os("DEPTHCAL_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_depthcal")));
    let out = std::process::Command::new(bin)
        .args(args)
        .output()
        .expect("run depthcal");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Every file below `dir` with its bytes, sorted by path (empty when `dir` does not exist): a snapshot to
/// check that a failed command wrote nothing.
pub fn listing(dir: &std::path::Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    if !dir.exists() {
        return out;
    }
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Writes a KUKA pose file (`frame[,t_s],x_mm,...,c_deg`) with one row per id: the pose `pose(i)` and, when
/// given, the time `times[i]` (seconds).
pub fn write_kuka_pose_file(
    path: &std::path::Path,
    ids: &[String],
    times: Option<&[f64]>,
    pose: impl Fn(usize) -> depthcal::geometry::pose::KukaPose,
) {
    let mut s = String::from("frame,");
    if times.is_some() {
        s.push_str("t_s,");
    }
    s.push_str("x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n");
    for (i, id) in ids.iter().enumerate() {
        let p = pose(i);
        s.push_str(id);
        if let Some(t) = times {
            s.push_str(&format!(",{:.9}", t[i]));
        }
        s.push_str(&format!(
            ",{},{},{},{},{},{}\n",
            p.x_mm, p.y_mm, p.z_mm, p.a_deg, p.b_deg, p.c_deg
        ));
    }
    std::fs::write(path, s).unwrap();
}
pub mod bag;
pub mod foreign;
pub mod outcome;

/// Checks that every top-level field of a report `v` is listed in docs/json.md's section of its schema
/// (the `schema` field), and that the section lists no field the report lacks.
pub fn assert_documented(v: &serde_json::Value) {
    let schema = v["schema"].as_str().expect("a report names its schema");
    assert_documented_section(v, schema, "");
}

/// [`assert_documented`] for an object documented in its own section of docs/json.md, `## \`SCHEMA\`
/// SUFFIX` (e.g. the entries of a list inside a report).
pub fn assert_documented_section(v: &serde_json::Value, schema: &str, suffix: &str) {
    let doc =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/json.md"))
            .unwrap();
    let head = format!("## `{schema}`{suffix}");
    let start = doc
        .find(&head)
        .unwrap_or_else(|| panic!("docs/json.md has no {head}"));
    let section = &doc[start + head.len()..];
    let section = &section[..section.find("\n## ").unwrap_or(section.len())];
    let fields: std::collections::BTreeSet<String> = v
        .as_object()
        .expect("a JSON object")
        .keys()
        .cloned()
        .collect();
    let mut listed = std::collections::BTreeSet::new();
    for line in section.lines().filter(|l| l.starts_with("| `")) {
        let first = line.split('|').nth(1).unwrap_or("");
        let names: Vec<String> = first
            .split('`')
            .skip(1)
            .step_by(2)
            .map(String::from)
            .collect();
        // A row whose fields are all missing must say when they are absent.
        assert!(
            names.iter().any(|n| fields.contains(n)) || line.contains("absent"),
            "{schema}: docs/json.md lists fields the report lacks: {names:?}"
        );
        listed.extend(names);
    }
    let undocumented: Vec<_> = fields.difference(&listed).collect();
    assert!(
        undocumented.is_empty(),
        "{schema}: not in docs/json.md: {undocumented:?}"
    );
}

/// A pose file of ROS-Industrial's `industrial_calibration` example data (`x:`, `y:`, `z:`, `qx:` … `qw:`
/// lines; metres, Hamilton quaternion).
pub fn industrial_pose(path: &std::path::Path) -> Isometry3<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    let get = |k: &str| -> f64 {
        text.lines()
            .find_map(|l| l.strip_prefix(&format!("{k}:")))
            .unwrap_or_else(|| panic!("{}: no {k}", path.display()))
            .trim()
            .parse()
            .unwrap()
    };
    depthcal::geometry::pose::xyzquat_to_isometry(&[
        get("x"),
        get("y"),
        get("z"),
        get("qx"),
        get("qy"),
        get("qz"),
        get("qw"),
    ])
    .unwrap()
}

/// A pose from a translation (metres) and roll, pitch, yaw (degrees).
pub fn iso(t: [f64; 3], rpy_deg: [f64; 3]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians(),
        ),
    )
}

/// Writes a two-robot cell from the 7-Scenes frames of `data` into `dir`: frames with `pick(k)` go to the
/// left robot, the others to the right one, each with its own base and hand-eye (cell.toml without
/// priors, ground_truth.json). Returns the true T_base1_base2.
pub fn seven_scenes_cell(data: &Path, dir: &Path, pick: impl Fn(usize) -> bool) -> Isometry3<f64> {
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
