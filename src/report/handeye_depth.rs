//! The report of `handeye --depth`: [`HandEyeDepthReport`], one robot's hand-eye refined from its depth
//! frames.

use super::pose::{matrix6_rows, ErrorReport, PoseReport, SigmaReport};
use crate::calibration::handeye::depth::joint::{JointHandEyeResult, JointRobotResult};
use crate::calibration::handeye::depth::observe::{DofObservability, FlangeMotion, WeakDirection};
use crate::calibration::handeye::depth::plan::SuggestedPose;
use crate::calibration::handeye::depth::{FrameDepthResidual, HandEyeDepthResult};
use crate::cell::GroundTruth;
use crate::geometry::transform::pose_error;
use nalgebra::{Isometry3, Matrix6, Vector6};
use serde::Serialize;

/// The schema name and version of [`HandEyeDepthReport`].
pub const HANDEYE_DEPTH_SCHEMA: &str = "depthcal.handeye-depth/1";

/// The refined hand-eye against a known true one (simulated cells).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HandEyeTruthReport {
    /// The cell's hand-eye against the truth.
    pub before: ErrorReport,
    /// The refined hand-eye against the truth.
    pub after: ErrorReport,
    /// `sqrt(eᵀΣ⁻¹e / 6)` of the refined hand-eye's error `e = log(T_ee_cam⁻¹ · truth)` (camera frame) under
    /// the reported covariance: about 1 when the covariance is honest, below when it is conservative.
    pub normalised_error: f64,
    /// The largest `|eₖ| / σₖ` over the six parameters.
    pub max_error_over_sigma: f64,
}

impl HandEyeTruthReport {
    /// The errors of `r` against the true hand-eye `truth`.
    pub fn new(r: &HandEyeDepthResult, truth: &Isometry3<f64>) -> Self {
        Self::of(&r.initial, &r.t_ee_cam, &r.covariance, truth)
    }

    /// The errors of a hand-eye refined from `initial` to `refined` with covariance `covariance` (camera
    /// frame) against `truth`.
    pub fn of(
        initial: &Isometry3<f64>,
        refined: &Isometry3<f64>,
        covariance: &Matrix6<f64>,
        truth: &Isometry3<f64>,
    ) -> Self {
        let e = refined.inverse() * truth;
        let w = crate::calibration::handeye::log_rotation(&e.rotation);
        let t = e.translation.vector;
        let v = Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z);
        let ne = covariance
            .try_inverse()
            .map(|inv| (v.transpose() * inv * v)[(0, 0)].max(0.0) / 6.0)
            .map_or(f64::NAN, f64::sqrt);
        let max = (0..6)
            .map(|k| v[k].abs() / covariance[(k, k)].max(1e-30).sqrt())
            .fold(0.0, f64::max);
        HandEyeTruthReport {
            before: ErrorReport::new(pose_error(initial, truth)),
            after: ErrorReport::new(pose_error(refined, truth)),
            normalised_error: ne,
            max_error_over_sigma: max,
        }
    }
}

/// The true hand-eye of robot `name` in a simulated cell's ground truth (`robots[].T_ee_cam`).
pub fn true_hand_eye(gt: &GroundTruth, name: &str) -> Option<Isometry3<f64>> {
    let robots = gt.extra.get("robots")?.as_array()?;
    let r = robots
        .iter()
        .find(|r| r.get("name").and_then(|n| n.as_str()) == Some(name))?;
    let m = r.get("T_ee_cam")?.as_array()?;
    let mut rows = [0.0; 16];
    for (i, row) in m.iter().enumerate().take(4) {
        for (j, x) in row.as_array()?.iter().enumerate().take(4) {
            rows[4 * i + j] = x.as_f64()?;
        }
    }
    crate::geometry::transform::isometry_from_rows(&rows, "T_ee_cam").ok()
}

/// `depthcal handeye --depth`'s JSON: one robot's hand-eye refined from its depth frames.
#[derive(Clone, Debug, Serialize)]
pub struct HandEyeDepthReport {
    /// [`HANDEYE_DEPTH_SCHEMA`].
    pub schema: &'static str,
    /// The cell directory.
    pub cell: String,
    /// The robot.
    pub robot: String,
    /// Frames that overlap the others.
    pub frames_used: usize,
    /// The cell's hand-eye (the start).
    #[serde(rename = "T_ee_cam_initial")]
    pub t_ee_cam_initial: PoseReport,
    /// The refined hand-eye.
    #[serde(rename = "T_ee_cam")]
    pub t_ee_cam: PoseReport,
    /// The change `initial⁻¹ · refined` (camera frame).
    pub change: PoseReport,
    /// Its size: rotation (degrees) and translation (metres).
    pub change_size: ErrorReport,
    /// The change's covariance, `[rx, ry, rz (rad), tx, ty, tz (m)]` in the camera frame.
    pub covariance: [[f64; 6]; 6],
    /// What `covariance` is about.
    pub covariance_parameters: &'static str,
    /// The largest per-axis rotation 1-σ (camera frame), degrees: what a cell's `hand_eye` reads from this
    /// file.
    pub hand_eye_sigma_deg: f64,
    /// The largest per-axis translation 1-σ (camera frame), millimetres.
    pub hand_eye_sigma_mm: f64,
    /// Each parameter's 1-σ and status.
    pub dofs: Vec<DofObservability>,
    /// The poorly constrained directions in words.
    pub weak_directions: Vec<WeakDirection>,
    /// How the flange moved.
    pub flange_motion: FlangeMotion,
    /// Flange poses to capture that would constrain the weak directions.
    pub suggested_poses: Vec<SuggestedPose>,
    /// The range at which rotations are compared with translations, metres.
    pub characteristic_range_m: f64,
    /// Per-frame residuals before and after.
    pub frames: Vec<FrameDepthResidual>,
    /// Median over the frames, before, metres.
    pub median_residual_before_m: f64,
    /// Median over the frames, after, metres.
    pub median_residual_after_m: f64,
    /// Tests at the finest gate.
    pub tests: usize,
    /// Tests refused by the side-of-surface rule.
    pub wrong_side_tests: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Whether the last step was negligible.
    pub converged: bool,
    /// Against the cell's ground truth (`null` without one).
    pub error_vs_truth: Option<HandEyeTruthReport>,
    /// The verdict.
    pub trusted: bool,
    /// Why not trusted.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
}

impl HandEyeDepthReport {
    /// The report of `r` for the cell in `cell`, with the error against `truth` when known.
    pub fn new(r: &HandEyeDepthResult, cell: &str, truth: Option<&Isometry3<f64>>) -> Self {
        let sd = |k: usize| r.covariance[(k, k)].max(0.0).sqrt();
        HandEyeDepthReport {
            schema: HANDEYE_DEPTH_SCHEMA,
            cell: cell.to_string(),
            robot: r.robot.clone(),
            frames_used: r.frames_used,
            t_ee_cam_initial: PoseReport::new(&r.initial),
            t_ee_cam: PoseReport::new(&r.t_ee_cam),
            change: PoseReport::new(&r.change),
            change_size: ErrorReport::new((
                r.change.rotation.angle().to_degrees(),
                r.change.translation.vector.norm(),
            )),
            covariance: matrix6_rows(&r.covariance),
            covariance_parameters: "change T_ee_cam_initial⁻¹ · T_ee_cam, camera frame",
            hand_eye_sigma_deg: sd(0).max(sd(1)).max(sd(2)).to_degrees(),
            hand_eye_sigma_mm: sd(3).max(sd(4)).max(sd(5)) * 1e3,
            dofs: r.dofs.clone(),
            weak_directions: r.weak_directions.clone(),
            flange_motion: r.flange_motion.clone(),
            suggested_poses: r.suggested_poses.clone(),
            characteristic_range_m: r.characteristic_range_m,
            frames: r.frames.clone(),
            median_residual_before_m: r.median_before_m,
            median_residual_after_m: r.median_after_m,
            tests: r.tests,
            wrong_side_tests: r.wrong_side_tests,
            iterations: r.iterations,
            converged: r.converged,
            error_vs_truth: truth.map(|t| HandEyeTruthReport::new(r, t)),
            trusted: r.trusted,
            reasons: r.reasons.clone(),
            suggestions: r.suggestions.clone(),
        }
    }
}

/// The schema name and version of [`JointHandEyeReport`].
pub const HANDEYE_JOINT_SCHEMA: &str = "depthcal.handeye-joint/1";

/// One robot's hand-eye in [`JointHandEyeReport`].
#[derive(Clone, Debug, Serialize)]
pub struct JointRobotReport {
    /// The robot.
    pub robot: String,
    /// The hand-eye the joint refinement started from (the per-robot refinement's).
    #[serde(rename = "T_ee_cam_initial")]
    pub t_ee_cam_initial: PoseReport,
    /// The jointly refined hand-eye.
    #[serde(rename = "T_ee_cam")]
    pub t_ee_cam: PoseReport,
    /// The change `initial⁻¹ · refined` (camera frame).
    pub change: PoseReport,
    /// Its size.
    pub change_size: ErrorReport,
    /// The change's covariance, camera frame.
    pub covariance: [[f64; 6]; 6],
    /// The largest per-axis rotation 1-σ, degrees.
    pub hand_eye_sigma_deg: f64,
    /// The largest per-axis translation 1-σ, millimetres.
    pub hand_eye_sigma_mm: f64,
    /// Each parameter's 1-σ and status.
    pub dofs: Vec<DofObservability>,
    /// The poorly constrained directions in words.
    pub weak_directions: Vec<WeakDirection>,
    /// The range at which rotations are compared with translations, metres.
    pub characteristic_range_m: f64,
    /// Per-frame residuals (own and cross-robot tests) before and after.
    pub frames: Vec<FrameDepthResidual>,
    /// Median over the frames, before, metres.
    pub median_residual_before_m: f64,
    /// Median over the frames, after, metres.
    pub median_residual_after_m: f64,
    /// Against the cell's ground truth (`null` without one): `before` is the per-robot refinement's.
    pub error_vs_truth: Option<HandEyeTruthReport>,
}

impl JointRobotReport {
    fn new(r: &JointRobotResult, truth: Option<&Isometry3<f64>>) -> Self {
        let sd = |k: usize| r.covariance[(k, k)].max(0.0).sqrt();
        JointRobotReport {
            robot: r.robot.clone(),
            t_ee_cam_initial: PoseReport::new(&r.initial),
            t_ee_cam: PoseReport::new(&r.t_ee_cam),
            change: PoseReport::new(&r.change),
            change_size: ErrorReport::new((
                r.change.rotation.angle().to_degrees(),
                r.change.translation.vector.norm(),
            )),
            covariance: matrix6_rows(&r.covariance),
            hand_eye_sigma_deg: sd(0).max(sd(1)).max(sd(2)).to_degrees(),
            hand_eye_sigma_mm: sd(3).max(sd(4)).max(sd(5)) * 1e3,
            dofs: r.dofs.clone(),
            weak_directions: r.weak_directions.clone(),
            characteristic_range_m: r.characteristic_range_m,
            frames: r.frames.clone(),
            median_residual_before_m: r.median_before_m,
            median_residual_after_m: r.median_after_m,
            error_vs_truth: truth
                .map(|t| HandEyeTruthReport::of(&r.initial, &r.t_ee_cam, &r.covariance, t)),
        }
    }
}

/// The base-to-base transforms against the truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BaseTruthReport {
    /// The ordinary calibration's (the joint refinement's start).
    pub calibrate: ErrorReport,
    /// The joint refinement's.
    pub joint: ErrorReport,
}

/// `calibrate --refine-hand-eye`'s `joint_hand_eye`: both hand-eyes and `T_base1_base2` refined together.
#[derive(Clone, Debug, Serialize)]
pub struct JointHandEyeReport {
    /// [`HANDEYE_JOINT_SCHEMA`].
    pub schema: &'static str,
    /// Both robots, the reference first.
    pub robots: Vec<JointRobotReport>,
    /// The ordinary calibration's `T_base1_base2` (the start).
    #[serde(rename = "T_base1_base2_initial")]
    pub t_base1_base2_initial: PoseReport,
    /// The jointly refined `T_base1_base2`.
    #[serde(rename = "T_base1_base2")]
    pub t_base1_base2: PoseReport,
    /// The size of the change from the start.
    pub base_change_size: ErrorReport,
    /// The joint `T_base1_base2`'s covariance.
    pub base_covariance: [[f64; 6]; 6],
    /// What `base_covariance` is about.
    pub base_covariance_parameters: &'static str,
    /// Its 1-σ.
    pub base_sigma: SigmaReport,
    /// The joint `T_base1_base2` replaced the calibration's `transform`.
    pub base_adopted: bool,
    /// Against the cell's ground truth (`null` without one).
    pub base_error_vs_truth: Option<BaseTruthReport>,
    /// Cross-robot tests at the finest gate.
    pub cross_tests: usize,
    /// All tests at the finest gate.
    pub tests: usize,
    /// Tests refused by the side-of-surface rule.
    pub wrong_side_tests: usize,
    /// Gauss-Newton iterations.
    pub iterations: usize,
    /// Whether the last step was negligible.
    pub converged: bool,
    /// The verdict.
    pub trusted: bool,
    /// Why not trusted.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
}

impl JointHandEyeReport {
    /// The report of `j`, against the true hand-eyes (by robot name) and base-to-base transform when
    /// known.
    pub fn new(j: &JointHandEyeResult, adopted: bool, gt: Option<&GroundTruth>) -> Self {
        let d = j.base_initial.inverse() * j.t_base1_base2;
        let truth_base = gt.and_then(|g| g.t_base1_base2);
        JointHandEyeReport {
            schema: HANDEYE_JOINT_SCHEMA,
            robots: j
                .robots
                .iter()
                .map(|r| {
                    let truth = gt.and_then(|g| true_hand_eye(g, &r.robot));
                    JointRobotReport::new(r, truth.as_ref())
                })
                .collect(),
            t_base1_base2_initial: PoseReport::new(&j.base_initial),
            t_base1_base2: PoseReport::new(&j.t_base1_base2),
            base_change_size: ErrorReport::new((
                d.rotation.angle().to_degrees(),
                d.translation.vector.norm(),
            )),
            base_covariance: matrix6_rows(&j.base_covariance),
            base_covariance_parameters: "left increment in the reference base frame (base1)",
            base_sigma: SigmaReport::from_covariance(&j.base_covariance),
            base_adopted: adopted,
            base_error_vs_truth: truth_base.map(|t| BaseTruthReport {
                calibrate: ErrorReport::new(pose_error(&j.base_initial, &t)),
                joint: ErrorReport::new(pose_error(&j.t_base1_base2, &t)),
            }),
            cross_tests: j.cross_tests,
            tests: j.tests,
            wrong_side_tests: j.wrong_side_tests,
            iterations: j.iterations,
            converged: j.converged,
            trusted: j.trusted,
            reasons: j.reasons.clone(),
            suggestions: j.suggestions.clone(),
        }
    }
}
