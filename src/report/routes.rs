//! The report of `compare` on a cell of three or more robots ([`RoutesReport`]): every route to each base
//! (the joint solution, the robot's pair with the reference, each chain of two pairs) side by side.

use super::pose::{ErrorReport, PoseReport, SigmaReport};
use super::robots::PairReport;
use crate::calibration::multi_robot::CellCalibration;
use crate::calibration::routes::{RobotRoutes, Route};
use crate::calibration::uncertainty::NormalisedError;
use serde::Serialize;

/// The schema name and version of [`RoutesReport`].
pub const ROUTES_SCHEMA: &str = "depthcal.routes/1";

/// One route to a base. Lengths in metres, angles in degrees.
#[derive(Clone, Debug, Serialize)]
pub struct RouteReport {
    /// `joint solution`, or the robots it passes joined by ` - ` (the reference first).
    pub route: String,
    /// The robots it passes (empty for the joint solution).
    pub via: Vec<String>,
    /// `T_<reference>_<robot>` by this route.
    pub transform: PoseReport,
    /// Its 1-σ per axis, propagated from its pairs' covariances.
    pub sigma: SigmaReport,
    /// Every pair of it was trusted on its own (the joint solution: the robot is trusted).
    pub trusted: bool,
    /// Its distance from the joint solution (absent when the robot has no joint pose).
    pub from_joint: Option<ErrorReport>,
    /// Its error against the cell's ground truth.
    pub error_vs_truth: Option<ErrorReport>,
    /// That error normalised by the route's covariance.
    pub normalised_error: Option<NormalisedError>,
}

/// Every route to one robot's base.
#[derive(Clone, Debug, Serialize)]
pub struct RobotRoutesReport {
    /// The robot.
    pub name: String,
    /// The robot is calibrated and trusted in the joint solution.
    pub trusted: bool,
    /// The joint solution first (when the robot has a pose), then its pair with the reference, then each
    /// chain through another robot.
    pub routes: Vec<RouteReport>,
    /// The route with the smallest error against the truth (absent without a ground truth).
    pub best_vs_truth: Option<String>,
}

/// `depthcal compare --json` on a cell of three or more robots.
#[derive(Clone, Debug, Serialize)]
pub struct RoutesReport {
    /// [`ROUTES_SCHEMA`].
    pub schema: &'static str,
    /// The cell directory.
    pub cell: String,
    /// The reference robot.
    pub reference: String,
    /// Every robot is calibrated and trusted in the joint solution.
    pub trusted: bool,
    /// Why not.
    pub reasons: Vec<String>,
    /// Each other robot's routes, in manifest order.
    pub robots: Vec<RobotRoutesReport>,
    /// Every pair's own result against the joint solution (as `calibrate --json`'s `pairs`).
    pub pairs: Vec<PairReport>,
    /// Wall time of the whole run, milliseconds.
    pub total_ms: f64,
}

impl RouteReport {
    /// One route.
    pub fn new(r: &Route) -> Self {
        RouteReport {
            route: r.name(),
            via: r.via.clone(),
            transform: PoseReport::new(&r.transform),
            sigma: SigmaReport::from_covariance(&r.covariance),
            trusted: r.trusted,
            from_joint: ErrorReport::from_opt(r.from_joint),
            error_vs_truth: ErrorReport::from_opt(r.error_vs_truth),
            normalised_error: r.normalised_error,
        }
    }
}

impl RoutesReport {
    /// The report of `routes` (from [`crate::calibration::routes::robot_routes`] on `c`).
    pub fn new(c: &CellCalibration, routes: &[RobotRoutes], cell: &str, total_ms: f64) -> Self {
        RoutesReport {
            schema: ROUTES_SCHEMA,
            cell: cell.to_string(),
            reference: c.reference.clone(),
            trusted: c.trust.trusted,
            reasons: c.trust.reasons.clone(),
            robots: routes
                .iter()
                .map(|r| RobotRoutesReport {
                    name: r.robot.clone(),
                    trusted: c
                        .robots
                        .iter()
                        .find(|b| b.name == r.robot)
                        .is_some_and(|b| b.trust.trusted),
                    routes: r.routes.iter().map(RouteReport::new).collect(),
                    best_vs_truth: r
                        .routes
                        .iter()
                        .filter_map(|x| x.error_vs_truth.map(|e| (x, e)))
                        .min_by(|a, b| {
                            // Rotation at 1 m against translation: degrees to radians times metres.
                            let score = |e: (f64, f64)| e.0.to_radians() + e.1;
                            score(a.1).total_cmp(&score(b.1))
                        })
                        .map(|(x, _)| x.name()),
                })
                .collect(),
            pairs: c.pairs.iter().map(PairReport::new).collect(),
            total_ms,
        }
    }
}
