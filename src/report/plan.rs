//! The report of `depthcal plan` (`--json`).

use crate::calibration::multi_robot::CellCalibration;
use crate::calibration::plan::CellPlan;
use crate::calibration::plan_robots::RobotsPlan;
use crate::calibration::robot_to_robot::Calibration;
use serde::Serialize;

/// Schema name of [`PlanReport`].
pub const PLAN_SCHEMA: &str = "depthcal.plan/1";

/// What `depthcal plan --json` prints.
#[derive(Clone, Debug, Serialize)]
pub struct PlanReport {
    /// [`PLAN_SCHEMA`].
    pub schema: &'static str,
    /// The cell directory.
    pub cell: String,
    /// The reference robot (base1).
    pub reference: String,
    /// The other robot (base2).
    pub other: String,
    /// The calibration the plan rests on can be trusted.
    pub calibration_trusted: bool,
    /// Why not.
    pub calibration_reasons: Vec<String>,
    /// The plan.
    #[serde(flatten)]
    pub plan: CellPlan,
    /// A cell of three or more robots: every base's strength, the weakest, the pairs touching it; the plan
    /// above is then the planned pair's (`reference`, `other`). Absent for two robots.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robots: Option<RobotsPlan>,
    /// Wall time of the whole run, milliseconds.
    pub total_ms: f64,
}

impl PlanReport {
    /// The report of `plan` for the cell directory `cell`, made from calibration `c`.
    pub fn new(c: &Calibration, plan: CellPlan, cell: &str, total_ms: f64) -> Self {
        PlanReport {
            schema: PLAN_SCHEMA,
            cell: cell.to_string(),
            reference: c.reference.clone(),
            other: c.other.clone(),
            calibration_trusted: c.trust.trusted,
            calibration_reasons: c.trust.reasons.clone(),
            plan,
            robots: None,
            total_ms,
        }
    }

    /// The report of the plan `p` of a cell of three or more robots calibrated as `c`: the pair plan of
    /// `p.planned_pair`, the cell's verdict.
    pub fn with_robots(c: &CellCalibration, p: RobotsPlan, cell: &str, total_ms: f64) -> Self {
        PlanReport {
            schema: PLAN_SCHEMA,
            cell: cell.to_string(),
            reference: p.planned_pair[0].clone(),
            other: p.planned_pair[1].clone(),
            calibration_trusted: c.trust.trusted,
            calibration_reasons: c.trust.reasons.clone(),
            plan: p.plan.clone(),
            robots: Some(p),
            total_ms,
        }
    }
}
