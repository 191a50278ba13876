//! The `realsense` feature against a real librealsense (CI: the one inside the pyrealsense2 wheel, see
//! `.ci/setup-realsense.sh`): recordings written by librealsense's own recorder from a software device with
//! known depth, colour and intrinsics (`scripts/make_realsense_recording.py`) are imported through
//! librealsense's playback, and the cells must hold exactly those values. A ROS1 `.bag` written by librealsense
//! 2.56 is read by both readers (playback and the built-in pure-Rust one), with identical results. Capture
//! without a camera must fail with a clear message.
#![cfg(feature = "realsense")]

mod common;

use common::depthcal;

use depthcal::camera::DistortionModel;
use depthcal::cell::Cell;
use depthcal::geometry::pose::KukaPose;
use depthcal::geometry::transform::pose_error;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The recording's camera (passed to the script).
const W: u32 = 40;
const H: u32 = 30;
const FX: f32 = 33.5;
const FY: f32 = 32.25;
const PPX: f32 = 19.5;
const PPY: f32 = 14.75;
const COEFFS: [f32; 5] = [-0.0625, 0.125, -0.001, 0.002, -0.03125];
const DEPTH_UNITS: f32 = 0.0001;
const FPS: u32 = 30;

/// The script's depth formula.
fn depth_value(u: u32, v: u32, k: u32) -> u16 {
    if (u + v + k).is_multiple_of(11) {
        0
    } else {
        ((1000 + 7 * u + 13 * v + 101 * k) % 65536) as u16
    }
}

/// The script's colour formula.
fn color_value(u: u32, v: u32, k: u32) -> [u8; 3] {
    [
        ((u + k) % 256) as u8,
        ((v + 2 * k) % 256) as u8,
        ((u + v) % 256) as u8,
    ]
}

/// Writes a recording with librealsense's recorder; `env` names the variable holding the pyrealsense2 to use.
fn record(env: &str, out: &Path, frames: u32) -> serde_json::Value {
    let py = std::env::var(env).unwrap_or_else(|_| {
        panic!(
            "{env} is not set: source .ci/setup-realsense.sh before testing the realsense feature"
        )
    });
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/make_realsense_recording.py");
    let coeffs: Vec<String> = COEFFS.iter().map(|c| c.to_string()).collect();
    let o = Command::new("python3")
        .arg(&script)
        .arg(out)
        .args(["--frames", &frames.to_string()])
        .args(["--width", &W.to_string(), "--height", &H.to_string()])
        .args(["--fx", &FX.to_string(), "--fy", &FY.to_string()])
        .args(["--ppx", &PPX.to_string(), "--ppy", &PPY.to_string()])
        .args(["--model", "inverse_brown_conrady"])
        .arg(format!("--coeffs={}", coeffs.join(",")))
        .args([
            "--depth-units",
            &DEPTH_UNITS.to_string(),
            "--fps",
            &FPS.to_string(),
        ])
        .arg("--color")
        .env("DEPTHCAL_PYREALSENSE2_PATH", py)
        .output()
        .expect("run python3");
    assert!(
        o.status.success(),
        "{} failed: {}",
        script.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        summary["delivered"], frames,
        "the software device delivered every frame"
    );
    summary
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn kuka(i: usize) -> KukaPose {
    KukaPose {
        x_mm: 250.0 + 20.0 * i as f64,
        y_mm: 80.5,
        z_mm: 400.0 - 7.0 * i as f64,
        a_deg: 5.0 * i as f64,
        b_deg: -30.0,
        c_deg: 175.0,
    }
}

/// A KUKA pose file with rows `p00..`, optionally with t_s.
fn pose_file(path: &Path, n: usize, times: Option<&[f64]>) -> Vec<String> {
    let ids: Vec<String> = (0..n).map(|i| format!("p{i:02}")).collect();
    common::write_kuka_pose_file(path, &ids, times, kuka);
    ids
}

fn read_rgb(p: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(p).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    (info.width, info.height, buf)
}

/// Checks robot `robot` of `cell`: the intrinsics, and frames `ids` holding recorded frames `ks`.
fn check_cell(cell: &Path, robot: &str, ids: &[String], ks: &[u32], color: bool) {
    let cell = Cell::open(cell).unwrap();
    let r = cell.robot(robot).unwrap();
    assert_eq!(r.frames.len(), ids.len(), "frame count");
    let i = &r.intrinsics;
    assert_eq!((i.width, i.height), (W, H));
    assert_eq!(
        (i.fx, i.fy, i.ppx, i.ppy),
        (FX as f64, FY as f64, PPX as f64, PPY as f64)
    );
    assert_eq!(i.model, DistortionModel::InverseBrownConrady);
    assert_eq!(i.coeffs, COEFFS.map(|c| c as f64));
    assert_eq!(i.depth_scale, DEPTH_UNITS as f64);
    for (idx, (id, &k)) in ids.iter().zip(ks).enumerate() {
        assert_eq!(&r.frames[idx].id, id);
        let d = r.load_depth(idx).unwrap();
        for v in 0..H {
            for u in 0..W {
                assert_eq!(
                    d.get(u, v),
                    depth_value(u, v, k),
                    "{id} (recorded frame {k}) at ({u},{v})"
                );
            }
        }
        let (rot, t) = pose_error(&r.frames[idx].t_base_ee, &kuka(idx).to_isometry());
        assert!(rot < 1e-6 && t < 1e-9, "{id}: pose off by {rot} deg, {t} m");
        if color {
            let (w, h, px) = read_rgb(r.frames[idx].color_path.as_ref().unwrap());
            assert_eq!((w, h), (W, H));
            for v in 0..H {
                for u in 0..W {
                    let o = ((v * W + u) * 3) as usize;
                    assert_eq!(
                        &px[o..o + 3],
                        &color_value(u, v, k),
                        "colour of {id} at ({u},{v})"
                    );
                }
            }
        } else {
            assert!(r.frames[idx].color_path.is_none());
        }
    }
}

fn import(rec: &Path, cell: &Path, poses: &Path, extra: &[&str]) -> (i32, String, String) {
    let mut a = vec![
        "import",
        s(rec),
        s(cell),
        "--robot",
        "left",
        "--poses",
        s(poses),
        "--hand-eye",
        "identity",
    ];
    a.extend_from_slice(extra);
    depthcal(&a)
}

#[test]
fn db3_playback_imports_every_frame_exactly() {
    let dir = common::scratch("rs-db3");
    let rec = dir.join("rec.db3");
    let summary = record("DEPTHCAL_PYREALSENSE2_PATH", &rec, 5);
    assert_eq!(summary["librealsense"], "2.59.1");
    let poses = dir.join("poses.csv");
    let ids = pose_file(&poses, 5, None);
    let cell = dir.join("cell");
    let (code, out, err) = import(&rec, &cell, &poses, &["--color", "--json"]);
    assert_eq!(code, 0, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["depth_frames_in_recording"], 5);
    // librealsense's timestamps: 1000 ms + k frame periods.
    for (k, t) in report["stamps_s"].as_array().unwrap().iter().enumerate() {
        let want = 1.0 + k as f64 / FPS as f64;
        assert!((t.as_f64().unwrap() - want).abs() < 1e-6, "{t} vs {want}");
    }
    check_cell(&cell, "left", &ids, &[0, 1, 2, 3, 4], true);

    // By time: rows at frames 1 and 3 (a few ms off) take exactly those frames.
    let poses_t = dir.join("poses-t.csv");
    let t = |k: u32, ms: f64| 1.0 + k as f64 / FPS as f64 + ms * 1e-3;
    let ids_t = pose_file(&poses_t, 2, Some(&[t(1, 4.0), t(3, -6.0)]));
    let cell_t = dir.join("cell-t");
    let (code, _, err) = import(
        &rec,
        &cell_t,
        &poses_t,
        &["--match", "time", "--tolerance-ms", "10"],
    );
    assert_eq!(code, 0, "{err}");
    check_cell(&cell_t, "left", &ids_t, &[1, 3], false);

    // Count mismatch by order: the error names the pose file and the row.
    let poses_6 = dir.join("poses-6.csv");
    pose_file(&poses_6, 6, None);
    let cell_6 = dir.join("cell-6");
    let (code, _, err) = import(&rec, &cell_6, &poses_6, &[]);
    assert_eq!(code, 1);
    assert!(
        err.contains("poses-6.csv") && err.contains("line 7") && err.contains("5 depth frames"),
        "{err}"
    );
    assert!(!cell_6.exists());
    // Topic options belong to the .bag reader.
    let (code, _, err) = import(&rec, &cell_6, &poses, &["--topic", "/x"]);
    assert_eq!(code, 1);
    assert!(err.contains("--topic"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn librealsense_bag_reads_the_same_with_playback_and_the_builtin_reader() {
    let dir = common::scratch("rs-bag");
    let rec = dir.join("rec.bag");
    record("DEPTHCAL_PYREALSENSE2_BAG_PATH", &rec, 4);
    let poses = dir.join("poses.csv");
    let ids = pose_file(&poses, 4, None);
    let mut cells: Vec<PathBuf> = Vec::new();
    for reader in ["librealsense", "rosbag"] {
        let cell = dir.join(format!("cell-{reader}"));
        let (code, _, err) = import(&rec, &cell, &poses, &["--color", "--reader", reader]);
        assert_eq!(code, 0, "{reader}: {err}");
        check_cell(&cell, "left", &ids, &[0, 1, 2, 3], true);
        cells.push(cell);
    }
    // Same bytes from both readers.
    for f in [
        "left/intrinsics.json",
        "left/poses.csv",
        "left/depth/p02.png",
        "left/color/p03.png",
    ] {
        assert_eq!(
            std::fs::read(cells[0].join(f)).unwrap(),
            std::fs::read(cells[1].join(f)).unwrap(),
            "{f}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn capture_without_a_camera_says_so_and_writes_nothing() {
    let dir = common::scratch("rs-capture");
    let cell = dir.join("cell");
    let (code, _, err) = depthcal(&[
        "capture",
        s(&cell),
        "--robot",
        "left",
        "--pose",
        "100,0,500,0,90,0",
        "--hand-eye",
        "identity",
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("no RealSense camera found") && err.contains("librealsense 2.59"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert!(!cell.exists());
    // With a serial number the message names it.
    let (code, _, err) = depthcal(&[
        "capture",
        s(&cell),
        "--robot",
        "left",
        "--pose",
        "0,0,0,0,0,0",
        "--serial",
        "123456789012",
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("serial number 123456789012"), "{err}");
    // A bad pose is reported before the camera is looked for.
    let (code, _, err) = depthcal(&["capture", s(&cell), "--robot", "left", "--pose", "1,2,3"]);
    assert_eq!(code, 1);
    assert!(err.contains("--pose") && err.contains("6 numbers"), "{err}");
    // A missing recording names the file.
    let (code, _, err) = depthcal(&["import", s(&dir.join("none.db3")), "--list"]);
    assert_eq!(code, 1);
    assert!(err.contains("none.db3"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
