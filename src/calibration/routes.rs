//! The routes to each base of a cell of three or more robots (`depthcal compare` on such a cell): the joint
//! solution, the robot's own pair with the reference, and every chain of two pairs through another robot,
//! each with its covariance propagated from the pairs', its trust (every pair of it trusted), its distance
//! from the joint solution and, with a ground truth, its error. The joint solution should be at least as
//! accurate as the best of the others; a route far from it names a pair to look at.
//!
//! Covariances are left increments in the reference base frame (as everywhere in `calibration`): a chain
//! `T_0k = T_0j · T_jk` has `Σ_0j + Ad(T_0j) Σ_jk Ad(T_0j)ᵀ`, a pair read backwards `T_kj = T_jk⁻¹` has
//! `Ad(T_jk⁻¹) Σ_jk Ad(T_jk⁻¹)ᵀ`. The pairs' inputs (hand-eyes, poses) are shared between routes, so the
//! routes are not independent: their 1-σ are each route's own, not a basis for averaging them.

use crate::calibration::multi_robot::CellCalibration;
use crate::calibration::uncertainty::{adjoint, normalised_error, NormalisedError};
use crate::cell::Cell;
use crate::error::Result;
use crate::geometry::transform::pose_error;
use nalgebra::{Isometry3, Matrix6};

/// One way to obtain a robot's base in the reference frame.
#[derive(Clone, Debug)]
pub struct Route {
    /// The robots it passes, the reference first and the robot last; the joint solution is `[]`.
    pub via: Vec<String>,
    /// `T_reference_robot`, metres.
    pub transform: Isometry3<f64>,
    /// Its covariance, `[rx, ry, rz (rad), tx, ty, tz (m)]`.
    pub covariance: Matrix6<f64>,
    /// Every pair of the route was trusted on its own (the joint solution: the robot is trusted).
    pub trusted: bool,
    /// Its distance from the joint solution (degrees, metres); `None` when the robot has no joint pose.
    pub from_joint: Option<(f64, f64)>,
    /// Against the ground truth (degrees, metres).
    pub error_vs_truth: Option<(f64, f64)>,
    /// That error normalised by the route's covariance.
    pub normalised_error: Option<NormalisedError>,
}

impl Route {
    /// `joint solution`, or the robots joined by ` - `.
    pub fn name(&self) -> String {
        if self.via.is_empty() {
            "joint solution".into()
        } else {
            self.via.join(" - ")
        }
    }
}

/// Every route to one robot: the joint solution first (when it has a pose), then the direct pair, then the
/// chains in robot order.
#[derive(Clone, Debug)]
pub struct RobotRoutes {
    /// The robot.
    pub robot: String,
    /// The routes.
    pub routes: Vec<Route>,
}

/// A pair's own transform and covariance read from robot `a` to robot `b` (either order of the pair).
fn pair_between(
    c: &CellCalibration,
    a: &str,
    b: &str,
) -> Option<(Isometry3<f64>, Matrix6<f64>, bool)> {
    c.pairs.iter().find_map(|p| {
        let q = &p.calibration;
        if q.reference == a && q.other == b {
            Some((q.transform, q.covariance, q.trust.trusted))
        } else if q.reference == b && q.other == a {
            let inv = q.transform.inverse();
            let ad = adjoint(&inv);
            Some((inv, ad * q.covariance * ad.transpose(), q.trust.trusted))
        } else {
            None
        }
    })
}

/// The routes to every robot but the reference, in the order of `c.robots`. `truths` holds each robot's
/// true `T_reference_robot` in the same order (`None` where the cell has no truth for it).
pub fn robot_routes(c: &CellCalibration, truths: &[Option<Isometry3<f64>>]) -> Vec<RobotRoutes> {
    let reference = c.reference.as_str();
    c.robots
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let truth = truths.get(k).copied().flatten();
            let make =
                |via: Vec<String>, t: Isometry3<f64>, cov: Matrix6<f64>, trusted: bool| Route {
                    via,
                    transform: t,
                    covariance: cov,
                    trusted,
                    from_joint: r.transform.map(|j| pose_error(&t, &j)),
                    error_vs_truth: truth.map(|g| pose_error(&t, &g)),
                    normalised_error: truth.and_then(|g| normalised_error(&t, &g, &cov)),
                };
            let mut routes = Vec::new();
            if let (Some(t), Some(cov)) = (r.transform, r.covariance) {
                routes.push(make(Vec::new(), t, cov, r.trust.trusted));
            }
            if let Some((t, cov, ok)) = pair_between(c, reference, &r.name) {
                routes.push(make(vec![reference.into(), r.name.clone()], t, cov, ok));
            }
            for j in c.robots.iter().filter(|j| j.name != r.name) {
                let (Some(a), Some(b)) = (
                    pair_between(c, reference, &j.name),
                    pair_between(c, &j.name, &r.name),
                ) else {
                    continue;
                };
                let ad = adjoint(&a.0);
                routes.push(make(
                    vec![reference.into(), j.name.clone(), r.name.clone()],
                    a.0 * b.0,
                    a.1 + ad * b.1 * ad.transpose(),
                    a.2 && b.2,
                ));
            }
            RobotRoutes {
                robot: r.name.clone(),
                routes,
            }
        })
        .collect()
}

/// Each robot's true `T_reference_robot` from the cell's `ground_truth.json`, in the order of `c.robots`
/// (`None` where it has none; all `None` without the file). Errors: a malformed file.
pub fn true_bases(cell: &Cell, c: &CellCalibration) -> Result<Vec<Option<Isometry3<f64>>>> {
    let truth = cell.ground_truth()?;
    let first = c.robots.first().map_or("", |r| r.name.as_str());
    Ok(c.robots
        .iter()
        .map(|r| {
            truth
                .as_ref()
                .and_then(|g| g.base_of(&r.name, &c.reference, first))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::multi_robot::{PairCalibration, RobotBase};
    use crate::calibration::pose_graph::{EdgeCheck, EdgeVerdict};
    use crate::calibration::robot_to_robot::Calibration;
    use crate::registration::Trust;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn iso(t: [f64; 3], yaw_deg: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
        )
    }

    /// Robot `name` at `t` in the joint solution, trusted.
    fn base(name: &str, t: Isometry3<f64>) -> RobotBase {
        RobotBase {
            name: name.into(),
            transform: Some(t),
            covariance: Some(Matrix6::identity() * 1e-8),
            trust: Trust::new(),
            error_vs_truth: None,
            normalised_error: None,
            pairs_used: vec![],
        }
    }

    fn pair(a: &str, b: &str, t: Isometry3<f64>, sigma: f64, trusted: bool) -> PairCalibration {
        let mut c = Calibration::empty_for_tests(a, b);
        c.transform = t;
        c.covariance = Matrix6::identity() * sigma * sigma;
        if !trusted {
            c.trust.fail("no", "try");
        }
        PairCalibration {
            calibration: c,
            check: EdgeCheck {
                verdict: if trusted {
                    EdgeVerdict::Agrees
                } else {
                    EdgeVerdict::NotUsable
                },
                residual: None,
                loop_error: None,
            },
        }
    }

    #[test]
    fn chains_compose_pairs_in_either_order_and_propagate_covariance() {
        // Truth: b at (1, 0, 0) turned 90°, c at (0, 2, 0) turned 180°.
        let (tb, tc) = (iso([1.0, 0.0, 0.0], 90.0), iso([0.0, 2.0, 0.0], 180.0));
        let cell = CellCalibration {
            reference: "a".into(),
            robots: vec![base("b", tb), base("c", tc)],
            pairs: vec![
                pair("a", "b", tb, 1e-3, true),
                pair("a", "c", tc, 1e-3, false),
                // Stored as c -> b: the chain a - b - c reads it backwards.
                pair("c", "b", tc.inverse() * tb, 2e-3, true),
            ],
            trust: Trust::new(),
            timings_ms: vec![],
            warnings: vec![],
        };
        let routes = robot_routes(&cell, &[Some(tb), Some(tc)]);
        assert_eq!(routes.len(), 2);
        let names: Vec<String> = routes[1].routes.iter().map(Route::name).collect();
        assert_eq!(names, ["joint solution", "a - c", "a - b - c"]);
        for r in routes.iter().flat_map(|r| &r.routes) {
            let (deg, m) = r.error_vs_truth.unwrap();
            assert!(deg < 1e-9 && m < 1e-9, "{}: {deg} {m}", r.name());
            assert!(r.from_joint.unwrap().1 < 1e-9);
        }
        // a - b - c: trusted (both pairs are), its covariance the sum of a - b's and c - b's turned into a's
        // frame: larger than either.
        let chain = &routes[1].routes[2];
        assert!(chain.trusted);
        assert!(!routes[1].routes[1].trusted, "a - c was not trusted");
        let tr = chain.covariance.trace();
        assert!(tr > 6.0 * 4e-6, "{tr}");
        // Rotation variance is frame-free for an isotropic covariance: 1e-6 + 4e-6 per axis.
        assert!((chain.covariance[(2, 2)] - 5e-6).abs() < 1e-12);
        // A route through b to b itself is not a chain; b's chain runs through c.
        let names: Vec<String> = routes[0].routes.iter().map(Route::name).collect();
        assert_eq!(names, ["joint solution", "a - b", "a - c - b"]);
        assert!(!routes[0].routes[2].trusted, "a - c is in it");
    }

    #[test]
    fn a_wrong_pair_shows_in_its_routes_error_and_distance_from_the_joint_pose() {
        let tb = iso([1.0, 0.0, 0.0], 90.0);
        let tc = iso([0.0, 2.0, 0.0], 180.0);
        let off = iso([0.0, 0.01, 0.0], 0.0) * tc;
        let cell = CellCalibration {
            reference: "a".into(),
            robots: vec![base("b", tb), base("c", tc)],
            pairs: vec![
                pair("a", "b", tb, 1e-4, true),
                pair("a", "c", off, 1e-4, true),
                pair("b", "c", tb.inverse() * tc, 1e-4, true),
            ],
            trust: Trust::new(),
            timings_ms: vec![],
            warnings: vec![],
        };
        let r = &robot_routes(&cell, &[Some(tb), Some(tc)])[1];
        let direct = &r.routes[1];
        assert_eq!(direct.name(), "a - c");
        assert!((direct.from_joint.unwrap().1 - 0.01).abs() < 1e-9);
        assert!((direct.error_vs_truth.unwrap().1 - 0.01).abs() < 1e-9);
        assert!(direct.normalised_error.unwrap().translation > 10.0);
        assert!(r.routes[2].error_vs_truth.unwrap().1 < 1e-9);
        // Without a truth there are no errors, and a robot without a joint pose has no joint route.
        let mut cell = cell;
        cell.robots[1].transform = None;
        let r = &robot_routes(&cell, &[None, None])[1];
        assert_eq!(r.routes[0].name(), "a - c");
        assert!(r
            .routes
            .iter()
            .all(|x| x.error_vs_truth.is_none() && x.from_joint.is_none()));
    }
}
