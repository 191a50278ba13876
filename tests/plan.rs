//! `depthcal plan`: the weak degrees of freedom of each hand-eye and of `T_base1_base2`, and the flange
//! poses that would constrain them, on simulated cells with a degenerate and a good pose set; its JSON is
//! documented and a bad plan configuration is an error naming the file and field.

mod common;
use common::*;
use depthcal::sim::{SimCell, SimConfig};
use nalgebra::{Isometry3, Vector3};

/// A small simulated cell (no colour) whose first robot only turns its flange about one axis.
fn one_axis_cell(name: &str) -> std::path::PathBuf {
    let dir = scratch(name);
    let mut cell = SimCell::generate(&SimConfig {
        seed: 5,
        frames: 8,
        color: false,
        ..SimConfig::default()
    })
    .unwrap();
    let r = &mut cell.robots[0];
    let p0 = r.poses[0].pose;
    let n = r.poses.len();
    for (k, rec) in r.poses.iter_mut().enumerate() {
        let f = k as f64 / (n - 1) as f64 - 0.5;
        let shift = Isometry3::translation(0.06 * f, -0.04 * f * f, 0.03 * f);
        rec.pose =
            shift * p0 * Isometry3::rotation(Vector3::new(0.0, 0.0, (70.0 * f).to_radians()));
    }
    cell.write(&dir, &|_| {}).unwrap();
    dir
}

/// Runs `depthcal ARGS` (with `--json`): the documented report; the exit status is 0 for a trusted
/// calibration and 3 for an untrusted one.
fn plan_json(args: &[&str]) -> serde_json::Value {
    let (code, out, err) = depthcal(args);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap_or_else(|_| panic!("{err}"));
    assert_documented(&v);
    let trusted = v["calibration_trusted"] == true;
    assert_eq!(code, if trusted { 0 } else { 3 }, "{err}");
    v
}

#[test]
fn plan_names_the_weak_directions_and_proposes_poses_that_lower_them() {
    let dir = one_axis_cell("plan-one-axis");
    let d = dir.display().to_string();
    // A base-to-base limit below what the registration reaches, so that it has weak directions to plan for.
    let pc = dir.join("plan.json");
    std::fs::write(&pc, r#"{"weak_sigma_mm": 0.05}"#).unwrap();
    let p = pc.display().to_string();
    let v = plan_json(&["plan", &d, "--json", "--plan-config", &p, "--count", "3"]);
    let he = v["hand_eyes"].as_array().unwrap();
    assert_eq!(he.len(), 2);
    let status = |h: &serde_json::Value, dof: &str| {
        h["dofs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["dof"] == dof)
            .unwrap()["status"]
            .as_str()
            .unwrap()
            .to_string()
    };
    // The robot that only turned about its flange z: the translation along it is free, poses proposed.
    assert_ne!(status(&he[0], "tz"), "observable", "{}", he[0]);
    assert!(!he[0]["suggested_poses"].as_array().unwrap().is_empty());
    // The other robot's poses determine its hand-eye.
    for dof in ["rx", "ry", "rz", "tx", "ty", "tz"] {
        assert_eq!(status(&he[1], dof), "observable", "{}", he[1]);
    }
    // Base-to-base: below the limit given, the registration's directions are weak.
    let base = v["base_sigma_mm"].as_f64().unwrap();
    assert!(base > 0.05, "{base}");
    assert!(!v["base_weak_directions"].as_array().unwrap().is_empty());
    // The text says the same.
    let (_, text, _) = depthcal(&["plan", &d, "--plan-config", &p, "--count", "3"]);
    assert!(text.contains("hand-eye left     weak:"), "{text}");
    assert!(text.contains("base-to-base  largest 1-sigma"), "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The 7-Scenes real-depth cell (centimetre poses): the base-to-base transform has weak directions, and
/// each proposed pose sees part of the scene only the other robot saw and lowers the predicted 1-σ.
#[test]
fn seven_scenes_base_to_base_gets_poses_that_share_more_of_the_scene() {
    let Some(data) = data("7scenes-rgbd-tsdf-fusion") else {
        return;
    };
    let dir = scratch("plan-7scenes");
    seven_scenes_cell(&data, &dir, |k| k % 2 == 0);
    let v = plan_json(&["plan", &dir.display().to_string(), "--json"]);
    let base = v["base_sigma_mm"].as_f64().unwrap();
    let weak = v["base_weak_directions"].as_array().unwrap();
    eprintln!("7-Scenes: largest 1-σ {base:.3} mm, weak {weak:?}");
    assert!(!weak.is_empty(), "{base}");
    let poses = v["base_suggested_poses"].as_array().unwrap();
    assert!(!poses.is_empty() && poses.len() <= 4, "{poses:?}");
    let mut last = base;
    for s in poses {
        eprintln!("  {s}");
        let p = s["predicted_sigma_mm"].as_f64().unwrap();
        assert!(p < last, "{s}");
        assert!(s["new_shared_points"].as_u64().unwrap() > 0, "{s}");
        last = p;
    }
    // Each robot's 25 frames leave some of its hand-eye weak under centimetre poses: said, with poses.
    for h in v["hand_eyes"].as_array().unwrap() {
        assert!(!h["weak_directions"].as_array().unwrap().is_empty(), "{h}");
        assert!(!h["suggested_poses"].as_array().unwrap().is_empty(), "{h}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plan_of_the_demo_cell_and_bad_plan_configurations() {
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/clouds/demo-cell");
    let (code, text, err) = depthcal(&["plan", demo]);
    assert_eq!(code, 0, "{err}");
    assert!(
        text.contains("hand-eye left     all six parameters observable"),
        "{text}"
    );
    assert!(text.contains("no weak direction"), "{text}");
    let dir = scratch("plan-bad-config");
    for (body, field) in [
        (r#"{"voxel_m": -1}"#, "plan.voxel_m"),
        (r#"{"turns_deg": []}"#, "plan.turns_deg"),
        (r#"{"hand_eye": {"gates_m": [0]}}"#, "plan.hand_eye.gates_m"),
        (r#"{"voxl_m": 0.01}"#, "voxl_m"),
    ] {
        let f = dir.join("p.json");
        std::fs::write(&f, body).unwrap();
        let (code, _, err) = depthcal(&["plan", demo, "--plan-config", &f.display().to_string()]);
        assert_eq!(code, 1, "{body}: {err}");
        assert!(
            err.contains("p.json") && err.contains(field),
            "{body}: {err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
