//! The parts of the calibration report for cells of three or more robots: each robot's base in the joint
//! solution ([`RobotBaseReport`]) and each pair's own result against it ([`PairReport`]).

use super::pose::{matrix6_rows, ErrorReport, PoseReport, SigmaReport};
use crate::calibration::multi_robot::{CellCalibration, PairCalibration, RobotBase};
use crate::calibration::pose_graph::EdgeVerdict;
use crate::calibration::uncertainty::NormalisedError;
use crate::geometry::robot_formats::{ros2_static_tf_command, Frames};
use serde::Serialize;

/// One robot's base in the joint solution. Lengths in metres, angles in degrees.
#[derive(Clone, Debug, Serialize)]
pub struct RobotBaseReport {
    /// The robot's name.
    pub name: String,
    /// Its base frame id in the ROS outputs.
    pub frame_id: String,
    /// `T_<reference>_<robot>`: maps this robot's base coordinates into the reference base (absent when it
    /// is not calibrated).
    pub transform: Option<PoseReport>,
    /// Its covariance, `[rx, ry, rz (rad), tx, ty, tz (m)]`, a left increment in the reference base frame.
    pub covariance: Option<[[f64; 6]; 6]>,
    /// 1-σ per axis.
    pub sigma: Option<SigmaReport>,
    /// The robot is calibrated and its pose can be trusted.
    pub trusted: bool,
    /// Why not, naming every pair that could have given it a pose.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
    /// The pairs of the solution that touch this robot (`"a - b"`).
    pub pairs_used: Vec<String>,
    /// Against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
    /// That error normalised by the covariance.
    pub normalised_error: Option<NormalisedError>,
    /// The ROS 2 command that publishes the transform.
    pub ros2: Option<String>,
}

/// One pair's own two-robot result and how it fits the joint solution.
#[derive(Clone, Debug, Serialize)]
pub struct PairReport {
    /// The pair's first robot (its reference).
    pub reference: String,
    /// The pair's second robot.
    pub other: String,
    /// The pair's own `T_<reference>_<other>`.
    pub transform: PoseReport,
    /// Its 1-σ per axis.
    pub sigma: SigmaReport,
    /// The pair's own result passed every two-robot check.
    pub trusted: bool,
    /// Why not.
    pub reasons: Vec<String>,
    /// Its refinement's fitness and overlap, 0–1.
    pub fitness: Option<f64>,
    /// See `fitness`.
    pub overlap: Option<f64>,
    /// `agrees` (used, its loops agree), `unchecked` (used, no loop runs through it), `not_usable` (not
    /// trusted), `disagrees` (trusted, dropped: it alone disagrees with its loops), `ambiguous` (trusted,
    /// dropped: one of several pairs any of which would explain a loop's disagreement).
    pub verdict: EdgeVerdict,
    /// The pair against the joint solution, degrees (absent when a robot of it is not calibrated).
    pub residual_deg: Option<f64>,
    /// The same, metres.
    pub residual_m: Option<f64>,
    /// Its normalised disagreement with the rest of the graph; absent when no loop runs through it.
    pub loop_error: Option<f64>,
    /// The pair's own error against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
}

impl RobotBaseReport {
    /// `r` of a cell whose reference base frame id is `parent`; `frame_id` is this robot's; `pair_names`
    /// names the cell's pairs by index.
    pub fn new(r: &RobotBase, parent: &str, frame_id: &str, pair_names: &[String]) -> Self {
        let frames = Frames {
            parent: parent.to_string(),
            child: frame_id.to_string(),
        };
        RobotBaseReport {
            name: r.name.clone(),
            frame_id: frame_id.to_string(),
            transform: r.transform.as_ref().map(PoseReport::new),
            covariance: r.covariance.as_ref().map(matrix6_rows),
            sigma: r.covariance.as_ref().map(SigmaReport::from_covariance),
            trusted: r.trust.trusted,
            reasons: r.trust.reasons.clone(),
            suggestions: r.trust.suggestions.clone(),
            pairs_used: r
                .pairs_used
                .iter()
                .map(|&k| pair_names[k].clone())
                .collect(),
            error_vs_truth: ErrorReport::from_opt(r.error_vs_truth),
            normalised_error: r.normalised_error,
            ros2: r
                .transform
                .as_ref()
                .map(|t| ros2_static_tf_command(t, &frames)),
        }
    }
}

impl PairReport {
    /// One pair of the cell.
    pub fn new(p: &PairCalibration) -> Self {
        let c = &p.calibration;
        PairReport {
            reference: c.reference.clone(),
            other: c.other.clone(),
            transform: PoseReport::new(&c.transform),
            sigma: SigmaReport::from_covariance(&c.covariance),
            trusted: c.trust.trusted,
            reasons: c.trust.reasons.clone(),
            fitness: c.fitness,
            overlap: c.overlap,
            verdict: p.check.verdict,
            residual_deg: p.check.residual.map(|r| r.0),
            residual_m: p.check.residual.map(|r| r.1),
            loop_error: p.check.loop_error,
            error_vs_truth: ErrorReport::from_opt(c.error_vs_truth),
        }
    }
}

/// The pairs' names, `"a - b"`, by index.
pub fn pair_names(c: &CellCalibration) -> Vec<String> {
    c.pairs
        .iter()
        .map(|p| format!("{} - {}", p.calibration.reference, p.calibration.other))
        .collect()
}
