//! Robot-to-robot calibration of a cell: fuse each robot's frames in its base frame, get an initial
//! `T_base1_base2` from an [`Initializer`], refine it with trimmed robust ICP, and report its quality.

use crate::calibration::consistency::{robot_consistency, RobotConsistency};
use crate::calibration::handeye::depth::check::HandEyeCheck;
use crate::calibration::hypotheses::{
    choose, refine_and_judge, without_robot_bodies, FreeSpaceTest,
};
use crate::calibration::initializer::{InitialGuess, Initializer, InitializerInput};
use crate::calibration::pose_scatter::PoseScatter;
use crate::calibration::uncertainty::{
    cloud_motion_covariance, inputs_covariance, normalised_error, NormalisedError,
};
use crate::cell::{Cell, CellRobot};
use crate::error::Result;
use crate::geometry::transform::pose_error;
use crate::registration::pipeline::recheck_weak_directions;
use crate::registration::quality::Degeneracy;
use crate::registration::Trust;
use crate::registration::{PreparedLevels, RegisterConfig};
use crate::timing::StageTimer;
use nalgebra::{Isometry3, Matrix6};

pub use crate::calibration::config::CalibrateConfig;
pub use crate::calibration::fused::{fuse_cell, fuse_robots, FusedCell, FusedRobots};
pub use crate::calibration::visibility::FreeSpaceCheck;

/// The result of [`calibrate`].
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The reference robot's name (base1).
    pub reference: String,
    /// The other robot's name (base2).
    pub other: String,
    /// `T_base1_base2`: maps the other robot's base coordinates into the reference robot's base (metres).
    pub transform: Isometry3<f64>,
    /// Covariance of `[rx, ry, rz (rad), tx, ty, tz (m)]`, a left increment in the reference base frame.
    pub covariance: Matrix6<f64>,
    /// The initialiser's estimate before refinement.
    pub initial: InitialGuess,
    /// Initialiser name.
    pub method: String,
    /// Trimmed robust ICP refined the initial estimate (false with `--no-refine`: then the quality
    /// figures below are `None`, `converged` is false and the degeneracy empty).
    pub refined: bool,
    /// Fraction of the other robot's points with a reference point within the final correspondence
    /// distance (`None` when not refined).
    pub fitness: Option<f64>,
    /// RMS distance of those pairs, metres (`None` when not refined).
    pub inlier_rmse: Option<f64>,
    /// Overlap estimated by the trimmed ICP, a fraction (`None` when not refined).
    pub overlap: Option<f64>,
    /// ICP's finest level met its tolerances (after a second run from where it stopped, when the first ran out).
    pub converged: bool,
    /// Degeneracy analysis of the final ICP.
    pub degeneracy: Degeneracy,
    /// Priors used, in words.
    pub priors_used: Vec<String>,
    /// Fused points per robot (reference, other).
    pub fused_points: [usize; 2],
    /// Frames per robot (reference, other).
    pub frames: [usize; 2],
    /// Errors against `ground_truth.json` when the cell has one: (degrees, metres).
    pub error_vs_truth: Option<(f64, f64)>,
    /// The same for the initial estimate.
    pub initial_error_vs_truth: Option<(f64, f64)>,
    /// Wall time per stage, milliseconds.
    pub timings_ms: Vec<(String, f64)>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
    /// The priors were assumed (the cell did not state them), not read.
    pub priors_assumed: bool,
    /// Free-space violation of the final transform (mean of both ways, 0–1) and the margin used (m),
    /// when the fused clouds carry their depth views.
    pub free_space: Option<FreeSpaceCheck>,
    /// A far-away second answer of the initialiser that scored almost as well, if any.
    pub ambiguity: Option<crate::registration::pipeline::Ambiguity>,
    /// Whether the result can be trusted, and why not.
    pub trust: Trust,
    /// The part of `covariance` that the cell's inputs (hand-eyes, pose repeatability, depth scale) add
    /// ([`crate::calibration::uncertainty`]).
    pub inputs_covariance: Matrix6<f64>,
    /// The error against the ground truth normalised by `covariance`, when the cell has a truth.
    pub normalised_error: Option<NormalisedError>,
    /// Each robot's own frames against each other (reference, other), when the clouds were fused.
    pub consistency: Vec<RobotConsistency>,
    /// Each robot's stated hand-eye against its own depth frames (reference, other), when the clouds were
    /// fused and `hand_eye_check.enabled`.
    pub hand_eye_checks: Vec<HandEyeCheck>,
    /// The refinement's ICP levels, coarse to fine, with each iteration's residuals (metres) and inliers
    /// (empty when not refined).
    pub icp_levels: Vec<crate::registration::IcpLevelTrace>,
    /// The hypotheses the refinement refined and judged at full resolution, in the initialiser's order
    /// ([`crate::calibration::hypotheses`]): one for an initialiser with one answer, none without
    /// refinement.
    pub hypotheses: Vec<crate::calibration::hypotheses::JudgedSummary>,
    /// Each robot's pose scatter from its own frames (reference, other), when the clouds were fused and
    /// `pose_scatter.enabled`.
    pub pose_scatter: Vec<PoseScatter>,
}

#[cfg(test)]
impl Calibration {
    /// A result of `reference` and `other` at the identity with a zero covariance, trusted, for unit tests
    /// of what consumes results.
    pub(crate) fn empty_for_tests(reference: &str, other: &str) -> Self {
        Calibration {
            reference: reference.into(),
            other: other.into(),
            transform: Isometry3::identity(),
            covariance: Matrix6::zeros(),
            initial: InitialGuess {
                transform: Isometry3::identity(),
                sigma_rotation_deg: 1.0,
                sigma_translation_m: 0.01,
                detail: String::new(),
                ambiguity: None,
                alternatives: Vec::new(),
            },
            method: "depth".into(),
            refined: true,
            fitness: None,
            inlier_rmse: None,
            overlap: None,
            converged: true,
            degeneracy: Degeneracy {
                condition: f64::NAN,
                weak: Vec::new(),
                held: Vec::new(),
                free_below: f64::INFINITY,
            },
            priors_used: Vec::new(),
            fused_points: [0, 0],
            frames: [0, 0],
            error_vs_truth: None,
            initial_error_vs_truth: None,
            timings_ms: Vec::new(),
            warnings: Vec::new(),
            priors_assumed: false,
            free_space: None,
            ambiguity: None,
            trust: Trust::new(),
            inputs_covariance: Matrix6::zeros(),
            normalised_error: None,
            consistency: Vec::new(),
            hand_eye_checks: Vec::new(),
            icp_levels: Vec::new(),
            hypotheses: Vec::new(),
            pose_scatter: Vec::new(),
        }
    }
}

/// What to calibrate and how: the one entry point [`calibrate_request`] takes it; [`calibrate`] is the
/// common case.
pub struct CalibrateRequest<'a> {
    /// The cell dataset.
    pub cell: &'a Cell,
    /// Where the first estimate of `T_base1_base2` comes from.
    pub initializer: &'a dyn Initializer,
    /// The settings.
    pub config: &'a CalibrateConfig,
    /// Refine the initialiser's estimate with trimmed robust ICP (default true). Without it the result is
    /// the initialiser's estimate and its 1-σ (`calibrate --no-refine`), and an initialiser that does not
    /// need the clouds ([`Initializer::needs_clouds`]) fuses none.
    pub refine: bool,
    /// Called with a stage description as each stage starts.
    pub progress: Option<&'a mut dyn FnMut(&str)>,
}

impl<'a> CalibrateRequest<'a> {
    /// The cell with `initializer` under `config`, refined, without progress reports.
    pub fn new(
        cell: &'a Cell,
        initializer: &'a dyn Initializer,
        config: &'a CalibrateConfig,
    ) -> Self {
        CalibrateRequest {
            cell,
            initializer,
            config,
            refine: true,
            progress: None,
        }
    }
}

/// Calibrates the cell: `T_base1_base2` between the reference robot and the other robot.
///
/// `progress` is called with a stage description as each stage starts. The same as [`calibrate_request`]
/// with refinement, without the fused clouds.
pub fn calibrate(
    cell: &Cell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let mut req = CalibrateRequest::new(cell, initializer, cfg);
    req.progress = Some(progress);
    calibrate_request(req).map(|(c, _)| c)
}

/// Calibrates the cell as `req` asks: fuse → initialise → refine (unless `req.refine` is false) → the
/// checks. Returns the result and the fused clouds it registered (each in its own robot's base frame, e.g.
/// to write them out; empty when none were needed).
pub fn calibrate_request(req: CalibrateRequest) -> Result<(Calibration, FusedCell)> {
    let CalibrateRequest {
        cell,
        initializer,
        config: cfg,
        refine,
        progress,
    } = req;
    let mut quiet = |_: &str| {};
    let progress: &mut dyn FnMut(&str) = match progress {
        Some(p) => p,
        None => &mut quiet,
    };
    cfg.validate()?;
    let fuse = refine || initializer.needs_clouds();
    let fused = if fuse {
        if refine {
            let (reference, other) = cell.robot_pair()?;
            progress(&format!(
                "fusing {} frames of {} and {} of {}",
                reference.frames.len(),
                reference.name,
                other.frames.len(),
                other.name
            ));
        } else {
            progress("fusing both robots' frames");
        }
        fuse_cell(cell, cfg)?
    } else {
        FusedCell::without_clouds(cell, cfg)?
    };
    let mut c = refine_cell(cell, &fused, initializer, cfg, refine, progress)?;
    // One pair is calibrated; a robot beyond it is named, not dropped in silence.
    let left_out: Vec<&str> = cell
        .robots
        .iter()
        .map(|r| r.name.as_str())
        .filter(|n| *n != c.reference && *n != c.other)
        .collect();
    if !left_out.is_empty() {
        c.warnings.push(format!(
            "the cell names {} robots and this call solves one pair: {:?} against the reference {:?}; not calibrated: {:?} (`depthcal calibrate` and calibration::multi_robot solve every robot)",
            cell.robots.len(),
            c.other,
            c.reference,
            left_out
        ));
    }
    if fuse {
        c.timings_ms.insert(0, ("fuse".into(), fused.fuse_ms));
        if !fused.pose_scatter.is_empty() {
            c.timings_ms
                .insert(1, ("pose_scatter".into(), fused.pose_scatter_ms));
        }
        if !fused.hand_eye_checks.is_empty() {
            let at = c.timings_ms.len().min(2);
            c.timings_ms
                .insert(at, ("hand_eye_check".into(), fused.hand_eye_check_ms));
        }
    }
    Ok((c, fused))
}

/// Runs `initializer` on the fused cell (the timings exclude the fusion) and, when `refine` is set, refines its estimate with trimmed robust
/// ICP; without refinement the result is the initial estimate with a covariance from its stated 1-σ and
/// no cloud quality figures (NaN).
pub fn refine_cell(
    cell: &Cell,
    fused: &FusedCell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    refine: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let pair = match fused.robots.as_slice() {
        [a, b] => (a, b),
        _ => cell.robot_pair()?,
    };
    let truth = cell.ground_truth()?.and_then(|g| g.t_base1_base2);
    refine_pair(pair, fused, initializer, cfg, refine, truth, progress)
}

/// [`refine_cell`] for any two robots of a cell: `pair` is (the pair's reference, the other) as fused in
/// `fused`, `truth` their true `T_reference_other` when known.
pub fn refine_pair(
    pair: (&CellRobot, &CellRobot),
    fused: &FusedCell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    refine: bool,
    truth: Option<Isometry3<f64>>,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let (reference, other) = pair;
    let mut timer = StageTimer::new();
    let priors = fused.priors.constraint();
    // The search also drops hypotheses whose bases would share one footprint.
    let constraint = priors.clone().with_min_translation(cfg.min_base_distance_m);
    let (ref_cloud, other_cloud) = (&fused.reference, &fused.other);
    progress(&format!("initialising ({})", initializer.name()));
    let initial = initializer.initialize(&InitializerInput {
        reference: ref_cloud,
        other: other_cloud,
        constraint: &constraint,
        seed: cfg.seed,
    })?;
    timer.lap("initialize");
    let mut out = Calibration {
        reference: reference.name.clone(),
        other: other.name.clone(),
        transform: initial.transform,
        covariance: initial.covariance(),
        method: initializer.name().to_string(),
        refined: false,
        fitness: None,
        inlier_rmse: None,
        overlap: None,
        converged: false,
        degeneracy: Degeneracy {
            condition: f64::NAN,
            weak: Vec::new(),
            held: Vec::new(),
            free_below: f64::INFINITY,
        },
        priors_used: fused.priors.describe(),
        fused_points: [ref_cloud.cloud.len(), other_cloud.cloud.len()],
        frames: [reference.frames.len(), other.frames.len()],
        error_vs_truth: truth.map(|t| pose_error(&initial.transform, &t)),
        initial_error_vs_truth: truth.map(|t| pose_error(&initial.transform, &t)),
        ambiguity: initial.ambiguity.clone(),
        initial,
        timings_ms: Vec::new(),
        warnings: Vec::new(),
        priors_assumed: fused.priors.level_assumed() && cfg.use_priors,
        free_space: None,
        trust: Trust::new(),
        inputs_covariance: Matrix6::zeros(),
        normalised_error: None,
        consistency: Vec::new(),
        hand_eye_checks: fused.hand_eye_checks.clone(),
        icp_levels: Vec::new(),
        hypotheses: Vec::new(),
        pose_scatter: fused.pose_scatter.clone(),
    };
    if !ref_cloud.views.is_empty() && !other_cloud.views.is_empty() {
        let (a, b) = rayon::join(
            || robot_consistency(reference, ref_cloud, &cfg.consistency),
            || robot_consistency(other, other_cloud, &cfg.consistency),
        );
        out.consistency = vec![a, b];
        timer.lap("consistency");
    }
    let inputs = |t: &nalgebra::Isometry3<f64>| {
        inputs_covariance(
            t,
            &cloud_motion_covariance(reference, &ref_cloud.views),
            &cloud_motion_covariance(other, &other_cloud.views),
        )
    };
    if !refine {
        out.inputs_covariance = inputs(&out.transform);
        out.covariance += out.inputs_covariance;
        out.normalised_error =
            truth.and_then(|t| normalised_error(&out.transform, &t, &out.covariance));
        out.trust = calibration_trust(&out, &priors, cfg.min_base_distance_m, None);
        out.timings_ms = timer.wall_ms();
        return Ok(out);
    }
    progress("refining (trimmed robust ICP)");
    let mut rcfg = cfg.register.clone();
    rcfg.seed = cfg.seed;
    // The hold test of weak directions runs once, on the answer kept (below), not on every hypothesis:
    // these only collect its candidates.
    rcfg.degeneracy_threshold = cfg.register.degeneracy_candidate_threshold();
    rcfg.degeneracy_slide_voxels = 0.0;
    // The initialiser's answer and its alternatives, each refined and judged at full resolution.
    let starts: Vec<nalgebra::Isometry3<f64>> = std::iter::once(out.initial.transform)
        .chain(out.initial.alternatives.iter().copied())
        .collect();
    let test = FreeSpaceTest::new(fused, &cfg.visibility);
    // The hypotheses' clouds are often the very same points: their levels are prepared once.
    let prepared = PreparedLevels::new();
    let mut judged = refine_and_judge(
        fused,
        &starts,
        &rcfg,
        &cfg.visibility,
        test.as_ref(),
        &prepared,
    )?;
    let summaries: Vec<_> = judged
        .iter()
        .map(|j| j.summary(cfg.visibility.choice_penalty_scale))
        .collect();
    let (best, rival) = choose(&summaries, judged[0].registration.voxel, &rcfg);
    for (k, j) in judged.iter().enumerate() {
        log::info!(
            "hypothesis {k}{}: score {:.3}, agreement {:.3}, fitness {:.3}, free space {}{}",
            if k == best { " (chosen)" } else { "" },
            summaries[k].score,
            j.agreement(),
            j.registration.fitness,
            j.free_space
                .as_ref()
                .map_or("untested".to_string(), |f| format!(
                    "{:.1}%",
                    f.violation * 1e2
                )),
            truth.map_or(String::new(), |t| {
                let (r, m) = pose_error(&j.registration.transform, &t);
                format!(", {r:.3}° / {:.2} mm from the truth", m * 1e3)
            })
        );
    }
    // The search's own coarse ambiguity gives way to the judgement at full resolution.
    out.ambiguity = rival;
    out.hypotheses = summaries;
    out.hypotheses[best].chosen = true;
    let mut chosen = judged.swap_remove(best);
    // A refinement that ran out of iterations gets them: once more, from where it stopped, with the whole
    // budget again. Its answer replaces the first only if it converged; otherwise the result stays
    // unconverged (and untrusted).
    if !chosen.registration.converged {
        let from = chosen.registration.transform;
        let again = refine_and_judge(
            fused,
            &[from],
            &rcfg,
            &cfg.visibility,
            test.as_ref(),
            &prepared,
        )?;
        if let Some(j) = again.into_iter().next() {
            let (r, m) = pose_error(&j.registration.transform, &from);
            log::info!(
                "the chosen hypothesis ran out of ICP iterations; continued: moved {r:.4}° / {:.3} mm, converged {}",
                m * 1e3,
                j.registration.converged
            );
            if j.registration.converged {
                chosen = j;
            }
        }
    }
    let mut reg = chosen.registration;
    if reg.degeneracy.is_degenerate() {
        let (reference, other) = without_robot_bodies(fused, &chosen.start, &cfg.visibility);
        let hold = RegisterConfig {
            degeneracy_slide_voxels: cfg.register.degeneracy_slide_voxels,
            degeneracy_threshold: cfg.register.degeneracy_threshold,
            ..rcfg.clone()
        };
        recheck_weak_directions(&mut reg, other, reference, &hold, Some(&prepared))?;
    }
    timer.lap("refine");
    out.warnings = reg.warnings.clone();
    out.transform = reg.transform;
    out.inputs_covariance = inputs(&reg.transform);
    out.covariance = reg.covariance + out.inputs_covariance;
    out.normalised_error =
        truth.and_then(|t| normalised_error(&out.transform, &t, &out.covariance));
    out.refined = true;
    out.fitness = Some(reg.fitness);
    out.inlier_rmse = Some(reg.inlier_rmse);
    out.overlap = Some(reg.overlap);
    out.converged = reg.converged;
    out.degeneracy = reg.degeneracy;
    out.error_vs_truth = truth.map(|t| pose_error(&reg.transform, &t));
    out.free_space = chosen.free_space;
    out.icp_levels = reg.icp_levels;
    timer.lap("checks");
    out.trust = calibration_trust(&out, &priors, cfg.min_base_distance_m, Some(&reg.trust));
    let spread = crate::calibration::precision::Spread::of(&reg.covariance);
    if let Some(why) = spread.excess(cfg.max_registration_sigma_deg, cfg.max_registration_sigma_m) {
        out.trust.fail(
            why,
            "capture views of more distinct objects both robots see, or give an initialiser (--method marker|checkerboard|features)",
        );
    }
    out.timings_ms = timer.wall_ms();
    Ok(out)
}

/// The quality gate of a calibration: the registration's own checks, the priors, the bases' distance
/// (`min_base_distance_m`, metres), the initialiser's ambiguity and the free-space test.
fn calibration_trust(
    c: &Calibration,
    constraint: &crate::registration::PoseConstraint,
    min_base_distance_m: f64,
    registration: Option<&Trust>,
) -> Trust {
    let mut t = Trust::new();
    if let Some(r) = registration {
        t.merge(r);
    }
    let distance = c.transform.translation.vector.norm();
    if distance < min_base_distance_m {
        t.fail(
            format!(
                "robot {:?}'s base would stand {:.3} m from robot {:?}'s, closer than two robots' bases can (min_base_distance_m {:.2} m)",
                c.other, distance, c.reference, min_base_distance_m
            ),
            "capture views of the part of the workspace both robots see, or state [priors] base_distance_m in cell.toml",
        );
    }
    if !constraint.is_empty() && !constraint.accepts(&c.transform) {
        let z = c.transform.rotation * nalgebra::Vector3::z();
        t.fail(
            format!(
                "the result violates the priors ({}): tilt {:.2}°, base distance {:.3} m",
                c.priors_used.join(", "),
                z.z.clamp(-1.0, 1.0).acos().to_degrees(),
                c.transform.translation.vector.norm()
            ),
            "check [priors] in cell.toml; if a base really is tilted, state bases_level = false (or use --no-priors)",
        );
    }
    for r in c.consistency.iter().filter(|r| !r.consistent) {
        t.fail(
            format!(
                "robot {:?}'s own frames are not consistent: {}",
                r.robot,
                r.findings.join("; ")
            ),
            format!(
                "check robot {:?}'s intrinsics (focal length, principal point, depth scale), hand-eye and pose file",
                r.robot
            ),
        );
    }
    for h in c.hand_eye_checks.iter().filter(|h| !h.consistent) {
        t.fail(h.reason(), h.suggestion());
    }
    if let Some(a) = &c.ambiguity {
        let what = if c.refined {
            format!(
                "a second answer {:.2}° / {:.1} mm away, refined at full resolution, explains the data {:.0}% as well (surface agreement over the surfaces' directions, weighed by the free-space test: {:.3} against {:.3}) and passes the free-space test",
                a.rotation_deg,
                a.translation * 1e3,
                a.score_ratio * 1e2,
                a.score_ratio * a.best_score,
                a.best_score
            )
        } else {
            format!(
                "a second answer {:.2}° / {:.1} mm from the initial estimate scores {:.0}% of it in the global stage's verification",
                a.rotation_deg,
                a.translation * 1e3,
                a.score_ratio * 1e2
            )
        };
        t.fail(
            format!("ambiguous: {what}"),
            "give an initialiser (--method marker|checkerboard|features or --init), a crop box around the shared part, or more views of distinctive shared objects",
        );
    }
    if let Some(f) = &c.free_space {
        if !f.passes() {
            t.fail(
                format!(
                    "free-space test failed: {:.1}% of the surfaces land where the other robot's cameras saw through them or saw them from behind (each robot's own frames: {:.1}%)",
                    f.violation * 1e2,
                    f.own_violation * 1e2
                ),
                "the clouds overlap in a wrong pose: try an initialiser (--init or an image method) and check the hand-eyes and intrinsics",
            );
        }
    }
    t
}
