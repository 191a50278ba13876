//! [`calibrate_hand_eye`] as named stages: every closed form ([`closed_forms`]) → the least-median-of-squares
//! start ([`lmeds_start`]) → the robust two-pass refinement with outlier rejection ([`robust_refinement`]) →
//! per-frame residuals and warnings ([`frame_report`], [`fit_warnings`]) → the board and the residual scales.

use super::{
    check_motions, convention_hint, frame_residuals, lmeds, motion_pairs, refine, robust_score,
    robust_sigmas, solve_closed_form, validate_frames, ClosedFormResult, FrameResidual,
    HandEyeConfig, HandEyeFrame, HandEyeMethod, HandEyeResult, HandEyeSigma, Motion,
};
use crate::calibration::average::{average_poses, AverageConfig};
use crate::error::{Error, Result};
use crate::stats::{median, rms};
use nalgebra::Isometry3;
use refine::Kernel;

/// A candidate solution: its robust score (metres), the method it came from, `T_ee_cam` and `T_base_board`.
type Candidate = (f64, HandEyeMethod, Isometry3<f64>, Isometry3<f64>);

/// Hand-eye calibration: every closed form, the best as a start, joint robust refinement with outlier
/// rejection, residuals, and the board pose in the base. See the module documentation of
/// [`crate::calibration::handeye`] for the conventions.
///
/// Errors for fewer than 3 frames, NaN or implausible poses, motions that cannot determine the answer
/// (no rotation, all rotations about one axis) or robot and camera motions that clearly disagree.
pub fn calibrate_hand_eye(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
) -> Result<HandEyeResult> {
    config.validate()?;
    validate_frames(frames, config)?;
    let motions = motion_pairs(frames, config.max_pairs);
    let (excitation, mut warnings) = check_motions(&motions, config)?;
    let lever = median(
        &frames
            .iter()
            .map(|f| f.t_cam_board.translation.vector.norm())
            .collect::<Vec<_>>(),
    )
    .max(0.01);

    let (closed_forms, best) = closed_forms(frames, &motions, config, lever, &mut warnings);
    let Some(best) = best else {
        return Err(Error::Failed(format!(
            "hand-eye method {} failed on these frames",
            config.method
        )));
    };
    let (method, from_lmeds, x, z) = lmeds_start(frames, config, lever, best);
    let refined = if config.refine {
        robust_refinement(frames, config, x, z, &mut warnings)
    } else {
        Refinement::none(frames.len(), x, z)
    };
    let (x, z) = (refined.t_ee_cam, refined.t_base_board);
    let residuals = frame_report(frames, &x, &z, &refined);
    fit_warnings(frames, config, lever, &x, &z, &residuals, &mut warnings);
    let board_poses: Vec<Isometry3<f64>> = frames
        .iter()
        .zip(&refined.rejected)
        .filter(|(_, r)| !**r)
        .map(|(f, _)| f.t_base_ee * x * f.t_cam_board)
        .collect();
    let board = average_poses(&board_poses, None, &AverageConfig::default())?;
    let (sigma_rotation_deg, sigma_translation_mm) = inlier_scales(&residuals);
    let rejected = residuals
        .iter()
        .filter(|r| r.rejected)
        .map(|r| r.frame.clone())
        .collect();
    Ok(HandEyeResult {
        t_ee_cam: x,
        t_base_board: z,
        method,
        from_lmeds,
        refined: config.refine,
        residuals,
        rejected,
        closed_forms,
        excitation,
        board,
        sigma_rotation_deg,
        sigma_translation_mm,
        t_ee_cam_sigma: refined.sigma,
        iterations: refined.iterations,
        converged: refined.converged,
        warnings,
    })
}

/// Solves every closed form, with its fit over all frames; returns them and the best-scoring one among the
/// methods asked for (all of them for `auto`). A method's failure becomes a warning.
fn closed_forms(
    frames: &[HandEyeFrame],
    motions: &[Motion],
    config: &HandEyeConfig,
    lever: f64,
    warnings: &mut Vec<String>,
) -> (Vec<ClosedFormResult>, Option<Candidate>) {
    let mut results = Vec::new();
    let mut best: Option<Candidate> = None;
    for m in HandEyeMethod::CLOSED_FORMS {
        match solve_closed_form(m, frames, motions) {
            Ok((x, z)) => {
                let r = frame_residuals(frames, &x, &z);
                let rd: Vec<f64> = r.iter().map(|p| p.0.to_degrees()).collect();
                let tm: Vec<f64> = r.iter().map(|p| p.1 * 1e3).collect();
                results.push(ClosedFormResult {
                    method: m,
                    t_ee_cam: Some(x),
                    t_base_board: Some(z),
                    rotation_median_deg: median(&rd),
                    translation_median_mm: median(&tm),
                    rotation_rms_deg: rms(&rd),
                    translation_rms_mm: rms(&tm),
                    error: None,
                });
                let score = robust_score(frames, &x, &z, lever);
                let wanted = config.method == HandEyeMethod::Auto || config.method == m;
                if wanted && best.as_ref().is_none_or(|b| score < b.0) {
                    best = Some((score, m, x, z));
                }
            }
            Err(e) => {
                warnings.push(format!("{m}: {e}"));
                results.push(ClosedFormResult {
                    method: m,
                    t_ee_cam: None,
                    t_base_board: None,
                    rotation_median_deg: f64::NAN,
                    translation_median_mm: f64::NAN,
                    rotation_rms_deg: f64::NAN,
                    translation_rms_mm: f64::NAN,
                    error: Some(e.to_string()),
                });
            }
        }
    }
    (results, best)
}

/// The starting point of the refinement: the best closed form, or the least-median-of-squares search over
/// frame triples when it scores better (only for `auto` with refinement). Returns the method, whether the
/// search won, `T_ee_cam` and `T_base_board`.
fn lmeds_start(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
    lever: f64,
    best: Candidate,
) -> (HandEyeMethod, bool, Isometry3<f64>, Isometry3<f64>) {
    let (score, method, x, z) = best;
    if config.method == HandEyeMethod::Auto && config.refine {
        if let Some((s, lx, lz)) = lmeds(frames, config, lever) {
            if s < score {
                return (method, true, lx, lz);
            }
        }
    }
    (method, false, x, z)
}

/// What the robust refinement produced.
struct Refinement {
    /// The refined `T_ee_cam`, metres.
    t_ee_cam: Isometry3<f64>,
    /// The refined `T_base_board`, metres.
    t_base_board: Isometry3<f64>,
    /// Per frame: rejected as an outlier.
    rejected: Vec<bool>,
    /// Per frame: the whitened residual norm under the inliers' scales (0 without refinement).
    normalized: Vec<f64>,
    /// Levenberg-Marquardt iterations of both passes.
    iterations: usize,
    /// Whether the second pass converged (`true` without refinement).
    converged: bool,
    /// 1-σ of `T_ee_cam` from the inliers (`None` without refinement).
    sigma: Option<HandEyeSigma>,
}

impl Refinement {
    /// The start taken as it is (refinement off).
    fn none(n: usize, x: Isometry3<f64>, z: Isometry3<f64>) -> Self {
        Self {
            t_ee_cam: x,
            t_base_board: z,
            rejected: vec![false; n],
            normalized: vec![0.0; n],
            iterations: 0,
            converged: true,
            sigma: None,
        }
    }
}

/// The whitened norm of a `(rotation rad, translation m)` residual under per-axis scales: the norm of a 6-D
/// vector, `√((θ/σ_r)² + (d/σ_t)²)`.
fn whitened(r: &(f64, f64), sr: f64, st: f64) -> f64 {
    ((r.0 / sr).powi(2) + (r.1 / st).powi(2)).sqrt()
}

/// Two Levenberg-Marquardt passes over all of `T_ee_cam` and `T_base_board`: with a Cauchy kernel on every
/// frame, then, after [`reject_outliers`], with a Huber kernel on the inliers. The residual scales of each
/// pass are the robust ones of its start.
fn robust_refinement(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
    x: Isometry3<f64>,
    z: Isometry3<f64>,
    warnings: &mut Vec<String>,
) -> Refinement {
    let n = frames.len();
    let all = vec![true; n];
    let (sr, st) = robust_sigmas(&frame_residuals(frames, &x, &z));
    let p1 = refine::refine(
        frames,
        &all,
        &x,
        &z,
        sr,
        st,
        Kernel::Cauchy(config.cauchy_width),
        config.max_iterations,
    );
    let (x, z) = (p1.t_ee_cam, p1.t_base_board);
    let res = frame_residuals(frames, &x, &z);
    let rejected = reject_outliers(&res, config, warnings);
    let active: Vec<bool> = rejected.iter().map(|r| !r).collect();
    let inliers: Vec<(f64, f64)> = res
        .iter()
        .zip(&active)
        .filter(|(_, a)| **a)
        .map(|(r, _)| *r)
        .collect();
    let (sr2, st2) = robust_sigmas(&inliers);
    let p2 = refine::refine(
        frames,
        &active,
        &x,
        &z,
        sr2,
        st2,
        Kernel::Huber(config.outlier_threshold),
        config.max_iterations,
    );
    let (x, z) = (p2.t_ee_cam, p2.t_base_board);
    let normalized = frame_residuals(frames, &x, &z)
        .iter()
        .map(|r| whitened(r, sr2, st2))
        .collect();
    let sigma =
        refine::hand_eye_sigma(frames, &active, &x, &z, sr2, st2).map(|(r, t)| HandEyeSigma {
            rotation_deg: r.to_degrees(),
            translation_mm: t * 1e3,
        });
    if !p2.converged {
        warnings.push(format!(
            "the refinement did not converge in {} iterations",
            config.max_iterations
        ));
    }
    Refinement {
        t_ee_cam: x,
        t_base_board: z,
        rejected,
        normalized,
        iterations: p1.iterations + p2.iterations,
        converged: p2.converged,
        sigma,
    }
}

/// Marks outlier frames: a whitened residual above [`HandEyeConfig::outlier_threshold`] (under the robust
/// scales of `res`) or above the absolute limits. At least `max(3, ⌈n/2⌉)` frames are kept: the worst are
/// rejected first, and a warning says when not every outlier could be.
fn reject_outliers(
    res: &[(f64, f64)],
    config: &HandEyeConfig,
    warnings: &mut Vec<String>,
) -> Vec<bool> {
    let n = res.len();
    let (sr, st) = robust_sigmas(res);
    let mut order: Vec<(f64, usize)> = Vec::new();
    for (i, r) in res.iter().enumerate() {
        let e = whitened(r, sr, st);
        let abs_bad = config
            .max_rotation_residual_deg
            .is_some_and(|m| r.0.to_degrees() > m)
            || config
                .max_translation_residual_mm
                .is_some_and(|m| r.1 * 1e3 > m);
        if e > config.outlier_threshold || abs_bad {
            order.push((e, i));
        }
    }
    let keep_min = 3.max(n.div_ceil(2));
    order.sort_by(|a, b| b.0.total_cmp(&a.0));
    let can_reject = n.saturating_sub(keep_min);
    if order.len() > can_reject {
        warnings.push(format!(
            "{} of {n} frames look like outliers; only the worst {can_reject} are rejected",
            order.len()
        ));
    }
    let mut rejected = vec![false; n];
    for (_, i) in order.iter().take(can_reject) {
        rejected[*i] = true;
    }
    rejected
}

/// Per-frame residuals of the answer, in input order, with the refinement's whitened norms and rejections.
fn frame_report(
    frames: &[HandEyeFrame],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    refined: &Refinement,
) -> Vec<FrameResidual> {
    frames
        .iter()
        .zip(frame_residuals(frames, x, z))
        .enumerate()
        .map(|(i, (f, r))| FrameResidual {
            frame: f.id.clone(),
            rotation_deg: r.0.to_degrees(),
            translation_mm: r.1 * 1e3,
            normalized: refined.normalized[i],
            rejected: refined.rejected[i],
        })
        .collect()
}

/// Warnings about the answer: which frames were rejected, and a poor fit of the inliers (with a hint when
/// another pose convention fits far better).
fn fit_warnings(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
    lever: f64,
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    residuals: &[FrameResidual],
    warnings: &mut Vec<String>,
) {
    let list: Vec<String> = residuals
        .iter()
        .filter(|r| r.rejected)
        .map(|r| {
            format!(
                "{} ({:.2}°, {:.1} mm)",
                r.frame, r.rotation_deg, r.translation_mm
            )
        })
        .collect();
    if !list.is_empty() {
        warnings.push(format!(
            "rejected {} outlier frame(s): {}",
            list.len(),
            list.join(", ")
        ));
    }
    let inl: Vec<&FrameResidual> = residuals.iter().filter(|r| !r.rejected).collect();
    let mr = median(&inl.iter().map(|r| r.rotation_deg).collect::<Vec<_>>());
    let mt = median(&inl.iter().map(|r| r.translation_mm).collect::<Vec<_>>());
    if mr > config.warn_residual_deg || mt > config.warn_residual_mm {
        let mine = robust_score(frames, x, z, lever);
        let hint = convention_hint(frames, config, lever, mine);
        warnings.push(format!(
            "the solution fits poorly (median residual {mr:.2}°, {mt:.1} mm): check that the robot poses \
             are T_base_ee (flange in base) and the target poses T_cam_board (board in camera){hint}"
        ));
    }
}

/// The residual scale of the inlier frames, RMS per axis: `(rotation degrees, translation millimetres)`.
fn inlier_scales(residuals: &[FrameResidual]) -> (f64, f64) {
    let inl: Vec<&FrameResidual> = residuals.iter().filter(|r| !r.rejected).collect();
    let k = inl.len().max(1) as f64;
    (
        (inl.iter().map(|r| r.rotation_deg.powi(2)).sum::<f64>() / (3.0 * k)).sqrt(),
        (inl.iter().map(|r| r.translation_mm.powi(2)).sum::<f64>() / (3.0 * k)).sqrt(),
    )
}
