//! The JSON objects of results, the same as the command line's `--json` prints for the same inputs (so
//! that `to_dict()` of a result equals the CLI's output), built from the library's result types.

use depthcal::calibration::handeye::HandEyeResult;
use depthcal::calibration::robot_to_robot::Calibration;
use depthcal::geometry::pose::{isometry_to_xyzquat, KukaPose};
use depthcal::geometry::transform::isometry_to_nested;
use depthcal::registration::pipeline::Ambiguity;
use depthcal::registration::Registration;
use nalgebra::{Isometry3, Matrix6};
use serde_json::{json, Value};

/// A 4x4 row-major nested array.
pub fn matrix4_json(t: &Isometry3<f64>) -> Value {
    json!(isometry_to_nested(t))
}

/// A 6x6 nested array.
pub fn matrix6_json(m: &Matrix6<f64>) -> Value {
    let rows: Vec<Vec<f64>> = (0..6)
        .map(|r| (0..6).map(|c| m[(r, c)]).collect())
        .collect();
    json!(rows)
}

/// Stage timings as an object (milliseconds, rounded to 1 µs as the CLI prints them).
pub fn timings_json(t: &[(String, f64)]) -> Value {
    let mut m = serde_json::Map::new();
    for (k, v) in t {
        m.insert(k.clone(), json!((v * 1000.0).round() / 1000.0));
    }
    Value::Object(m)
}

/// An ambiguity; the translation under `key`, scaled by `scale`.
pub fn ambiguity_json(a: &Ambiguity, key: &str, scale: f64) -> Value {
    let mut v = json!({
        "runner_up": matrix4_json(&a.runner_up),
        "score_ratio": a.score_ratio,
        "rotation_deg": a.rotation_deg,
    });
    v[key] = (a.translation * scale).into();
    v
}

/// What a registration's report needs beyond the library's result.
pub struct RegisterInputs {
    /// The source's file name, or None for an array.
    pub source: Option<String>,
    /// The target's file name, or None for an array.
    pub target: Option<String>,
    /// Point counts of the clouds as given.
    pub points: [usize; 2],
    /// The seed.
    pub seed: u64,
    /// Wall time of the whole call, milliseconds.
    pub total_ms: f64,
}

/// The JSON of `depthcal register --json`.
pub fn registration(reg: &Registration, i: &RegisterInputs) -> Value {
    let g = reg.global.as_ref().map(|g| {
        json!({
            "correspondences": g.correspondences,
            "inliers": g.inliers,
            "iterations": g.iterations,
            "fitness": g.fitness,
            "transform": matrix4_json(&g.transform),
        })
    });
    json!({
        "source": i.source,
        "target": i.target,
        "transform": matrix4_json(&reg.transform),
        "fitness": reg.fitness,
        "inlier_rmse": reg.inlier_rmse,
        "overlap": reg.overlap,
        "converged": reg.converged,
        "iterations": reg.iterations,
        "covariance": matrix6_json(&reg.covariance),
        "information": matrix6_json(&reg.information),
        "covariance_parameters": "[rx, ry, rz (rad), tx, ty, tz (cloud units)], left increment about the target origin",
        "degenerate": reg.degeneracy.is_degenerate(),
        "degeneracy": reg.degeneracy,
        "voxel": reg.voxel,
        "spacing": reg.spacing,
        "points": {"source": i.points[0], "target": i.points[1],
                   "source_downsampled": reg.global_points[0], "target_downsampled": reg.global_points[1]},
        "global": g,
        "seed": i.seed,
        "warnings": reg.warnings,
        "trusted": reg.trust.trusted,
        "reasons": reg.trust.reasons,
        "suggestions": reg.trust.suggestions,
        "surface_agreement": reg.surface_agreement,
        "ambiguity": reg.ambiguity.as_ref().map(|x| ambiguity_json(x, "translation", 1.0)),
        "error_vs_truth": Value::Null,
        "timings_ms": timings_json(&reg.timings_ms),
        "total_ms": i.total_ms,
    })
}

/// The ROS 2 `static_transform_publisher` command line of `T_parent_child`.
pub fn ros2_command(t: &Isometry3<f64>, parent: &str, child: &str) -> String {
    let xq = isometry_to_xyzquat(t);
    format!(
        "ros2 run tf2_ros static_transform_publisher --x {:.6} --y {:.6} --z {:.6} --qx {:.8} --qy {:.8} --qz {:.8} --qw {:.8} --frame-id {parent} --child-frame-id {child}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6]
    )
}

/// The JSON of `depthcal calibrate --json`.
pub fn calibration(c: &Calibration, cell: &str, parent: &str, child: &str, total_ms: f64) -> Value {
    let t = &c.transform;
    let xq = isometry_to_xyzquat(t);
    let kuka = KukaPose::from_isometry(t);
    let sd: Vec<f64> = (0..6)
        .map(|k| c.covariance[(k, k)].max(0.0).sqrt())
        .collect();
    let err = |e: Option<(f64, f64)>| {
        e.map(|(r, t)| json!({"rotation_deg": r, "translation_mm": t * 1e3}))
    };
    json!({
        "cell": cell,
        "reference": c.reference,
        "other": c.other,
        "method": c.method,
        "transform": matrix4_json(t),
        "xyz_quaternion": {"x": xq[0], "y": xq[1], "z": xq[2], "qx": xq[3], "qy": xq[4], "qz": xq[5], "qw": xq[6]},
        "kuka_xyzabc": {"x_mm": kuka.x_mm, "y_mm": kuka.y_mm, "z_mm": kuka.z_mm, "a_deg": kuka.a_deg, "b_deg": kuka.b_deg, "c_deg": kuka.c_deg},
        "covariance": matrix6_json(&c.covariance),
        "covariance_parameters": "[rx, ry, rz (rad), tx, ty, tz (m)], left increment in the reference base frame",
        "sigma": {"rotation_deg": [sd[0].to_degrees(), sd[1].to_degrees(), sd[2].to_degrees()], "translation_mm": [sd[3] * 1e3, sd[4] * 1e3, sd[5] * 1e3]},
        "fitness": c.fitness,
        "inlier_rmse": c.inlier_rmse,
        "overlap": c.overlap,
        "refined": c.refined,
        "converged": c.converged,
        "degenerate": c.degeneracy.is_degenerate(),
        "degeneracy": c.degeneracy,
        "priors_used": c.priors_used,
        "priors_assumed": c.priors_assumed,
        "trusted": c.trust.trusted,
        "reasons": c.trust.reasons,
        "suggestions": c.trust.suggestions,
        "free_space": c.free_space,
        "ambiguity": c.ambiguity.as_ref().map(|x| ambiguity_json(x, "translation_mm", 1e3)),
        "initial": {"transform": matrix4_json(&c.initial.transform), "detail": c.initial.detail,
                    "sigma_rotation_deg": c.initial.sigma_rotation_deg, "sigma_translation_mm": c.initial.sigma_translation_m * 1e3,
                    "error_vs_truth": err(c.initial_error_vs_truth)},
        "error_vs_truth": err(c.error_vs_truth),
        "normalised_error": c.normalised_error,
        "consistency": c.consistency,
        "inputs_covariance": matrix6_json(&c.inputs_covariance),
        "frames": {"reference": c.frames[0], "other": c.frames[1]},
        "fused_points": {"reference": c.fused_points[0], "other": c.fused_points[1]},
        "ros2": ros2_command(t, parent, child),
        "frame_ids": {"parent": parent, "child": child},
        "warnings": c.warnings,
        "timings_ms": timings_json(&c.timings_ms),
        "total_ms": total_ms,
    })
}

fn kuka_json(t: &Isometry3<f64>) -> Value {
    let k = KukaPose::from_isometry(t);
    json!({"x_mm": k.x_mm, "y_mm": k.y_mm, "z_mm": k.z_mm, "a_deg": k.a_deg, "b_deg": k.b_deg, "c_deg": k.c_deg})
}

fn residual_summary(r: &HandEyeResult) -> Value {
    let inl: Vec<_> = r.residuals.iter().filter(|f| !f.rejected).collect();
    let mut rot: Vec<f64> = inl.iter().map(|f| f.rotation_deg).collect();
    let mut tr: Vec<f64> = inl.iter().map(|f| f.translation_mm).collect();
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        if v.is_empty() {
            0.0
        } else {
            v[v.len() / 2]
        }
    };
    json!({
        "frames": inl.len(),
        "rotation_rms_deg": rms(&rot),
        "rotation_max_deg": rot.iter().cloned().fold(0.0, f64::max),
        "rotation_median_deg": med(&mut rot),
        "translation_rms_mm": rms(&tr),
        "translation_max_mm": tr.iter().cloned().fold(0.0, f64::max),
        "translation_median_mm": med(&mut tr),
    })
}

/// Where the hand-eye's poses came from (file names, or None for arrays) and the setup.
pub struct HandEyeInputs {
    /// The robot pose file, if read from one.
    pub robot_poses: Option<String>,
    /// The target pose file, if read from one.
    pub target_poses: Option<String>,
    /// Camera fixed in the cell, board on the flange.
    pub eye_to_hand: bool,
}

/// The JSON of `depthcal handeye --json`.
pub fn hand_eye(r: &HandEyeResult, i: &HandEyeInputs) -> Value {
    let (x_name, z_name) = if i.eye_to_hand {
        ("T_ee_board", "T_base_cam")
    } else {
        ("T_ee_cam", "T_base_board")
    };
    let mut o = serde_json::Map::new();
    o.insert(x_name.into(), matrix4_json(&r.t_ee_cam));
    o.insert(z_name.into(), matrix4_json(&r.t_base_board));
    o.insert(format!("{x_name}_kuka"), kuka_json(&r.t_ee_cam));
    o.insert(
        format!("{x_name}_xyzquat"),
        json!(isometry_to_xyzquat(&r.t_ee_cam)),
    );
    o.insert(format!("{z_name}_kuka"), kuka_json(&r.t_base_board));
    o.insert(
        "method".into(),
        json!(if r.refined {
            "refined".to_string()
        } else {
            r.method.name().to_string()
        }),
    );
    o.insert("initial_method".into(), json!(r.method.name()));
    o.insert("initial_from_lmeds".into(), json!(r.from_lmeds));
    o.insert(
        "setup".into(),
        json!(if i.eye_to_hand {
            "eye-to-hand"
        } else {
            "eye-in-hand"
        }),
    );
    o.insert("robot_poses".into(), json!(i.robot_poses));
    o.insert("target_poses".into(), json!(i.target_poses));
    o.insert("images".into(), Value::Null);
    o.insert(
        "residuals".into(),
        serde_json::to_value(&r.residuals).unwrap_or_default(),
    );
    o.insert("residual_summary".into(), residual_summary(r));
    o.insert("rejected".into(), json!(r.rejected));
    o.insert("warnings".into(), json!(r.warnings));
    o.insert(
        "closed_forms".into(),
        json!(r
            .closed_forms
            .iter()
            .map(|c| json!({
                "method": c.method.name(),
                x_name: c.t_ee_cam.as_ref().map(matrix4_json),
                z_name: c.t_base_board.as_ref().map(matrix4_json),
                "rotation_median_deg": c.rotation_median_deg,
                "translation_median_mm": c.translation_median_mm,
                "rotation_rms_deg": c.rotation_rms_deg,
                "translation_rms_mm": c.translation_rms_mm,
                "error": c.error,
            }))
            .collect::<Vec<_>>()),
    );
    o.insert(
        "excitation".into(),
        serde_json::to_value(&r.excitation).unwrap_or_default(),
    );
    o.insert(
        format!("{z_name}_spread"),
        json!({
            "rotation_rms_deg": r.board.rotation_rms_deg,
            "rotation_max_deg": r.board.rotation_max_deg,
            "translation_rms_mm": r.board.translation_rms_mm,
            "translation_max_mm": r.board.translation_max_mm,
        }),
    );
    o.insert(
        "sigma".into(),
        json!({"rotation_deg": r.sigma_rotation_deg, "translation_mm": r.sigma_translation_mm}),
    );
    if let Some(s) = r.t_ee_cam_sigma {
        o.insert("hand_eye_sigma_deg".into(), json!(s.rotation_deg));
        o.insert("hand_eye_sigma_mm".into(), json!(s.translation_mm));
    }
    o.insert("iterations".into(), json!(r.iterations));
    o.insert("converged".into(), json!(r.converged));
    Value::Object(o)
}
