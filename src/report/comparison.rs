//! The report of `compare`: [`ComparisonReport`].

use super::calibration::InitialReport;
use super::pose::{ErrorReport, PoseReport};
use crate::methods::{Comparison, MethodOutcome};
use serde::Serialize;

/// The schema name and version of [`ComparisonReport`].
pub const COMPARISON_SCHEMA: &str = "depthcal.comparison/1";

/// One method's row.
#[derive(Clone, Debug, Serialize)]
pub struct MethodReport {
    /// The method's name.
    pub method: &'static str,
    /// `ok`, `skipped` or `failed`.
    pub status: &'static str,
    /// Why it was skipped or how it failed.
    pub reason: Option<String>,
    /// ICP refined its estimate.
    pub refined: Option<bool>,
    /// Its `T_base1_base2`.
    pub transform: Option<PoseReport>,
    /// Its error against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
    /// The initialiser's estimate.
    pub initial: Option<InitialReport>,
    /// Its largest difference from the other methods' results.
    pub disagreement: Option<ErrorReport>,
    /// Its result can be trusted.
    pub trusted: Option<bool>,
    /// Why not.
    pub reasons: Vec<String>,
    /// Wall time, milliseconds.
    pub time_ms: Option<f64>,
}

/// Every method a cell allows side by side, as `depthcal compare --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct ComparisonReport {
    /// [`COMPARISON_SCHEMA`].
    pub schema: &'static str,
    /// The cell directory.
    pub cell: String,
    /// The methods were refined with ICP.
    pub refined: bool,
    /// Wall time of the one fusion, milliseconds.
    pub fuse_ms: f64,
    /// The methods in order.
    pub methods: Vec<MethodReport>,
    /// Wall time of the whole run, milliseconds.
    pub total_ms: f64,
}

impl ComparisonReport {
    /// The report of `c` for the cell directory `cell`.
    pub fn new(c: &Comparison, cell: &str, total_ms: f64) -> Self {
        let methods = c
            .rows
            .iter()
            .map(|r| {
                let mut m = MethodReport {
                    method: r.method.name(),
                    status: "ok",
                    reason: None,
                    refined: None,
                    transform: None,
                    error_vs_truth: None,
                    initial: None,
                    disagreement: ErrorReport::from_opt(r.disagreement),
                    trusted: None,
                    reasons: Vec::new(),
                    time_ms: None,
                };
                match &r.outcome {
                    MethodOutcome::Ran(cal, ms) => {
                        m.refined = Some(cal.refined);
                        m.transform = Some(PoseReport::new(&cal.transform));
                        m.error_vs_truth = ErrorReport::from_opt(cal.error_vs_truth);
                        m.initial = Some(InitialReport {
                            transform: PoseReport::new(&cal.initial.transform),
                            detail: cal.initial.detail.clone(),
                            sigma_rotation_deg: cal.initial.sigma_rotation_deg,
                            sigma_translation_m: cal.initial.sigma_translation_m,
                            error_vs_truth: ErrorReport::from_opt(cal.initial_error_vs_truth),
                        });
                        m.trusted = Some(cal.trust.trusted);
                        m.reasons = cal.trust.reasons.clone();
                        m.time_ms = Some(*ms);
                    }
                    MethodOutcome::Skipped(why) => {
                        m.status = "skipped";
                        m.reason = Some(why.clone());
                    }
                    MethodOutcome::Failed(e) => {
                        m.status = "failed";
                        m.reason = Some(e.clone());
                    }
                }
                m
            })
            .collect();
        ComparisonReport {
            schema: COMPARISON_SCHEMA,
            cell: cell.to_string(),
            refined: c.refined,
            fuse_ms: c.fuse_ms,
            methods,
            total_ms,
        }
    }
}
