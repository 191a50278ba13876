//! The report of `handeye`: [`HandEyeReport`].

use super::pose::PoseReport;
use crate::calibration::handeye::{Excitation, FrameResidual, HandEyeResult};
use crate::stats::{max_or_zero, median, rms};
use serde::Serialize;

/// The schema name and version of [`HandEyeReport`].
pub const HANDEYE_SCHEMA: &str = "depthcal.handeye/1";

/// Where the hand-eye inputs came from.
#[derive(Clone, Debug, Default)]
pub struct HandEyeInputs {
    /// The camera is fixed and the board rides on the flange (eye-to-hand).
    pub eye_to_hand: bool,
    /// The robot pose file.
    pub robot_poses: String,
    /// The board pose file, if the poses came from one.
    pub target_poses: Option<String>,
    /// The image directory, if the board poses were found in images.
    pub images: Option<String>,
}

/// Residuals of the inlier frames.
#[derive(Clone, Debug, Serialize)]
pub struct ResidualSummary {
    /// Inlier frames.
    pub frames: usize,
    /// RMS rotation residual, degrees.
    pub rotation_rms_deg: f64,
    /// Largest rotation residual, degrees.
    pub rotation_max_deg: f64,
    /// Median rotation residual, degrees.
    pub rotation_median_deg: f64,
    /// RMS translation residual, millimetres.
    pub translation_rms_mm: f64,
    /// Largest translation residual, millimetres.
    pub translation_max_mm: f64,
    /// Median translation residual, millimetres.
    pub translation_median_mm: f64,
}

impl ResidualSummary {
    /// The summary of the frames not rejected.
    pub fn of(residuals: &[FrameResidual]) -> Self {
        let inl: Vec<&FrameResidual> = residuals.iter().filter(|f| !f.rejected).collect();
        let rot: Vec<f64> = inl.iter().map(|f| f.rotation_deg).collect();
        let tr: Vec<f64> = inl.iter().map(|f| f.translation_mm).collect();
        ResidualSummary {
            frames: inl.len(),
            rotation_rms_deg: rms(&rot),
            rotation_max_deg: max_or_zero(&rot),
            rotation_median_deg: median(&rot),
            translation_rms_mm: rms(&tr),
            translation_max_mm: max_or_zero(&tr),
            translation_median_mm: median(&tr),
        }
    }
}

/// One closed form's answer.
#[derive(Clone, Debug, Serialize)]
pub struct ClosedFormReport {
    /// The method's name.
    pub method: &'static str,
    /// Its hand-eye transform (`None` when it failed).
    pub hand_eye: Option<PoseReport>,
    /// Its board pose in the base (`None` when it failed).
    pub target: Option<PoseReport>,
    /// Median rotation residual over all frames, degrees.
    pub rotation_median_deg: f64,
    /// Median translation residual over all frames, millimetres.
    pub translation_median_mm: f64,
    /// RMS rotation residual over all frames, degrees.
    pub rotation_rms_deg: f64,
    /// RMS translation residual over all frames, millimetres.
    pub translation_rms_mm: f64,
    /// Why it failed.
    pub error: Option<String>,
}

/// Spread of the per-frame board poses about their average.
#[derive(Clone, Debug, Serialize)]
pub struct SpreadReport {
    /// RMS rotation from the average, degrees.
    pub rotation_rms_deg: f64,
    /// Largest rotation from the average, degrees.
    pub rotation_max_deg: f64,
    /// RMS translation from the average, millimetres.
    pub translation_rms_mm: f64,
    /// Largest translation from the average, millimetres.
    pub translation_max_mm: f64,
}

/// Residual scale of the inliers.
#[derive(Clone, Debug, Serialize)]
pub struct ResidualScale {
    /// Rotation, degrees (RMS per axis).
    pub rotation_deg: f64,
    /// Translation, millimetres (RMS per axis).
    pub translation_mm: f64,
}

/// A hand-eye calibration, as `depthcal handeye --json` prints it. Poses in metres and degrees; the
/// residuals of the board in millimetres, as hand-eye tools report them.
///
/// Eye-in-hand fills `T_ee_cam` (the hand-eye) and `T_base_board`; eye-to-hand fills `T_ee_board` and
/// `T_base_cam`. The names match the frames so that a cell's `hand_eye` file and `calibrate --board-pose`
/// read them without guessing.
#[derive(Clone, Debug, Serialize)]
#[allow(non_snake_case)]
pub struct HandEyeReport {
    /// [`HANDEYE_SCHEMA`].
    pub schema: &'static str,
    /// `eye-in-hand` or `eye-to-hand`.
    pub setup: &'static str,
    /// The camera in the flange frame (eye-in-hand).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub T_ee_cam: Option<PoseReport>,
    /// The board in the robot base (eye-in-hand).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub T_base_board: Option<PoseReport>,
    /// The board in the flange frame (eye-to-hand).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub T_ee_board: Option<PoseReport>,
    /// The camera in the robot base (eye-to-hand).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub T_base_cam: Option<PoseReport>,
    /// 1-σ of the hand-eye rotation, degrees (RMS per axis; absent without refinement). A cell's
    /// `hand_eye` entry naming this file takes it.
    pub hand_eye_sigma_deg: Option<f64>,
    /// 1-σ of the hand-eye translation, millimetres (the cell.toml key's unit).
    pub hand_eye_sigma_mm: Option<f64>,
    /// `refined`, or the closed form's name when not refined.
    pub method: String,
    /// The closed form the answer starts from.
    pub initial_method: &'static str,
    /// The least-median-of-squares search gave the starting point.
    pub initial_from_lmeds: bool,
    /// The robot pose file.
    pub robot_poses: String,
    /// The board pose file.
    pub target_poses: Option<String>,
    /// The image directory.
    pub images: Option<String>,
    /// Per-frame residuals, input order (rejected frames flagged).
    pub residuals: Vec<FrameResidual>,
    /// Their summary over the inliers.
    pub residual_summary: ResidualSummary,
    /// Rejected frame ids.
    pub rejected: Vec<String>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
    /// Every closed form's answer.
    pub closed_forms: Vec<ClosedFormReport>,
    /// How well the motions excite the rotation axes.
    pub excitation: Excitation,
    /// Spread of the per-frame board (eye-to-hand: camera) poses.
    pub target_spread: SpreadReport,
    /// Residual scale of the inliers.
    pub sigma: ResidualScale,
    /// LM iterations.
    pub iterations: usize,
    /// The refinement converged.
    pub converged: bool,
}

impl HandEyeReport {
    /// The report of `r`.
    pub fn new(r: &HandEyeResult, inputs: &HandEyeInputs) -> Self {
        let x = Some(PoseReport::new(&r.t_ee_cam));
        let z = Some(PoseReport::new(&r.t_base_board));
        let (eih, eth) = (!inputs.eye_to_hand, inputs.eye_to_hand);
        HandEyeReport {
            schema: HANDEYE_SCHEMA,
            setup: if eth { "eye-to-hand" } else { "eye-in-hand" },
            T_ee_cam: x.clone().filter(|_| eih),
            T_base_board: z.clone().filter(|_| eih),
            T_ee_board: x.filter(|_| eth),
            T_base_cam: z.filter(|_| eth),
            hand_eye_sigma_deg: r.t_ee_cam_sigma.map(|s| s.rotation_deg),
            hand_eye_sigma_mm: r.t_ee_cam_sigma.map(|s| s.translation_mm),
            method: if r.refined {
                "refined".to_string()
            } else {
                r.method.name().to_string()
            },
            initial_method: r.method.name(),
            initial_from_lmeds: r.from_lmeds,
            robot_poses: inputs.robot_poses.clone(),
            target_poses: inputs.target_poses.clone(),
            images: inputs.images.clone(),
            residuals: r.residuals.clone(),
            residual_summary: ResidualSummary::of(&r.residuals),
            rejected: r.rejected.clone(),
            warnings: r.warnings.clone(),
            closed_forms: r
                .closed_forms
                .iter()
                .map(|c| ClosedFormReport {
                    method: c.method.name(),
                    hand_eye: c.t_ee_cam.as_ref().map(PoseReport::new),
                    target: c.t_base_board.as_ref().map(PoseReport::new),
                    rotation_median_deg: c.rotation_median_deg,
                    translation_median_mm: c.translation_median_mm,
                    rotation_rms_deg: c.rotation_rms_deg,
                    translation_rms_mm: c.translation_rms_mm,
                    error: c.error.clone(),
                })
                .collect(),
            excitation: r.excitation.clone(),
            target_spread: SpreadReport {
                rotation_rms_deg: r.board.rotation_rms_deg,
                rotation_max_deg: r.board.rotation_max_deg,
                translation_rms_mm: r.board.translation_rms_mm,
                translation_max_mm: r.board.translation_max_mm,
            },
            sigma: ResidualScale {
                rotation_deg: r.sigma_rotation_deg,
                translation_mm: r.sigma_translation_mm,
            },
            iterations: r.iterations,
            converged: r.converged,
        }
    }
}
