//! Is a robot's stated hand-eye what its own depth frames say? The check `calibrate` runs on each robot
//! before it trusts a base-to-base transform built on the hand-eyes.
//!
//! A wrong hand-eye moves every frame differently (each by `T_base_ee_i · δ`), so the robot's fused cloud
//! is blurred and shifted, and the base-to-base transform registered from it is off by about the hand-eye
//! error times the working range: 1.5° at 1.5 m is 40 mm. The registration cannot see that (the blurred
//! cloud still aligns), and the covariance only knows the hand-eye's stated 1-σ. So the hand-eye is refined
//! from the robot's depth frames alone ([`refine_hand_eye_from_depth`], a short run: two gates, few
//! iterations) and the change `δ` it finds is tested against the 1-σ the cell states (or depthcal's default
//! when it states none) plus the fit's own covariance: the squared Mahalanobis distance
//! `δᵀ (C_fit + Σ_stated)⁻¹ δ` (six parameters: rotation vector and translation in the camera frame).
//! Directions the poses leave weak have a large `C_fit` and do not count. The refined hand-eye is not
//! adopted here (`calibrate --refine-hand-eye` does that); the check only says whether the stated one and
//! its 1-σ hold.
//!
//! Measured (`depthcal handeye --depth` with these settings; squared distances with the default 1-σ
//! 0.05° / 0.5 mm): the 7-Scenes two-robot cell of `tools/seven_scenes_two_robot_cell.py` with the true
//! hand-eyes 1.6 and 5.6 (changes 0.06° / 0.8 mm and 0.12° / 1.0 mm; centimetre pose noise), with both
//! hand-eyes 4 mm / 1.5° off 752 and 321; the demo cell 0.2 and 0.0. The limit is the 99.9% quantile of
//! χ² with six degrees of freedom, 22.46 (a distance of 4.74 σ).

use super::{refine_hand_eye_under_scatter, HandEyeDepthConfig};
use crate::calibration::uncertainty::twist_covariance;
use crate::camera::DepthView;
use crate::cell::CellRobot;
use crate::error::Result;
use nalgebra::{Matrix6, Vector6};
use serde::{Deserialize, Serialize};

/// Settings of [`check_hand_eye`] (the `hand_eye_check` section of calibrate's `--config`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandEyeCheckConfig {
    /// Run the check (default true; costs about 0.20 s for both robots of the demo cell and 0.51 s for the
    /// 7-Scenes cell's, on 2 cores).
    pub enabled: bool,
    /// A hand-eye is inconsistent with its depth when the squared Mahalanobis distance of the change
    /// exceeds this (default 22.46, the 99.9% quantile of χ² with 6 degrees of freedom).
    pub max_distance_sq: f64,
    /// Each sampled point is tested against every other frame, so the work grows with the square of the
    /// frames: `depth.sample_points` is lowered (to 100 at least) so that points × frames × (frames − 1)
    /// stays within this (default 1 000 000: 1200 points up to 29 frames).
    pub max_pair_tests: usize,
    /// The refinement's settings (default: those of `handeye --depth` with the gates 40 and 15 mm and at
    /// most 6 iterations per gate). Its step tolerances are replaced by `step_fraction` of the 1-σ tested
    /// against.
    pub depth: HandEyeDepthConfig,
    /// The refinement's iterations at a gate end once a step is below this fraction of the hand-eye 1-σ the
    /// change is tested against (default 0.05: 0.0025° / 0.025 mm with depthcal's default 1-σ). A step that
    /// small moves the tested distance by about this many σ (the steps after it are smaller still where the
    /// fit converges), against a limit of 4.74 σ.
    pub step_fraction: f64,
}

impl Default for HandEyeCheckConfig {
    fn default() -> Self {
        HandEyeCheckConfig {
            enabled: true,
            max_distance_sq: 22.46,
            max_pair_tests: 1_000_000,
            depth: HandEyeDepthConfig {
                gates_m: vec![0.04, 0.015],
                max_iterations: 6,
                ..HandEyeDepthConfig::default()
            },
            step_fraction: 0.05,
        }
    }
}

impl HandEyeCheckConfig {
    /// Checks the ranges; the error names the field (`hand_eye_check.depth.gates_m`).
    pub fn validate(&self) -> Result<()> {
        self.depth.validate_within("hand_eye_check.depth")?;
        if self.max_pair_tests == 0 {
            return Err(crate::error::Error::config(
                "hand_eye_check.max_pair_tests",
                "must be at least 1",
            ));
        }
        crate::error::check::positive("hand_eye_check.step_fraction", self.step_fraction)?;
        crate::error::check::positive("hand_eye_check.max_distance_sq", self.max_distance_sq)
    }
}

/// One robot's hand-eye against its depth frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HandEyeCheck {
    /// The robot's name.
    pub robot: String,
    /// The check ran (false: too few frames or no depth views; `note` says why, and `consistent` is
    /// true: no evidence against the hand-eye).
    pub checked: bool,
    /// Why the check did not run.
    pub note: Option<String>,
    /// The rotation of the change the depth asks for, degrees.
    pub change_deg: f64,
    /// Its translation, millimetres.
    pub change_mm: f64,
    /// `sqrt(δᵀ (C_fit + Σ_stated)⁻¹ δ)`: the change in standard deviations.
    pub distance_sigmas: f64,
    /// The limit of `distance_sigmas` (`sqrt(max_distance_sq)`).
    pub max_distance_sigmas: f64,
    /// The hand-eye rotation 1-σ tested against, degrees.
    pub sigma_deg: f64,
    /// The hand-eye translation 1-σ tested against, millimetres.
    pub sigma_mm: f64,
    /// The cell (or its hand-eye file) states those 1-σ; false: depthcal's defaults.
    pub sigma_stated: bool,
    /// Median per-frame residual with the stated hand-eye, millimetres.
    pub median_residual_mm: f64,
    /// The same with the changed one, millimetres.
    pub median_residual_changed_mm: f64,
    /// The hand-eye parameters (camera axes: `rx` … `tz`) the robot's poses determine at least weakly
    /// (`observable` or `weak` in the fit); the check sees only these (the others' fit covariance is huge).
    pub determined: Vec<&'static str>,
    /// The stated hand-eye and its 1-σ agree with the depth frames.
    pub consistent: bool,
    /// The test also allowed for the robot's pose scatter (its frames were moved by it).
    pub pose_scatter_counted: bool,
}

impl HandEyeCheck {
    fn not_checked(robot: &CellRobot, note: String, cfg: &HandEyeCheckConfig) -> Self {
        let (sigma_deg, sigma_mm, sigma_stated) = stated_sigma(robot);
        HandEyeCheck {
            robot: robot.name.clone(),
            checked: false,
            note: Some(note),
            change_deg: 0.0,
            change_mm: 0.0,
            distance_sigmas: 0.0,
            max_distance_sigmas: cfg.max_distance_sq.sqrt(),
            sigma_deg,
            sigma_mm,
            sigma_stated,
            median_residual_mm: 0.0,
            median_residual_changed_mm: 0.0,
            determined: Vec::new(),
            consistent: true,
            pose_scatter_counted: false,
        }
    }

    /// The trust reason of an inconsistent hand-eye, in words.
    pub fn reason(&self) -> String {
        format!(
            "robot {}'s hand-eye disagrees with its own depth frames: they agree best with it moved {:.2}° / {:.1} mm, \
             {:.1}σ of the hand-eye's 1-σ {:.3}° / {:.2} mm ({}){} and the fit's own (limit {:.1}σ; median residual \
             {:.2} -> {:.2} mm{})",
            self.robot,
            self.change_deg,
            self.change_mm,
            self.distance_sigmas,
            self.sigma_deg,
            self.sigma_mm,
            if self.sigma_stated {
                "as the cell states"
            } else {
                "depthcal's default: the cell states none"
            },
            if self.pose_scatter_counted {
                ", the poses' scatter"
            } else {
                ""
            },
            self.max_distance_sigmas,
            self.median_residual_mm,
            self.median_residual_changed_mm,
            if self.determined.len() < 6 {
                format!("; the poses determine {} of its parameters", self.determined.join(" "))
            } else {
                String::new()
            }
        )
    }

    /// What to do about an inconsistent hand-eye.
    pub fn suggestion(&self) -> String {
        format!(
            "refine the hand-eyes from the depth (`depthcal calibrate --refine-hand-eye`; `depthcal handeye --depth CELL \
             --robot {0}` shows robot {0}'s fit) or calibrate the hand-eye again; if it is only known that well, state \
             hand_eye_sigma_deg / hand_eye_sigma_mm of robot {0} in cell.toml (the result's 1-σ grows with them)",
            self.robot
        )
    }
}

/// The hand-eye 1-σ of `robot` (degrees, millimetres) and whether the cell stated both.
fn stated_sigma(robot: &CellRobot) -> (f64, f64, bool) {
    let u = &robot.uncertainty;
    let stated = ["hand_eye_sigma_deg", "hand_eye_sigma_mm"]
        .iter()
        .all(|k| u.stated.iter().any(|s| s == k));
    (
        u.hand_eye_rotation_rad.to_degrees(),
        u.hand_eye_translation_m * 1e3,
        stated,
    )
}

/// Checks `robot.t_ee_cam` and its stated 1-σ against the robot's depth frames (`views`: one per frame,
/// e.g. a fused cloud's; `None` reads the depth images). Errors: a bad configuration, an unreadable depth
/// image. Too few frames is not an error: the result says it was not checked.
pub fn check_hand_eye(
    robot: &CellRobot,
    views: Option<&[DepthView]>,
    cfg: &HandEyeCheckConfig,
) -> Result<HandEyeCheck> {
    check_hand_eye_under_scatter(robot, views, cfg, None)
}

/// [`check_hand_eye`] of a robot whose poses scatter: `scatter` is the poses' 1-σ per axis at the scene
/// (rotation in radians, translation in metres), the scatter a hand-eye change does not explain
/// ([`crate::calibration::pose_scatter::PoseScatter::beyond_hand_eye_mm`]: a hand-eye that is off must not
/// widen its own allowance). The covariance of the hand-eye change that independent pose errors of that size cause in
/// this very fit (its sensitivity to each frame's pose, propagated: [`super::refine_hand_eye_under_scatter`])
/// is added to the test's covariance, so that scattered poses are told apart from a hand-eye that is off.
pub fn check_hand_eye_under_scatter(
    robot: &CellRobot,
    views: Option<&[DepthView]>,
    cfg: &HandEyeCheckConfig,
    scatter: Option<(f64, f64)>,
) -> Result<HandEyeCheck> {
    cfg.validate()?;
    if robot.frames.len() < cfg.depth.min_frames {
        return Ok(HandEyeCheck::not_checked(
            robot,
            format!(
                "{} frames: the check needs at least {} from different flange orientations",
                robot.frames.len(),
                cfg.depth.min_frames
            ),
            cfg,
        ));
    }
    let n = robot.frames.len();
    let (sigma_deg, sigma_mm, _) = stated_sigma(robot);
    let depth = HandEyeDepthConfig {
        sample_points: (cfg.max_pair_tests / (n * (n - 1)))
            .clamp(100, cfg.depth.sample_points.max(100))
            .min(cfg.depth.sample_points),
        step_tolerance_deg: cfg.step_fraction * sigma_deg,
        step_tolerance_mm: cfg.step_fraction * sigma_mm,
        ..cfg.depth.clone()
    };
    let (fit, scatter) = refine_hand_eye_under_scatter(robot, views, &depth, scatter)?;
    let determined: Vec<&'static str> = fit
        .dofs
        .iter()
        .filter(|d| d.status != "unobservable")
        .map(|d| d.dof)
        .collect();
    if determined.is_empty() {
        return Ok(HandEyeCheck::not_checked(
            robot,
            "the flange poses determine none of the hand-eye's parameters (see `depthcal plan`)"
                .into(),
            cfg,
        ));
    }
    let (sigma_deg, sigma_mm, sigma_stated) = stated_sigma(robot);
    let delta: Vector6<f64> = {
        let r = fit.change.rotation.scaled_axis();
        let t = fit.change.translation.vector;
        Vector6::new(r.x, r.y, r.z, t.x, t.y, t.z)
    };
    let (sr, st) = (sigma_deg.to_radians(), sigma_mm * 1e-3);
    let prior = twist_covariance(sr, st);
    let Some(d2) = (fit.covariance + prior + scatter.unwrap_or_else(Matrix6::zeros))
        .cholesky()
        .map(|c| delta.dot(&c.solve(&delta)))
        .filter(|d2| d2.is_finite())
    else {
        return Ok(HandEyeCheck::not_checked(
            robot,
            "the depth fit's covariance is not positive definite".into(),
            cfg,
        ));
    };
    Ok(HandEyeCheck {
        robot: robot.name.clone(),
        checked: true,
        note: None,
        change_deg: fit.change.rotation.angle().to_degrees(),
        change_mm: fit.change.translation.vector.norm() * 1e3,
        distance_sigmas: d2.max(0.0).sqrt(),
        max_distance_sigmas: cfg.max_distance_sq.sqrt(),
        sigma_deg,
        sigma_mm,
        sigma_stated,
        median_residual_mm: fit.median_before_m * 1e3,
        median_residual_changed_mm: fit.median_after_m * 1e3,
        determined,
        consistent: d2 <= cfg.max_distance_sq,
        pose_scatter_counted: scatter.is_some(),
    })
}
