//! Calibrating a cell with a named method, and comparing every method the cell allows: what `depthcal
//! calibrate` and `depthcal compare` (and the Python package) run.

use super::{available, build, Method, MethodInputs};
use crate::calibration::handeye::depth::joint::{refine_jointly, JointHandEyeResult};
use crate::calibration::handeye::depth::{refine_hand_eye_from_depth, HandEyeDepthResult};
use crate::calibration::robot_to_robot::{
    calibrate_request, fuse_cell, refine_cell, CalibrateConfig, CalibrateRequest, Calibration,
    FusedCell,
};
use crate::cell::Cell;
use crate::error::Result;
use crate::geometry::transform::pose_error;
use nalgebra::Isometry3;
use std::time::Instant;

/// Calibrates `cell` with `method`: builds its initialiser (image methods find their targets here, timed
/// as the first stage), then refines with trimmed robust ICP unless `refine` is off. The initialiser's
/// warnings come first in the result's warnings. Returns the fused clouds too (empty when not needed).
pub fn calibrate_with_method(
    cell: &Cell,
    method: Method,
    inputs: &MethodInputs,
    cfg: &CalibrateConfig,
    refine: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<(Calibration, FusedCell)> {
    let (init, found_ms, warnings) = build(method, cell, inputs, cfg)?;
    let (mut c, fused) = calibrate_request(CalibrateRequest {
        refine,
        progress: Some(progress),
        ..CalibrateRequest::new(cell, init.as_ref(), cfg)
    })?;
    if found_ms > 0.0 {
        // The image targets are found before the clouds are fused.
        let key = match method {
            Method::Checkerboard => "board_poses",
            Method::Marker => "marker_poses",
            _ => "keypoints",
        };
        c.timings_ms.insert(0, (key.into(), found_ms));
    }
    c.warnings.splice(0..0, warnings);
    Ok((c, fused))
}

/// One method's outcome in a [`Comparison`].
#[derive(Clone, Debug)]
pub enum MethodOutcome {
    /// It ran: the calibration and its wall time (milliseconds).
    Ran(Box<Calibration>, f64),
    /// The cell's data does not allow it: why.
    Skipped(String),
    /// It failed: the error.
    Failed(String),
}

/// One row of a [`Comparison`].
#[derive(Clone, Debug)]
pub struct MethodRow {
    /// The method.
    pub method: Method,
    /// What came of it.
    pub outcome: MethodOutcome,
    /// The largest difference of its result from the other methods' results: (degrees, metres).
    pub disagreement: Option<(f64, f64)>,
}

/// Every method a cell allows, run on one fusion of the clouds.
#[derive(Clone, Debug)]
pub struct Comparison {
    /// The methods in order.
    pub rows: Vec<MethodRow>,
    /// The methods were refined with ICP.
    pub refined: bool,
    /// Wall time of the one fusion, milliseconds.
    pub fuse_ms: f64,
    /// The cell has a ground truth.
    pub has_truth: bool,
}

impl Comparison {
    /// A trusted result came out of some method.
    pub fn any_trusted(&self) -> bool {
        self.ran().any(|c| c.trust.trusted)
    }

    /// The calibrations of the methods that ran.
    pub fn ran(&self) -> impl Iterator<Item = &Calibration> {
        self.rows.iter().filter_map(|r| match &r.outcome {
            MethodOutcome::Ran(c, _) => Some(c.as_ref()),
            _ => None,
        })
    }
}

/// Runs every method the cell's data allows ([`available`]), or only `only` when given (then a method
/// whose table is missing runs and reports its error instead of being skipped). The clouds are fused once.
/// `Method::Guess` needs an input file and is not part of a comparison. Returns the fused clouds too
/// (empty when no method needed them).
pub fn compare_methods(
    cell: &Cell,
    only: &[Method],
    cfg: &CalibrateConfig,
    refine: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<(Comparison, FusedCell)> {
    if only.contains(&Method::Guess) {
        return Err(crate::Error::InvalidInput(
            "compare runs the methods that need no input file; guess is not one".into(),
        ));
    }
    let mut plan = available(cell);
    if !only.is_empty() {
        plan.retain(|(m, _)| only.contains(m));
        for (_, reason) in plan.iter_mut() {
            if reason.as_deref().is_some_and(|r| r.starts_with("no [")) {
                *reason = None;
            }
        }
    }
    let needs_fusion = refine || plan.iter().any(|(m, r)| *m == Method::Depth && r.is_none());
    let fused = if needs_fusion {
        progress("fusing both robots' frames");
        fuse_cell(cell, cfg)?
    } else {
        FusedCell::without_clouds(cell, cfg)?
    };
    let mut rows = Vec::new();
    for (method, reason) in plan {
        if let Some(r) = reason {
            rows.push((method, MethodOutcome::Skipped(r)));
            continue;
        }
        progress(&format!("running {}", method.name()));
        let t0 = Instant::now();
        let outcome =
            build(method, cell, &MethodInputs::default(), cfg).and_then(|(init, _, _)| {
                refine_cell(cell, &fused, init.as_ref(), cfg, refine, &mut |_| {})
            });
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        rows.push((
            method,
            match outcome {
                Ok(c) => MethodOutcome::Ran(Box::new(c), ms),
                Err(e) => MethodOutcome::Failed(e.to_string()),
            },
        ));
    }
    let results: Vec<(Method, Isometry3<f64>)> = rows
        .iter()
        .filter_map(|(m, o)| match o {
            MethodOutcome::Ran(c, _) => Some((*m, c.transform)),
            _ => None,
        })
        .collect();
    let disagreement = |m: Method, t: &Isometry3<f64>| -> Option<(f64, f64)> {
        results
            .iter()
            .filter(|(o, _)| *o != m)
            .map(|(_, u)| pose_error(t, u))
            .fold(None, |acc: Option<(f64, f64)>, (r, tr)| {
                Some(acc.map_or((r, tr), |(ar, at)| (ar.max(r), at.max(tr))))
            })
    };
    let rows = rows
        .into_iter()
        .map(|(method, outcome)| {
            let d = match &outcome {
                MethodOutcome::Ran(c, _) => disagreement(method, &c.transform),
                _ => None,
            };
            MethodRow {
                method,
                outcome,
                disagreement: d,
            }
        })
        .collect();
    let cmp = Comparison {
        rows,
        refined: refine,
        fuse_ms: fused.fuse_ms,
        has_truth: cell.ground_truth()?.and_then(|g| g.t_base1_base2).is_some(),
    };
    Ok((cmp, fused))
}

/// What `calibrate --refine-hand-eye` refined besides the calibration.
#[derive(Clone, Debug)]
pub struct HandEyeRefinement {
    /// Each robot's own refinement (cell order).
    pub robots: Vec<HandEyeDepthResult>,
    /// Both hand-eyes and `T_base1_base2` refined together (`refine_hand_eye.joint`).
    pub joint: Option<JointHandEyeResult>,
    /// The joint `T_base1_base2` replaced the calibration's (`refine_hand_eye.adopt_joint_base` and a
    /// trusted joint refinement).
    pub joint_base_adopted: bool,
}

/// [`calibrate_with_method`] after each robot's hand-eye is refined from its own depth frames
/// (`calibrate --refine-hand-eye`, [`crate::calibration::handeye::depth`], settings in
/// `cfg.refine_hand_eye`): a copy of the cell takes the refined hand-eyes (and, for a trusted refinement,
/// their 1-σ as the hand-eye uncertainty), then the usual calibration runs on it. A refinement that does
/// not lower its robot's residuals keeps the cell's hand-eye; an untrusted one makes the calibration
/// untrusted, with its reasons. Then, with `refine_hand_eye.joint`, both hand-eyes and `T_base1_base2`
/// are refined together from there ([`refine_jointly`]); with `refine_hand_eye.adopt_joint_base` a
/// trusted joint `T_base1_base2` (and its covariance) replaces the calibration's. Returns the calibration,
/// its fused clouds and the refinements.
pub fn calibrate_refining_hand_eyes(
    cell: &Cell,
    method: Method,
    inputs: &MethodInputs,
    cfg: &CalibrateConfig,
    refine: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<(Calibration, FusedCell, HandEyeRefinement)> {
    cfg.validate()?;
    let hand_eye = &cfg.refine_hand_eye.depth;
    let mut refined_cell = cell.clone();
    let mut results = Vec::with_capacity(cell.robots.len());
    for robot in &mut refined_cell.robots {
        progress(&format!(
            "refining the hand-eye of {} from its depth",
            robot.name
        ));
        let r = refine_hand_eye_from_depth(robot, None, hand_eye)?;
        if r.median_after_m <= r.median_before_m {
            robot.t_ee_cam = r.t_ee_cam;
            if r.trusted {
                let sd = |k: usize| r.covariance[(k, k)].max(0.0).sqrt();
                robot.uncertainty.hand_eye_rotation_rad = sd(0).max(sd(1)).max(sd(2));
                robot.uncertainty.hand_eye_translation_m = sd(3).max(sd(4)).max(sd(5));
            }
        }
        results.push(r);
    }
    // The refined hand-eyes are what the depth says: the check of the stated ones does not apply.
    let mut ccfg = cfg.clone();
    ccfg.hand_eye_check.enabled = false;
    let (mut c, fused) =
        calibrate_with_method(&refined_cell, method, inputs, &ccfg, refine, progress)?;
    for r in &results {
        if !r.trusted {
            c.trust.trusted = false;
            c.trust.reasons.extend(r.reasons.iter().cloned());
            for s in &r.suggestions {
                if !c.trust.suggestions.contains(s) {
                    c.trust.suggestions.push(s.clone());
                }
            }
        }
    }
    let mut joint = None;
    let mut adopted = false;
    if cfg.refine_hand_eye.joint {
        progress("refining both hand-eyes and the base-to-base transform together");
        let (r, o) = refined_cell.robot_pair()?;
        let j = refine_jointly([r, o], &c.transform, &cfg.refine_hand_eye)?;
        if cfg.refine_hand_eye.adopt_joint_base && j.trusted {
            let truth = cell.ground_truth()?.and_then(|g| g.t_base1_base2);
            c.transform = j.t_base1_base2;
            c.covariance = j.base_covariance;
            c.error_vs_truth = truth.map(|t| pose_error(&c.transform, &t));
            c.normalised_error = truth.and_then(|t| {
                crate::calibration::uncertainty::normalised_error(&c.transform, &t, &c.covariance)
            });
            adopted = true;
        }
        joint = Some(j);
    }
    Ok((
        c,
        fused,
        HandEyeRefinement {
            robots: results,
            joint,
            joint_base_adopted: adopted,
        },
    ))
}
