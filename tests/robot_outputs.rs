//! The robot and ROS outputs of `T_base1_base2` (ROS 2 launch file, URDF joint, TF YAML, KUKA, UR, ABB) and
//! the UR / ABB / Fanuc pose formats, each checked against an independent computation written out here;
//! and `calibrate --output DIR` end to end on the demo cell.

mod common;
use common::{depthcal, scratch};
use depthcal::cell::Cell;
use depthcal::geometry::pose::{isometry_to_xyzquat, KukaPose};
use depthcal::geometry::robot_formats::{self as rf, Frames};
use depthcal::geometry::transform::{pose_error, random_isometry};
use depthcal::geometry::Rng;
use depthcal::io::poses::{
    format_poses, parse_poses, read_poses, write_poses, PoseFormat, PoseRecord,
};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;

const DEMO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/clouds/demo-cell");

/// `Rz(z)·Ry(y)·Rx(x)` written out element by element.
fn rz_ry_rx(z: f64, y: f64, x: f64) -> Matrix3<f64> {
    let (sz, cz) = z.sin_cos();
    let (sy, cy) = y.sin_cos();
    let (sx, cx) = x.sin_cos();
    Matrix3::new(
        cz * cy,
        cz * sy * sx - sz * cx,
        cz * sy * cx + sz * sx,
        sz * cy,
        sz * sy * sx + cz * cx,
        sz * sy * cx - cz * sx,
        -sy,
        cy * sx,
        cy * cx,
    )
}

/// Rodrigues' formula for the rotation vector `r`, element by element.
fn rodrigues(r: [f64; 3]) -> Matrix3<f64> {
    let th = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if th == 0.0 {
        return Matrix3::identity();
    }
    let (x, y, z) = (r[0] / th, r[1] / th, r[2] / th);
    let (s, c) = th.sin_cos();
    let v = 1.0 - c;
    Matrix3::new(
        c + x * x * v,
        x * y * v - z * s,
        x * z * v + y * s,
        y * x * v + z * s,
        c + y * y * v,
        y * z * v - x * s,
        z * x * v - y * s,
        z * y * v + x * s,
        c + z * z * v,
    )
}

/// The rotation of the unit quaternion `w + x i + y j + z k`, element by element.
fn quat_matrix(w: f64, x: f64, y: f64, z: f64) -> Matrix3<f64> {
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

fn rot(t: &Isometry3<f64>) -> Matrix3<f64> {
    *t.rotation.to_rotation_matrix().matrix()
}

fn max_diff(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    (a - b).abs().max()
}

fn numbers(s: &str) -> Vec<f64> {
    s.split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
        .filter(|x| !x.is_empty() && x.chars().any(|c| c.is_ascii_digit()))
        .map(|x| x.parse().unwrap_or_else(|_| panic!("{x:?} in {s:?}")))
        .collect()
}

fn samples() -> Vec<Isometry3<f64>> {
    let mut rng = Rng::new(18);
    let mut v: Vec<Isometry3<f64>> = (0..200)
        .map(|_| random_isometry(&mut rng, PI, 3.0))
        .collect();
    // Gimbal lock, identity, half turns.
    v.push(Isometry3::identity());
    v.push(Isometry3::from_parts(
        Translation3::new(0.5, -0.2, 0.1),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), FRAC_PI_2),
    ));
    v.push(Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.0),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), PI),
    ));
    v
}

fn frames() -> Frames {
    Frames::new("left_base", "right_base").unwrap()
}

#[test]
fn new_pose_formats_round_trip() {
    let recs: Vec<PoseRecord> = samples()
        .into_iter()
        .enumerate()
        .map(|(i, pose)| PoseRecord {
            frame: format!("{i:03}"),
            pose,
            line: 0,
        })
        .collect();
    for f in [PoseFormat::Ur, PoseFormat::Abb, PoseFormat::Fanuc] {
        let text = format_poses(&recs, f);
        assert!(text.starts_with(&f.header()), "{f}");
        let (g, back) = parse_poses(&text, None, Path::new("p.csv")).unwrap();
        assert_eq!(g, f, "the header names the format");
        for (a, b) in recs.iter().zip(&back) {
            assert_eq!(a.frame, b.frame);
            // The matrices (a rotation angle from acos cannot resolve 1e-9 rad).
            let r = max_diff(&rot(&a.pose), &rot(&b.pose));
            let d = (a.pose.translation.vector - b.pose.translation.vector).norm();
            assert!(r < 1e-9 && d < 1e-9, "{f} frame {}: {r} {d} m", a.frame);
        }
        // Written again, the values are the same (within the rounding of the 9 decimals; a half turn
        // may read back a nanoradian short of π).
        let again = format_poses(&back, f);
        for (x, y) in text.lines().zip(again.lines()).skip(1) {
            let (a, b) = (numbers(x), numbers(y));
            assert!(
                a.iter().zip(&b).all(|(p, q)| (p - q).abs() < 2e-9),
                "{f}: {x} vs {y}"
            );
        }
        // Through files and `FromStr`.
        let d = scratch(&format!("fmt-{f}"));
        let p = d.join("poses.csv");
        write_poses(&p, &recs, f).unwrap();
        let (g, _) = read_poses(&p, Some(f.name().parse().unwrap())).unwrap();
        assert_eq!(g, f);
        let _ = std::fs::remove_dir_all(&d);
    }
    assert_eq!(
        PoseFormat::Ur.header(),
        "frame,x,y,z,rx,ry,rz",
        "documented header"
    );
    assert_eq!(PoseFormat::Abb.header(), "frame,x_mm,y_mm,z_mm,q1,q2,q3,q4");
    assert_eq!(
        PoseFormat::Fanuc.header(),
        "frame,x_mm,y_mm,z_mm,w_deg,p_deg,r_deg"
    );
}

#[test]
fn ur_rotation_vector_is_axis_times_angle() {
    let p = Path::new("ur.csv");
    // (0, 0, π/2): 90° about z maps x onto y.
    let text = format!(
        "{}\n0,0.1,0.2,0.3,0,0,{}\n",
        PoseFormat::Ur.header(),
        FRAC_PI_2
    );
    let (_, r) = parse_poses(&text, None, p).unwrap();
    let q = r[0].pose * nalgebra::Point3::new(1.0, 0.0, 0.0);
    assert!(
        (q - nalgebra::Point3::new(0.1, 1.2, 0.3)).norm() < 1e-12,
        "{q}"
    );
    // Any rotation vector against Rodrigues' formula, and the written vector back.
    let mut rng = Rng::new(3);
    for _ in 0..100 {
        let v = [
            rng.uniform(-2.0, 2.0),
            rng.uniform(-2.0, 2.0),
            rng.uniform(-2.0, 2.0),
        ];
        let text = format!(
            "{}\n0,1,2,3,{},{},{}\n",
            PoseFormat::Ur.header(),
            v[0],
            v[1],
            v[2]
        );
        let (_, r) = parse_poses(&text, None, p).unwrap();
        assert!(max_diff(&rot(&r[0].pose), &rodrigues(v)) < 1e-12);
        assert_eq!(r[0].pose.translation.vector, Vector3::new(1.0, 2.0, 3.0));
        let w = numbers(&PoseFormat::Ur.format_values(&r[0].pose));
        for k in 0..3 {
            assert!((w[3 + k] - v[k]).abs() < 1e-9, "{w:?} vs {v:?}");
        }
    }
}

#[test]
fn abb_quaternion_is_w_first_in_millimetres() {
    let p = Path::new("abb.csv");
    let mut rng = Rng::new(4);
    for _ in 0..100 {
        let mut q = [
            rng.uniform(0.0, 1.0),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
        ];
        let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        q.iter_mut().for_each(|x| *x /= n);
        let text = format!(
            "{}\n0,1000,-250,12.5,{},{},{},{}\n",
            PoseFormat::Abb.header(),
            q[0],
            q[1],
            q[2],
            q[3]
        );
        let (_, r) = parse_poses(&text, None, p).unwrap();
        assert!(max_diff(&rot(&r[0].pose), &quat_matrix(q[0], q[1], q[2], q[3])) < 1e-12);
        assert!((r[0].pose.translation.vector - Vector3::new(1.0, -0.25, 0.0125)).norm() < 1e-15);
    }
    let bad = format!("{}\n0,0,0,0,2,0,0,0\n", PoseFormat::Abb.header());
    let e = parse_poses(&bad, None, p).unwrap_err().to_string();
    assert!(e.contains("norm") && e.contains("q1"), "{e}");
}

#[test]
fn fanuc_wpr_is_fixed_axis_xyz() {
    let p = Path::new("fanuc.csv");
    let mut rng = Rng::new(5);
    for _ in 0..100 {
        let (w, pp, r) = (
            rng.uniform(-180.0, 180.0),
            rng.uniform(-89.0, 89.0),
            rng.uniform(-180.0, 180.0),
        );
        let text = format!(
            "{}\n0,100,200,300,{w},{pp},{r}\n",
            PoseFormat::Fanuc.header()
        );
        let (_, recs) = parse_poses(&text, None, p).unwrap();
        let want = rz_ry_rx(r.to_radians(), pp.to_radians(), w.to_radians());
        assert!(max_diff(&rot(&recs[0].pose), &want) < 1e-12);
        let v = numbers(&PoseFormat::Fanuc.format_values(&recs[0].pose));
        assert!((v[3] - w).abs() < 1e-8 && (v[4] - pp).abs() < 1e-8 && (v[5] - r).abs() < 1e-8);
        assert!((v[0] - 100.0).abs() < 1e-9 && (v[2] - 300.0).abs() < 1e-9);
    }
}

#[test]
fn a_cell_reads_ur_abb_and_fanuc_pose_files() {
    let d = scratch("cell-formats");
    let cell_dir = d.join("cell");
    copy_dir(Path::new(DEMO), &cell_dir);
    let original = Cell::open(DEMO).unwrap();
    for (robot, f) in [("left", PoseFormat::Ur), ("right", PoseFormat::Fanuc)] {
        let p = cell_dir.join(robot).join("poses.csv");
        let (_, recs) = read_poses(&p, None).unwrap();
        write_poses(&p, &recs, f).unwrap();
    }
    let toml = std::fs::read_to_string(cell_dir.join("cell.toml")).unwrap();
    let toml = toml.replacen("pose_format = \"kuka\"", "pose_format = \"ur\"", 1);
    let toml = toml.replacen("pose_format = \"kuka\"", "pose_format = \"fanuc\"", 1);
    std::fs::write(cell_dir.join("cell.toml"), &toml).unwrap();
    let cell = Cell::open(&cell_dir).unwrap();
    for (a, b) in original.robots.iter().zip(&cell.robots) {
        for (fa, fb) in a.frames.iter().zip(&b.frames) {
            let (r, t) = pose_error(&fa.t_base_ee, &fb.t_base_ee);
            assert!(r.to_radians() < 1e-8 && t < 1e-8, "{r} deg {t} m");
        }
    }
    // ABB too, and a mismatch between pose_format and the header is an error naming the format.
    let p = cell_dir.join("left").join("poses.csv");
    let (_, recs) = read_poses(&p, None).unwrap();
    write_poses(&p, &recs, PoseFormat::Abb).unwrap();
    let e = Cell::open(&cell_dir).unwrap_err().to_string();
    assert!(e.contains("pose format ur"), "{e}");
    std::fs::write(
        cell_dir.join("cell.toml"),
        toml.replacen("pose_format = \"ur\"", "pose_format = \"abb\"", 1),
    )
    .unwrap();
    let cell = Cell::open(&cell_dir).unwrap();
    assert_eq!(cell.frame_id("left"), "left_base");
    let _ = std::fs::remove_dir_all(&d);
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let q = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

#[test]
fn frame_ids_come_from_cell_toml_and_are_checked() {
    let d = scratch("cell-frames");
    let cell_dir = d.join("cell");
    copy_dir(Path::new(DEMO), &cell_dir);
    let toml = std::fs::read_to_string(cell_dir.join("cell.toml")).unwrap();
    let with = |frame: &str| {
        toml.replacen(
            "name = \"right\"\n",
            &format!("name = \"right\"\nframe = \"{frame}\"\n"),
            1,
        )
    };
    std::fs::write(cell_dir.join("cell.toml"), with("ur10/base_link")).unwrap();
    let cell = Cell::open(&cell_dir).unwrap();
    assert_eq!(cell.frame_id("right"), "ur10/base_link");
    assert_eq!(cell.frame_id("left"), "left_base");
    for bad in ["has space", "semi;colon", "<tag>", ""] {
        std::fs::write(cell_dir.join("cell.toml"), with(bad)).unwrap();
        let e = Cell::open(&cell_dir).unwrap_err().to_string();
        assert!(e.contains("frame"), "{bad:?}: {e}");
    }
    assert!(Frames::new("a", "a").is_err());
    assert!(Frames::new("a b", "c").is_err());
    assert!(Frames::new("world", "robot2/base_link").is_ok());
    let _ = std::fs::remove_dir_all(&d);
}

/// Tag names of `xml` opened and closed in order; panics when they do not nest.
fn check_xml_nesting(xml: &str) -> Vec<String> {
    let mut stack: Vec<String> = Vec::new();
    let mut seen = Vec::new();
    let mut rest = xml;
    while let Some(i) = rest.find('<') {
        rest = &rest[i + 1..];
        let j = rest.find('>').expect("unclosed <");
        let tag = &rest[..j];
        rest = &rest[j + 1..];
        if tag.starts_with('?') {
            assert!(tag.ends_with('?'), "{tag}");
        } else if tag.starts_with("!--") {
            assert!(tag.ends_with("--"), "{tag}");
        } else if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(stack.pop().as_deref(), Some(name.trim()), "close {name}");
        } else {
            assert_eq!(tag.matches('"').count() % 2, 0, "quotes of {tag}");
            let name = tag.split_whitespace().next().unwrap().trim_end_matches('/');
            seen.push(name.to_string());
            if !tag.ends_with('/') {
                stack.push(name.to_string());
            }
        }
    }
    assert!(stack.is_empty(), "unclosed {stack:?}");
    assert!(rest.trim().is_empty());
    seen
}

fn attr<'a>(xml: &'a str, tag: &str, name: &str) -> &'a str {
    let t = &xml[xml.find(&format!("<{tag} ")).unwrap()..];
    let t = &t[..t.find('>').unwrap()];
    let k = t.find(&format!("{name}=\"")).unwrap() + name.len() + 2;
    &t[k..k + t[k..].find('"').unwrap()]
}

#[test]
fn urdf_origin_gives_back_the_matrix() {
    let f = frames();
    for t in samples() {
        let x = rf::urdf_xacro(&t, &f);
        let tags = check_xml_nesting(&x);
        assert_eq!(tags, ["robot", "joint", "parent", "child", "origin"]);
        assert_eq!(attr(&x, "joint", "type"), "fixed");
        assert_eq!(attr(&x, "parent", "link"), "left_base");
        assert_eq!(attr(&x, "child", "link"), "right_base");
        let xyz = numbers(attr(&x, "origin", "xyz"));
        let rpy = numbers(attr(&x, "origin", "rpy"));
        assert!((Vector3::from_column_slice(&xyz) - t.translation.vector).norm() < 1e-9);
        // URDF: R = Rz(yaw)·Ry(pitch)·Rx(roll).
        let r = rz_ry_rx(rpy[2], rpy[1], rpy[0]);
        assert!(max_diff(&r, &rot(&t)) < 2e-9, "{rpy:?}");
    }
}

/// The `"--flag", "value"` pairs of a launch file's arguments.
fn launch_args(text: &str) -> HashMap<String, String> {
    let quoted: Vec<&str> = text.split('"').skip(1).step_by(2).collect();
    let mut m = HashMap::new();
    for w in quoted.windows(2) {
        if w[0].starts_with("--") {
            m.insert(w[0].to_string(), w[1].to_string());
        }
    }
    m
}

#[test]
fn launch_file_and_tf_yaml_hold_the_transform() {
    let f = frames();
    for t in samples() {
        let q = isometry_to_xyzquat(&t);
        let l = rf::ros2_launch_py(&t, &f);
        assert!(l.contains("package=\"tf2_ros\"") && l.contains("\"static_transform_publisher\""));
        assert!(l.contains("def generate_launch_description():"));
        let a = launch_args(&l);
        for (k, flag) in ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"]
            .iter()
            .enumerate()
        {
            let v: f64 = a[*flag].parse().unwrap();
            assert!((v - q[k]).abs() < 1e-9, "{flag}: {v} vs {}", q[k]);
        }
        assert_eq!(a["--frame-id"], "left_base");
        assert_eq!(a["--child-frame-id"], "right_base");
        // The YAML by hand: indentation gives the key path.
        let y = rf::tf_yaml(&t, &f);
        let mut path: Vec<(usize, String)> = Vec::new();
        let mut vals = HashMap::new();
        for line in y
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        {
            let indent = line.len() - line.trim_start().len();
            let (k, v) = line.trim().split_once(':').unwrap();
            while path.last().is_some_and(|(i, _)| *i >= indent) {
                path.pop();
            }
            let key: Vec<&str> = path.iter().map(|(_, k)| k.as_str()).chain([k]).collect();
            if v.trim().is_empty() {
                path.push((indent, k.to_string()));
            } else {
                vals.insert(key.join("."), v.trim().trim_matches('"').to_string());
            }
        }
        assert_eq!(vals["header.frame_id"], "left_base");
        assert_eq!(vals["child_frame_id"], "right_base");
        let keys = [
            "transform.translation.x",
            "transform.translation.y",
            "transform.translation.z",
            "transform.rotation.x",
            "transform.rotation.y",
            "transform.rotation.z",
            "transform.rotation.w",
        ];
        for (k, key) in keys.iter().enumerate() {
            let v: f64 = vals[*key].parse().unwrap();
            assert!((v - q[k]).abs() < 1e-9, "{key}");
        }
        assert_eq!(vals.len(), 9, "{vals:?}");
    }
}

#[test]
fn kuka_ur_and_abb_files_hold_the_transform() {
    let f = frames();
    for t in samples() {
        let k = numbers(rf::kuka_base_text(&t, &f).lines().last().unwrap());
        let want = KukaPose::from_isometry(&t);
        assert!(
            max_diff(
                &rz_ry_rx(k[3].to_radians(), k[4].to_radians(), k[5].to_radians()),
                &rot(&t)
            ) < 1e-9
        );
        assert!((k[0] - want.x_mm).abs() < 1e-6 && (k[2] - want.z_mm).abs() < 1e-6);
        let u_line = rf::ur_pose_text(&t, &f);
        let u_line = u_line.lines().last().unwrap();
        assert!(u_line.starts_with("p[") && u_line.ends_with(']'));
        let u = numbers(u_line);
        assert_eq!(u.len(), 6);
        assert!(max_diff(&rodrigues([u[3], u[4], u[5]]), &rot(&t)) < 5e-9);
        assert!((Vector3::new(u[0], u[1], u[2]) - t.translation.vector).norm() < 1e-9);
        let a_line = rf::abb_wobj_text(&t, &f);
        let a_line = a_line.lines().last().unwrap();
        assert!(a_line.starts_with("PERS wobjdata ") && a_line.ends_with("];"));
        // [FALSE, TRUE, "", [[x, y, z], [q1, q2, q3, q4]], [[0, 0, 0], [1, 0, 0, 0]]]
        let a = numbers(a_line);
        assert_eq!(a.len(), 14, "{a_line}");
        assert!(a[3] >= 0.0);
        assert!(max_diff(&quat_matrix(a[3], a[4], a[5], a[6]), &rot(&t)) < 5e-9);
        assert!((Vector3::new(a[0], a[1], a[2]) * 1e-3 - t.translation.vector).norm() < 1e-9);
        assert_eq!(&a[7..], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
        let m = numbers(&rf::matrix_text(&t));
        assert_eq!(m.len(), 16);
        let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
        assert!(max_diff(&r, &rot(&t)) < 1e-11);
    }
}

#[test]
fn calibrate_output_writes_every_file() {
    let d = scratch("calibrate-output");
    let out = d.join("out");
    let outs = out.to_str().unwrap();
    let (code, stdout, err) = depthcal(&[
        "calibrate",
        DEMO,
        "--output",
        outs,
        "--json",
        "--threads",
        "2",
        "--child-frame-id",
        "robot2/base_link",
    ]);
    assert_eq!(code, 0, "{err}");
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        [
            "T_base1_base2.txt",
            "abb_wobj.txt",
            "base_joint.urdf.xacro",
            "calibration.json",
            "cloud_other.ply",
            "cloud_reference.ply",
            "kuka_base.txt",
            "static_tf.launch.py",
            "tf.yaml",
            "ur_pose.txt",
        ]
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("calibration.json")).unwrap())
            .unwrap();
    let printed: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(
        v["transform"], printed["transform"],
        "the same JSON as --json"
    );
    assert_eq!(v["trusted"], true);
    let m = depthcal::io::read_matrix_file(out.join("T_base1_base2.txt")).unwrap();
    let rows: Vec<f64> = v["transform"]["matrix"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect();
    let mm = depthcal::geometry::transform::isometry_to_rows(&m);
    for k in 0..16 {
        assert!((mm[k] - rows[k]).abs() < 1e-11, "{k}");
    }
    let a = launch_args(&std::fs::read_to_string(out.join("static_tf.launch.py")).unwrap());
    let (xyz, q) = (&v["transform"]["xyz_m"], &v["transform"]["quaternion_xyzw"]);
    for (flag, value) in [
        ("--x", &xyz[0]),
        ("--y", &xyz[1]),
        ("--z", &xyz[2]),
        ("--qx", &q[0]),
        ("--qy", &q[1]),
        ("--qz", &q[2]),
        ("--qw", &q[3]),
    ] {
        let l: f64 = a[flag].parse().unwrap();
        assert!((l - value.as_f64().unwrap()).abs() < 1e-9, "{flag}");
    }
    assert_eq!(a["--frame-id"], "left_base");
    assert_eq!(a["--child-frame-id"], "robot2/base_link");
    // The clouds: both in the reference frame, as many points as were fused.
    let r = depthcal::io::read_cloud(out.join("cloud_reference.ply")).unwrap();
    let o = depthcal::io::read_cloud(out.join("cloud_other.ply")).unwrap();
    assert_eq!(
        r.len() as u64,
        v["fused_points"]["reference"].as_u64().unwrap()
    );
    assert_eq!(o.len() as u64, v["fused_points"]["other"].as_u64().unwrap());
    assert!(r.colors.is_some() && o.colors.is_some());
    // Refused before any work: a directory with other files, the cell itself, a file.
    std::fs::write(d.join("notes.txt"), "mine").unwrap();
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--output", d.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(
        err.contains("does not write") && err.contains("out"),
        "{err}"
    );
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--output", DEMO]);
    assert_eq!(code, 1);
    assert!(err.contains("refusing") && err.contains("holds"), "{err}");
    let (code, _, err) = depthcal(&[
        "calibrate",
        DEMO,
        "--output",
        d.join("notes.txt").to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("not a directory"), "{err}");
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--output", outs, "--frame-id", "a b"]);
    assert_eq!(code, 1);
    assert!(err.contains("frame"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn convert_writes_and_reads_ur_abb_and_fanuc() {
    let d = scratch("convert-formats");
    let src = format!("{DEMO}/left/poses.csv");
    let (_, original) = read_poses(&src, None).unwrap();
    let mut prev = src.clone();
    for to in ["ur", "abb", "fanuc", "kuka"] {
        let out = d.join(format!("{to}.csv"));
        let (code, _, err) = depthcal(&["convert", &prev, "--to", to, "-o", out.to_str().unwrap()]);
        assert_eq!(code, 0, "{err}");
        let text = std::fs::read_to_string(&out).unwrap();
        let f: PoseFormat = to.parse().unwrap();
        assert_eq!(text.lines().next().unwrap(), f.header());
        let (g, recs) = read_poses(&out, None).unwrap();
        assert_eq!(g, f);
        for (a, b) in original.iter().zip(&recs) {
            assert_eq!(a.frame, b.frame);
            assert!(max_diff(&rot(&a.pose), &rot(&b.pose)) < 1e-8);
            assert!((a.pose.translation.vector - b.pose.translation.vector).norm() < 1e-8);
        }
        prev = out.to_str().unwrap().to_string();
    }
    let (code, _, err) = depthcal(&["convert", &src, "--to", "staubli"]);
    assert_eq!(code, 2);
    assert!(err.contains("ur, abb or fanuc"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}

/// The half turn of issue 36 (a pose row `convert --to matrix` wrote from a UR pose of angle π) was read
/// as no rotation at all; through every format and back it must stay that row.
#[test]
fn convert_keeps_a_half_turn_through_every_format() {
    let d = scratch("convert-half-turn");
    // The row as the issue gives it (`frame,m00,m01,…,m33`).
    let text = "0.421964153,-0.192161107,0.886013748,0.457742764,-0.192161107,-0.974031771,\
                -0.119733949,0.200569575,0.886013748,-0.119733949,-0.447932382,0.422907741,0,0,0,1";
    let row: Vec<f64> = text.split(',').map(|v| v.parse().unwrap()).collect();
    let src = d.join("matrix.csv");
    std::fs::write(
        &src,
        format!("{}\np07,{text}\n", PoseFormat::Matrix.header()),
    )
    .unwrap();
    let mut prev = src.to_str().unwrap().to_string();
    for to in ["ur", "xyzquat", "abb", "fanuc", "kuka", "matrix"] {
        let out = d.join(format!("{to}-out.csv"));
        let (code, _, err) = depthcal(&["convert", &prev, "--to", to, "-o", out.to_str().unwrap()]);
        assert_eq!(code, 0, "{err}");
        let (_, recs) = read_poses(&out, None).unwrap();
        let angle = recs[0].pose.rotation.angle().to_degrees();
        assert!((angle - 180.0).abs() < 1e-4, "{to}: a turn of {angle}°");
        prev = out.to_str().unwrap().to_string();
    }
    let (_, back) = read_poses(&prev, None).unwrap();
    let m = back[0].pose.to_homogeneous();
    for r in 0..4 {
        for c in 0..4 {
            assert!((m[(r, c)] - row[4 * r + c]).abs() < 1e-6, "{m}");
        }
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn an_untrusted_calibration_writes_no_output() {
    let d = scratch("untrusted-output");
    let cell_dir = d.join("cell");
    copy_dir(Path::new(DEMO), &cell_dir);
    let p = cell_dir.join("right/intrinsics.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["fy"] = (v["fy"].as_f64().unwrap() * 10.0).into();
    std::fs::write(&p, v.to_string()).unwrap();
    let out = d.join("out");
    let (code, _, err) = depthcal(&[
        "calibrate",
        cell_dir.to_str().unwrap(),
        "--output",
        out.to_str().unwrap(),
        "--threads",
        "2",
    ]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("not written"), "{err}");
    assert!(!out.exists(), "an untrusted result must not be written");
    let _ = std::fs::remove_dir_all(&d);
}
