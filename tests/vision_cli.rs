//! The commands of the checkerboard workflow: without the `vision` feature they say so and how to build
//! it; with it, `simulate --board` → `intrinsics` → `handeye --images` → `calibrate --method checkerboard`
//! (also from the hand-eye runs' board poses) on a simulated cell, checked against its ground truth.

mod common;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_depthcal");

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(BIN).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[cfg(not(feature = "vision"))]
#[test]
fn without_the_feature_the_commands_say_how_to_get_it() {
    for args in [
        vec!["intrinsics", "a.png", "--board", "9x6", "--square", "25mm"],
        vec!["markers", "a.png", "--dict", "4x4_50"],
        vec![
            "handeye",
            "--robot-poses",
            "r.csv",
            "--images",
            "dir",
            "--board",
            "9x6",
            "--square",
            "0.025",
            "--intrinsics",
            "cam.json",
        ],
    ] {
        let (ok, _, err) = run(&args);
        assert!(!ok, "{args:?}");
        if args[0] != "handeye" {
            assert!(
                err.contains("without the `vision` feature") && err.contains("--features vision"),
                "{err}"
            );
        }
    }
    // handeye reads the robot poses first; with a real pose file it reaches the image step.
    let dir = common::scratch("vision-cli-off");
    let poses = dir.join("r.csv");
    std::fs::write(
        &poses,
        "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n0,0,0,500,0,0,0\n",
    )
    .unwrap();
    let p = poses.to_str().unwrap();
    let (ok, _, err) = run(&[
        "handeye",
        "--robot-poses",
        p,
        "--images",
        dir.to_str().unwrap(),
        "--board",
        "9x6",
        "--square",
        "0.025",
        "--intrinsics",
        "cam.json",
    ]);
    assert!(!ok && err.contains("without the `vision` feature"), "{err}");
}

#[cfg(feature = "vision")]
#[test]
fn simulate_intrinsics_handeye_and_calibrate_by_checkerboard() {
    use depthcal::cell::{Cell, GroundTruth};
    use depthcal::geometry::transform::{isometry_from_rows, pose_error};
    let dir = common::scratch("vision-cli");
    let cell_dir = dir.join("cell");
    let cfg = dir.join("sim.json");
    std::fs::write(
        &cfg,
        r#"{"frames": 12, "overlap": 1.0, "view_elevation_deg": [40, 80], "view_distance_m": [0.4, 0.75],
            "scene": {"objects": 5, "workspace_radius_m": 0.34}}"#,
    )
    .unwrap();
    let c = cell_dir.to_str().unwrap();
    let (ok, _, err) = run(&[
        "simulate",
        c,
        "--seed",
        "4",
        "--board",
        "9x6",
        "--square",
        "30mm",
        "--config",
        cfg.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let manifest = std::fs::read_to_string(cell_dir.join("cell.toml")).unwrap();
    assert!(manifest.contains("[board]") && manifest.contains("square_m = 0.03"));

    // Intrinsics from the left robot's colour images: the simulator's camera (fx = fy = 382.6, no
    // distortion), JSON readable as the cell's intrinsics.
    let images: Vec<String> = (0..12)
        .map(|k| format!("{c}/left/color/{k:03}.png"))
        .collect();
    let out_json = dir.join("cam.json");
    let mut args = vec!["intrinsics"];
    args.extend(images.iter().map(|s| s.as_str()));
    args.extend([
        "--board",
        "9x6",
        "--square",
        "0.03",
        "--no-k3",
        "--output",
        out_json.to_str().unwrap(),
        "--json",
    ]);
    let (ok, out, err) = run(&args);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["schema"], "depthcal.intrinsics/1");
    common::assert_documented(&v);
    let fx = v["fx"].as_f64().unwrap();
    assert!((fx - 382.6).abs() < 382.6 * 0.01, "fx {fx}");
    assert!(v["rms"].as_f64().unwrap() < 0.3, "{}", v["rms"]);
    assert_eq!(v["model"], "brown_conrady");
    assert_eq!(v["board"]["type"], "checkerboard");
    assert_eq!(v["views"].as_array().unwrap().len(), 12);
    assert_eq!(v["views"][0]["corners"], 54);
    assert_eq!(v["sigma"]["coeffs"].as_array().unwrap().len(), 5);
    assert_eq!(v["sigma"]["coeffs"][4], 0.0, "k3 is fixed: its 1-σ is 0");
    assert_eq!(v["config"]["estimate_k3"], false);
    let intr = depthcal::camera::Intrinsics::from_json_file(&out_json).unwrap();
    assert_eq!((intr.width, intr.height), (640, 480));
    assert_eq!(v["fx"], intr.fx, "--json holds the --output intrinsics");

    // Hand-eye from the images, with the cell's own intrinsics, for both robots.
    let cell = Cell::open(&cell_dir).unwrap();
    let gt = GroundTruth::read(&cell_dir).unwrap().unwrap();
    let mut board_poses = Vec::new();
    for (k, robot) in ["left", "right"].iter().enumerate() {
        let (ok, out, err) = run(&[
            "handeye",
            "--robot-poses",
            &format!("{c}/{robot}/poses.csv"),
            "--images",
            &format!("{c}/{robot}/color"),
            "--board",
            "9x6",
            "--square",
            "0.03",
            "--intrinsics",
            &format!("{c}/{robot}/intrinsics.json"),
            "--json",
        ]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        let rows: Vec<f64> = v["T_ee_cam"]["matrix"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|r| r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
            .collect();
        let x = isometry_from_rows(&rows.try_into().unwrap(), "T_ee_cam").unwrap();
        let (r, t) = pose_error(&x, &cell.robots[k].t_ee_cam);
        assert!(r < 0.1 && t < 1e-3, "{robot}: {r}° {} mm", t * 1e3);
        let p = dir.join(format!("he_{robot}.json"));
        std::fs::write(&p, &out).unwrap();
        board_poses.push(format!("{robot}={}", p.display()));
    }
    let truth = gt.t_base1_base2.unwrap();

    // Robot-to-robot: from the images, and from the hand-eye runs' board poses.
    for extra in [
        vec![],
        vec![
            "--board-pose",
            &board_poses[0],
            "--board-pose",
            &board_poses[1],
        ],
    ] {
        let mut args = vec!["calibrate", c, "--method", "checkerboard", "--json"];
        args.extend(extra.iter().copied());
        let (ok, out, err) = run(&args);
        assert!(ok, "{args:?}: {err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["method"], "checkerboard");
        let e = &v["initial"]["error_vs_truth"];
        let (r, t) = (
            e["rotation_deg"].as_f64().unwrap(),
            e["translation_m"].as_f64().unwrap() * 1e3,
        );
        assert!(r < 0.2 && t < 2.0, "{args:?}: initial {r}° {t} mm");
        let _ = truth;
    }

    // Bad input: a robot name that is not in the cell, and --board-pose without the method.
    let (ok, _, err) = run(&[
        "calibrate",
        c,
        "--method",
        "checkerboard",
        "--board-pose",
        "nobody=x.json",
    ]);
    assert!(!ok && err.contains("nobody"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
