//! The report of `calibrate`: [`CalibrationReport`].

use super::pose::{matrix6_rows, AmbiguityReport, ErrorReport, PoseReport, SigmaReport, Timings};
use crate::calibration::consistency::RobotConsistency;
use crate::calibration::handeye::depth::check::HandEyeCheck;
use crate::calibration::multi_robot::CellCalibration;
use crate::calibration::robot_to_robot::{Calibration, FreeSpaceCheck};
use crate::calibration::uncertainty::NormalisedError;
use crate::geometry::robot_formats::{ros2_static_tf_command, Frames};
use crate::registration::quality::Degeneracy;
use serde::Serialize;

/// The schema name and version of [`CalibrationReport`].
pub const CALIBRATION_SCHEMA: &str = "depthcal.calibration/1";

/// The covariance rows' meaning in a calibration.
pub const CALIBRATION_COVARIANCE_PARAMETERS: &str =
    "[rx, ry, rz (rad), tx, ty, tz (m)], left increment in the reference base frame";

/// The initialiser's estimate.
#[derive(Clone, Debug, Serialize)]
pub struct InitialReport {
    /// `T_base1_base2` before refinement.
    pub transform: PoseReport,
    /// How it was obtained.
    pub detail: String,
    /// Its stated 1-σ rotation, degrees.
    pub sigma_rotation_deg: f64,
    /// Its stated 1-σ translation, metres.
    pub sigma_translation_m: f64,
    /// Its error against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
}

/// A count per robot.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PerRobot {
    /// The reference robot's.
    pub reference: usize,
    /// The other robot's.
    pub other: usize,
}

/// The ROS frame ids of the transform.
#[derive(Clone, Debug, Serialize)]
pub struct FrameIds {
    /// The reference robot's base frame.
    pub parent: String,
    /// The other robot's base frame.
    pub child: String,
}

/// The result of a robot-to-robot calibration, as `depthcal calibrate --json` prints it (and
/// `calibrate --output DIR` writes to `calibration.json`). Lengths in metres, angles in degrees.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationReport {
    /// [`CALIBRATION_SCHEMA`].
    pub schema: &'static str,
    /// The cell directory.
    pub cell: String,
    /// The reference robot (base1).
    pub reference: String,
    /// The other robot (base2).
    pub other: String,
    /// The initialiser.
    pub method: String,
    /// `T_base1_base2`: maps the other robot's base coordinates into the reference robot's base.
    pub transform: PoseReport,
    /// Covariance of `[rx, ry, rz (rad), tx, ty, tz (m)]`.
    pub covariance: [[f64; 6]; 6],
    /// What the covariance's rows mean.
    pub covariance_parameters: &'static str,
    /// 1-σ per axis.
    pub sigma: SigmaReport,
    /// ICP refined the initial estimate (false with `--no-refine`: the quality figures are then absent).
    pub refined: bool,
    /// Fraction of the other robot's points with a reference point within the final correspondence
    /// distance, 0–1.
    pub fitness: Option<f64>,
    /// RMS distance of those pairs, metres.
    pub inlier_rmse_m: Option<f64>,
    /// Overlap estimated by the trimmed ICP, 0–1.
    pub overlap: Option<f64>,
    /// ICP's finest level met its tolerances (a coarser level that ran out only handed on its start).
    pub converged: Option<bool>,
    /// A direction of the final ICP is weakly constrained.
    pub degenerate: bool,
    /// The degeneracy analysis.
    pub degeneracy: Degeneracy,
    /// Priors used, in words.
    pub priors_used: Vec<String>,
    /// The priors were assumed, not read from the cell.
    pub priors_assumed: bool,
    /// Whether the result can be trusted.
    pub trusted: bool,
    /// Each failed check, in words.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
    /// The free-space test of the result.
    pub free_space: Option<FreeSpaceCheck>,
    /// A far-away second answer that scored almost as well.
    pub ambiguity: Option<AmbiguityReport>,
    /// The hypotheses refined and judged at full resolution (one for an initialiser with one answer).
    pub hypotheses: Vec<HypothesisReport>,
    /// The initialiser's estimate.
    pub initial: InitialReport,
    /// The error against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
    /// That error normalised by the covariance (about 1 when the covariance is honest).
    pub normalised_error: Option<NormalisedError>,
    /// Each robot's own frames against each other.
    pub consistency: Vec<RobotConsistency>,
    /// Each robot's stated hand-eye and its 1-σ against its own depth frames.
    pub hand_eye_check: Vec<HandEyeCheck>,
    /// Each robot's pose scatter from its own frames, and whether its frames were moved by it.
    pub pose_scatter: Vec<crate::calibration::pose_scatter::PoseScatter>,
    /// The part of the covariance the cell's inputs add (hand-eyes, pose repeatability, depth scale).
    pub inputs_covariance: [[f64; 6]; 6],
    /// Frames per robot.
    pub frames: PerRobot,
    /// Fused points per robot.
    pub fused_points: PerRobot,
    /// The ROS 2 command that publishes the transform.
    pub ros2: String,
    /// The frame ids of the ROS outputs.
    pub frame_ids: FrameIds,
    /// Warnings for the user.
    pub warnings: Vec<String>,
    /// Wall time per stage, milliseconds.
    pub timings_ms: Timings,
    /// Wall time of the whole run, milliseconds.
    pub total_ms: f64,
    /// With `--refine-hand-eye`: each robot's hand-eye refined from its depth frames (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hand_eye_refinement: Option<Vec<super::HandEyeDepthReport>>,
    /// With `--refine-hand-eye` (and `refine_hand_eye.joint`): both hand-eyes and `T_base1_base2` refined
    /// together (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joint_hand_eye: Option<super::JointHandEyeReport>,
    /// Cells of three or more robots: every robot but the reference, its base in the joint solution (absent
    /// for two robots).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robots: Option<Vec<super::robots::RobotBaseReport>>,
    /// Cells of three or more robots: every pair's own result against the joint solution (absent for two
    /// robots).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pairs: Option<Vec<super::robots::PairReport>>,
}

/// One hypothesis the refinement refined and judged at full resolution.
#[derive(Clone, Debug, Serialize)]
pub struct HypothesisReport {
    /// The refined `T_base1_base2`.
    pub transform: PoseReport,
    /// Its surface agreement at the finest level, 0–1.
    pub agreement: f64,
    /// Its refinement's fitness, 0–1.
    pub fitness: f64,
    /// Its free-space violation, 0–1; `None` without depth views.
    pub free_space_violation: Option<f64>,
    /// It passes the free-space test.
    pub passes_free_space: bool,
    /// What the choice ranks by: the agreement weighed by the free-space test.
    pub score: f64,
    /// It is the answer.
    pub chosen: bool,
}

impl HypothesisReport {
    /// From the calibration's summary of a judged hypothesis.
    pub fn new(h: &crate::calibration::hypotheses::JudgedSummary) -> Self {
        HypothesisReport {
            transform: PoseReport::new(&h.transform),
            agreement: h.agreement,
            fitness: h.fitness,
            free_space_violation: h.free_space_violation,
            passes_free_space: h.passes_free_space,
            score: h.score,
            chosen: h.chosen,
        }
    }
}

impl CalibrationReport {
    /// The report of `c` for the cell directory `cell`, with the frame ids of the ROS outputs and the
    /// whole run's wall time (milliseconds).
    pub fn new(c: &Calibration, cell: &str, frames: &Frames, total_ms: f64) -> Self {
        CalibrationReport {
            schema: CALIBRATION_SCHEMA,
            cell: cell.to_string(),
            reference: c.reference.clone(),
            other: c.other.clone(),
            method: c.method.clone(),
            transform: PoseReport::new(&c.transform),
            covariance: matrix6_rows(&c.covariance),
            covariance_parameters: CALIBRATION_COVARIANCE_PARAMETERS,
            sigma: SigmaReport::from_covariance(&c.covariance),
            refined: c.refined,
            fitness: c.fitness,
            inlier_rmse_m: c.inlier_rmse,
            overlap: c.overlap,
            converged: c.refined.then_some(c.converged),
            degenerate: c.degeneracy.is_degenerate(),
            degeneracy: c.degeneracy.clone(),
            priors_used: c.priors_used.clone(),
            priors_assumed: c.priors_assumed,
            trusted: c.trust.trusted,
            reasons: c.trust.reasons.clone(),
            suggestions: c.trust.suggestions.clone(),
            free_space: c.free_space.clone(),
            ambiguity: c.ambiguity.as_ref().map(AmbiguityReport::new),
            hypotheses: c.hypotheses.iter().map(HypothesisReport::new).collect(),
            initial: InitialReport {
                transform: PoseReport::new(&c.initial.transform),
                detail: c.initial.detail.clone(),
                sigma_rotation_deg: c.initial.sigma_rotation_deg,
                sigma_translation_m: c.initial.sigma_translation_m,
                error_vs_truth: ErrorReport::from_opt(c.initial_error_vs_truth),
            },
            error_vs_truth: ErrorReport::from_opt(c.error_vs_truth),
            normalised_error: c.normalised_error,
            consistency: c.consistency.clone(),
            hand_eye_check: c.hand_eye_checks.clone(),
            pose_scatter: c.pose_scatter.clone(),
            inputs_covariance: matrix6_rows(&c.inputs_covariance),
            frames: PerRobot {
                reference: c.frames[0],
                other: c.frames[1],
            },
            fused_points: PerRobot {
                reference: c.fused_points[0],
                other: c.fused_points[1],
            },
            ros2: ros2_static_tf_command(&c.transform, frames),
            frame_ids: FrameIds {
                parent: frames.parent.clone(),
                child: frames.child.clone(),
            },
            warnings: c.warnings.clone(),
            timings_ms: Timings(c.timings_ms.clone()),
            total_ms,
            hand_eye_refinement: None,
            joint_hand_eye: None,
            robots: None,
            pairs: None,
        }
    }

    /// The report of a cell of three or more robots: the two-robot fields show
    /// [`CellCalibration::headline`] (the reference and the first other robot in the joint solution, the
    /// whole cell's trust), `robots` every robot's base and `pairs` every pair. `frame_ids` are the other
    /// robots' base frame ids, in the order of `c.robots`.
    pub fn with_robots(
        c: &CellCalibration,
        cell: &str,
        frames: &Frames,
        frame_ids: &[String],
        total_ms: f64,
    ) -> Self {
        let mut r = CalibrationReport::new(&c.headline(), cell, frames, total_ms);
        let names = super::robots::pair_names(c);
        r.robots = Some(
            c.robots
                .iter()
                .zip(frame_ids)
                .map(|(b, f)| super::robots::RobotBaseReport::new(b, &frames.parent, f, &names))
                .collect(),
        );
        r.pairs = Some(c.pairs.iter().map(super::robots::PairReport::new).collect());
        r
    }
}
