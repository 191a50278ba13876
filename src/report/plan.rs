//! The report of `depthcal plan` (`--json`).

use crate::calibration::plan::CellPlan;
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
            total_ms,
        }
    }
}
