//! `depthcal import rec.bag --tf-base B --tf-flange F`: the robot poses come from the recording's `/tf` and
//! `/tf_static` (`tf2_msgs/TFMessage`) at each depth frame's stamp. Bags written here hold a chain
//! world -> base (static) -> link1 (moving, on /tf) -> flange (static) with known poses and depth stamps
//! between the /tf samples; the imported poses must equal an independent lerp/slerp of the two nearest
//! samples. Missing frames, stamps beyond the samples and gaps are errors that name them, with nothing
//! written.

mod common;

use common::bag::*;
use common::{depthcal, listing, scratch};
use depthcal::cell::Cell;
use depthcal::geometry::transform::pose_error;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use std::path::Path;

const T0_NS: u64 = 1_700_000_100_000_000_000;
/// The /tf publishing period (10 ms).
const TF_PERIOD_NS: u64 = 10_000_000;
/// Depth frames: 5 of them, 100 ms apart, each 3.7 ms after a /tf sample.
const FRAMES: u64 = 5;

fn depth_time(k: u64) -> u64 {
    T0_NS + 50_000_000 + k * 100_000_000 + 3_700_000
}

fn secs(t_ns: u64) -> f64 {
    (t_ns / 1_000_000_000) as f64 + (t_ns % 1_000_000_000) as f64 * 1e-9
}

/// `T_base_link1` at time `t` (seconds since T0): a nonlinear motion, so that interpolating between samples
/// differs from evaluating it.
fn base_link1(t: f64) -> Isometry3<f64> {
    let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -0.2, 1.0));
    Isometry3::from_parts(
        Translation3::new(
            0.4 + 0.2 * (3.0 * t).sin(),
            -0.1 + 0.15 * t * t,
            0.6 + 0.05 * (5.0 * t).cos(),
        ),
        UnitQuaternion::from_axis_angle(&axis, 0.8 * (2.0 * t).sin())
            * UnitQuaternion::from_euler_angles(0.1 * t, 0.0, 0.0),
    )
}

fn world_base() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(2.0, -1.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 1.2),
    )
}

fn link1_flange() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.05, 0.21),
        UnitQuaternion::from_euler_angles(0.3, -0.4, 0.0),
    )
}

/// One `geometry_msgs/TransformStamped`.
fn transform(t_ns: u64, parent: &str, child: &str, t: &Isometry3<f64>) -> Vec<u8> {
    let mut v = ros_header(t_ns, parent);
    v.extend(ros_string(child));
    let (p, q) = (t.translation.vector, t.rotation.quaternion());
    for x in [p.x, p.y, p.z, q.i, q.j, q.k, q.w] {
        v.extend_from_slice(&x.to_le_bytes());
    }
    v
}

/// A `tf2_msgs/TFMessage` of several transforms.
fn tf_message(transforms: &[Vec<u8>]) -> Vec<u8> {
    let mut v = (transforms.len() as u32).to_le_bytes().to_vec();
    for t in transforms {
        v.extend_from_slice(t);
    }
    v
}

fn cam() -> Cam {
    Cam {
        w: 8,
        h: 6,
        fx: 7.0,
        fy: 7.0,
        ppx: 3.5,
        ppy: 2.5,
        model: "plumb_bob",
        d: vec![0.0; 5],
    }
}

/// What the /tf of a test bag covers.
struct Coverage {
    /// /tf samples of base -> link1 from this time (ns) ...
    from_ns: u64,
    /// ... to this one.
    to_ns: u64,
    /// No samples in this window (ns), if any.
    hole: Option<(u64, u64)>,
}

fn tf_sample_times(c: &Coverage) -> Vec<u64> {
    (0..)
        .map(|k| c.from_ns + k * TF_PERIOD_NS)
        .take_while(|&t| t <= c.to_ns)
        .filter(|t| c.hole.is_none_or(|(a, b)| *t < a || *t > b))
        .collect()
}

/// A bag with 5 depth frames, camera info, the static chain and the /tf samples of `c`.
fn write_tf_bag(path: &Path, c: &Coverage) {
    let cam = cam();
    let mut msgs = vec![msg(
        "/tf_static",
        "tf2_msgs/TFMessage",
        T0_NS,
        tf_message(&[
            transform(T0_NS, "world", "base", &world_base()),
            // An old-style leading slash names the same frame.
            transform(T0_NS, "/link1", "flange", &link1_flange()),
        ]),
    )];
    let mut events: Vec<(u64, Msg)> = Vec::new();
    for t in tf_sample_times(c) {
        let rel = (t - T0_NS) as f64 * 1e-9;
        events.push((
            t,
            msg(
                "/tf",
                "tf2_msgs/TFMessage",
                t,
                tf_message(&[
                    transform(t, "base", "link1", &base_link1(rel)),
                    // An unrelated tree in the same message.
                    transform(
                        t,
                        "odom",
                        "base_footprint",
                        &Isometry3::translation(rel, 0.0, 0.0),
                    ),
                ]),
            ),
        ));
    }
    for k in 0..FRAMES {
        let t = depth_time(k);
        let px: Vec<u8> = (0..cam.w * cam.h)
            .flat_map(|i| ((500 + i + 100 * k as u32) as u16).to_le_bytes())
            .collect();
        events.push((
            t,
            msg(
                "/camera/depth/camera_info",
                "sensor_msgs/CameraInfo",
                t,
                camera_info_msg(t, &cam),
            ),
        ));
        events.push((
            t + 1,
            msg(
                "/camera/depth/image_rect_raw",
                "sensor_msgs/Image",
                t + 1,
                image_msg(t, (cam.w, cam.h), "16UC1", false, 2, &px, 0),
            ),
        ));
    }
    events.sort_by_key(|e| e.0);
    msgs.extend(events.into_iter().map(|e| e.1));
    write_bag(path, &msgs, 16, &[Compression::None, Compression::Lz4]);
}

/// Spherical linear interpolation written out (not nalgebra's): the shorter arc from `a` to `b`.
fn slerp(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, f: f64) -> UnitQuaternion<f64> {
    let (qa, mut qb) = (a.quaternion().coords, b.quaternion().coords);
    let mut dot = qa.dot(&qb);
    if dot < 0.0 {
        qb = -qb;
        dot = -dot;
    }
    let th = dot.min(1.0).acos();
    let q = if th < 1e-12 {
        qa
    } else {
        (qa * ((1.0 - f) * th).sin() + qb * (f * th).sin()) / th.sin()
    };
    UnitQuaternion::from_quaternion(Quaternion::from(q))
}

/// `T_base_flange` at `t_ns` from the two samples around it, computed here.
fn expected(t_ns: u64, c: &Coverage) -> Isometry3<f64> {
    let ts = tf_sample_times(c);
    let i = ts.iter().rposition(|&s| s <= t_ns).unwrap();
    let (a, b) = (ts[i], ts[i + 1]);
    let f = (t_ns - a) as f64 / (b - a) as f64;
    let rel = |t: u64| (t - T0_NS) as f64 * 1e-9;
    let (pa, pb) = (base_link1(rel(a)), base_link1(rel(b)));
    let p = pa.translation.vector * (1.0 - f) + pb.translation.vector * f;
    let r = slerp(&pa.rotation, &pb.rotation, f);
    Isometry3::from_parts(Translation3::from(p), r) * link1_flange()
}

/// Stamps are seconds since the epoch in f64, which resolves 0.24 µs there: at the test motion's speed
/// (< 1 m/s, < 2 rad/s) a pose may differ from the exact interpolation by a fraction of a micrometre.
const TIME_TOL_M: f64 = 1e-6;
const TIME_TOL_DEG: f64 = 1e-4;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn full() -> Coverage {
    Coverage {
        from_ns: T0_NS,
        to_ns: T0_NS + 600_000_000,
        hole: None,
    }
}

#[test]
fn poses_from_tf_match_an_independent_interpolation() {
    let d = scratch("import-tf");
    let bag = d.join("rec.bag");
    let cov = full();
    write_tf_bag(&bag, &cov);
    // --list shows the TF edges.
    let (code, out, err) = depthcal(&["import", s(&bag), "--list"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("tf base -> link1: 61 /tf samples"), "{out}");
    assert!(out.contains("tf link1 -> flange: static"), "{out}");
    // The same as JSON: depthcal.recording/1, documented field by field.
    let (code, out, err) = depthcal(&["import", s(&bag), "--list", "--json"]);
    assert_eq!(code, 0, "{err}");
    let list: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(list["schema"], "depthcal.recording/1");
    common::assert_documented(&list);
    let edges = list["tf"].as_array().unwrap();
    let link1 = edges
        .iter()
        .find(|e| e["parent"] == "base" && e["child"] == "link1")
        .unwrap_or_else(|| panic!("no base -> link1 edge: {list}"));
    assert_eq!(link1["samples"], 61);
    assert_eq!(link1["is_static"], false);
    assert_eq!(link1["span_s"].as_array().map(Vec::len), Some(2));
    assert_eq!(
        list["depth_frames"].as_u64(),
        Some(list["depth_stamps_s"].as_array().unwrap().len() as u64)
    );
    assert!(list["color_stream"].is_null() && list["color_frames"].is_null());
    let cell = d.join("cell");
    let (code, out, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "arm",
        "--tf-base",
        "base",
        "--tf-flange",
        "/flange",
        "--hand-eye",
        "identity",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["schema"], "depthcal.import/1");
    common::assert_documented(&report);
    assert_eq!(
        report["append"]["frames"].as_array().unwrap().len(),
        FRAMES as usize
    );
    let c = Cell::open(&cell).unwrap();
    let r = c.robot("arm").unwrap();
    assert_eq!(r.frames.len(), FRAMES as usize);
    assert_eq!(r.frames[0].id, "000");
    for (k, f) in r.frames.iter().enumerate() {
        let want = expected(depth_time(k as u64), &cov);
        let (rot, tr) = pose_error(&f.t_base_ee, &want);
        assert!(
            rot < TIME_TOL_DEG && tr < TIME_TOL_M,
            "frame {k}: {rot} deg, {tr} m"
        );
        // Not the closed-form motion at the stamp (the samples are interpolated, not the function).
        let exact = base_link1(secs(depth_time(k as u64) - T0_NS)) * link1_flange();
        assert!(
            pose_error(&f.t_base_ee, &exact).1 > 5.0 * TIME_TOL_M,
            "frame {k}"
        );
        // The depth is the frame's own.
        let img = r.load_depth(k).unwrap();
        assert_eq!(img.data[0], 500 + 100 * k as u16);
    }
    // A second import appends with the next ids.
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "arm",
        "--tf-base",
        "base",
        "--tf-flange",
        "flange",
    ]);
    assert_eq!(code, 0, "{err}");
    let c = Cell::open(&cell).unwrap();
    let r = c.robot("arm").unwrap();
    assert_eq!(r.frames.len(), 2 * FRAMES as usize);
    assert_eq!(r.frames[FRAMES as usize].id, "005");
    // T_world_flange through the static world -> base edge.
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&d.join("cell2")),
        "--robot",
        "w",
        "--tf-base",
        "world",
        "--tf-flange",
        "flange",
        "--hand-eye",
        "identity",
    ]);
    assert_eq!(code, 0, "{err}");
    let c = Cell::open(d.join("cell2")).unwrap();
    let f = &c.robot("w").unwrap().frames[2];
    let want = world_base() * expected(depth_time(2), &cov);
    assert!(pose_error(&f.t_base_ee, &want).1 < TIME_TOL_M);
}

#[test]
fn missing_frames_stamps_beyond_the_samples_and_gaps_are_named() {
    let d = scratch("import-tf-errors");
    let args = |bag: &Path, cell: &Path, flange: &str| -> Vec<String> {
        [
            "import",
            s(bag),
            s(cell),
            "--robot",
            "arm",
            "--tf-base",
            "base",
            "--tf-flange",
            flange,
            "--hand-eye",
            "identity",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |a: &[String]| {
        let a: Vec<&str> = a.iter().map(|x| x.as_str()).collect();
        depthcal(&a)
    };
    let cell = d.join("cell");
    // A frame the bag does not have.
    let bag = d.join("full.bag");
    write_tf_bag(&bag, &full());
    let (code, _, err) = run(&args(&bag, &cell, "tool0"));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("\"tool0\"") && err.contains("flange, link1, odom, world"),
        "{err}"
    );
    assert!(!cell.exists());
    // /tf ends 80 ms before the last depth frame (3.7 ms after a sample): beyond the 20 ms tolerance.
    let bag = d.join("short.bag");
    let short = Coverage {
        to_ns: depth_time(FRAMES - 1) - 80_000_000,
        ..full()
    };
    write_tf_bag(&bag, &short);
    let (code, _, err) = run(&args(&bag, &cell, "flange"));
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("depth frame 5")
            && err.contains("base -> link1")
            && err.contains("after the last"),
        "{err}"
    );
    assert!(
        err.contains("83.7 ms") && err.contains("tolerance 20.0 ms"),
        "{err}"
    );
    assert!(!cell.exists());
    let mut a = args(&bag, &cell, "flange");
    a.extend(["--tf-tolerance-ms".into(), "100".into()]);
    let (code, _, err) = run(&a);
    assert_eq!(code, 0, "{err}");
    // The last frame took the last sample: held, not extrapolated.
    let c = Cell::open(&cell).unwrap();
    let last = &c.robot("arm").unwrap().frames[FRAMES as usize - 1].t_base_ee;
    let last_sample = *tf_sample_times(&short).last().unwrap();
    let held = base_link1(secs(last_sample - T0_NS)) * link1_flange();
    assert!(pose_error(last, &held).1 < 2e-9, "a sample is exact");
    // A hole in /tf around frame 3: samples 70 ms apart there, more than a 50 ms largest gap.
    let bag = d.join("hole.bag");
    let holed = Coverage {
        hole: Some((depth_time(2) - 30_000_000, depth_time(2) + 30_000_000)),
        ..full()
    };
    write_tf_bag(&bag, &holed);
    let cell = d.join("cell-hole");
    let mut a = args(&bag, &cell, "flange");
    a.extend(["--tf-max-gap-ms".into(), "50".into()]);
    let (code, _, err) = run(&a);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("depth frame 3") && err.contains("70.0 ms apart") && err.contains("(50.0 ms)"),
        "{err}"
    );
    assert!(listing(&cell).is_empty());
    // The default (250 ms) interpolates across it.
    let (code, _, err) = run(&args(&bag, &cell, "flange"));
    assert_eq!(code, 0, "{err}");
    let c = Cell::open(&cell).unwrap();
    let f = &c.robot("arm").unwrap().frames[2].t_base_ee;
    assert!(pose_error(f, &expected(depth_time(2), &holed)).1 < TIME_TOL_M);
    // A bag without TF, and flags that do not go together.
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&d.join("c3")),
        "--robot",
        "a",
        "--tf-base",
        "base",
    ]);
    assert_eq!(code, 2, "{err}");
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&d.join("c3")),
        "--robot",
        "a",
        "--tf-base",
        "base",
        "--tf-flange",
        "flange",
        "--poses",
        "p.csv",
    ]);
    assert_eq!(code, 2, "{err}");
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&d.join("c3")),
        "--robot",
        "a",
        "--tf-base",
        "base",
        "--tf-flange",
        "flange",
        "--match",
        "time",
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("--match time"), "{err}");
    assert!(!d.join("c3").exists());
}

#[test]
fn a_bag_without_tf_says_so() {
    let d = scratch("import-no-tf");
    let bag = d.join("plain.bag");
    let cam = cam();
    let px = vec![0u8; (cam.w * cam.h * 2) as usize];
    let msgs = vec![
        msg(
            "/camera/depth/camera_info",
            "sensor_msgs/CameraInfo",
            T0_NS,
            camera_info_msg(T0_NS, &cam),
        ),
        msg(
            "/camera/depth/image_rect_raw",
            "sensor_msgs/Image",
            T0_NS + 1,
            image_msg(T0_NS, (cam.w, cam.h), "16UC1", false, 2, &px, 0),
        ),
    ];
    write_bag(&bag, &msgs, 8, &[Compression::None]);
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&d.join("c")),
        "--robot",
        "a",
        "--tf-base",
        "base",
        "--tf-flange",
        "tool0",
        "--hand-eye",
        "identity",
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("no tf2_msgs/TFMessage"), "{err}");
}
