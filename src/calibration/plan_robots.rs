//! `depthcal plan` on a cell of three or more robots: how strong each base of the joint solution is, which
//! is the weakest, what each pair touching it lacks, and which flange poses would strengthen it most.
//!
//! A base's strength is the largest 1-σ of its joint covariance in millimetres, rotations counted at the
//! RMS radius of the reference robot's fused cloud (as [`super::plan`] counts them); a robot without a
//! pose is weaker than any. The poses are the two-robot plan ([`super::plan::plan_pair`]) of the pair
//! touching the weakest robot whose refinement saw the most overlap: the pair that more views of its
//! shared scene strengthen most readily. Its hand-eye plans cover both robots of that pair.

use super::fused::FusedRobots;
use super::multi_robot::CellCalibration;
use super::plan::{directions_sigma_mm, plan_pair, rms_radius, CellPlan, PlanConfig};
use super::pose_graph::EdgeVerdict;
use super::priors::CellPriors;
use crate::error::{Error, Result};
use serde::Serialize;

/// One base of the joint solution.
#[derive(Clone, Debug, Serialize)]
pub struct BaseStrength {
    /// The robot.
    pub robot: String,
    /// It has a pose in the joint solution.
    pub calibrated: bool,
    /// It is trusted.
    pub trusted: bool,
    /// The largest 1-σ of its joint pose, millimetres (rotations at the RMS radius); `None` without a pose.
    pub sigma_mm: Option<f64>,
    /// Pairs of the solution that touch it.
    pub pairs_used: usize,
}

/// A pair touching the weakest robot, and what would make it count more.
#[derive(Clone, Debug, Serialize)]
pub struct PairAdvice {
    /// `"a - b"`.
    pub pair: String,
    /// Its verdict in the graph.
    pub verdict: EdgeVerdict,
    /// Its refinement's overlap, 0–1.
    pub overlap: Option<f64>,
    /// What it lacks and what would help, in words.
    pub advice: String,
}

/// The plan of a cell of three or more robots.
#[derive(Clone, Debug, Serialize)]
pub struct RobotsPlan {
    /// The rotation scale of `sigma_mm`: the reference cloud's RMS radius, metres.
    pub radius_m: f64,
    /// Every other robot's base, in manifest order.
    pub bases: Vec<BaseStrength>,
    /// The weakest base's robot.
    pub weakest: String,
    /// Every pair touching it.
    pub pairs: Vec<PairAdvice>,
    /// The pair whose poses are planned: its reference, then the other robot.
    pub planned_pair: [String; 2],
    /// That pair's largest 1-σ from its inputs alone (hand-eyes, pose repeatability, depth scale: more
    /// views do not lower it), millimetres at `radius_m`.
    pub pair_inputs_sigma_mm: f64,
    /// That pair's largest 1-σ from the registration alone (what more shared views lower), millimetres.
    pub pair_registration_sigma_mm: f64,
    /// That pair's plan.
    #[serde(skip)]
    pub plan: CellPlan,
}

/// What a pair touching `weak` lacks, by its verdict.
fn advice(verdict: EdgeVerdict, weak: &str, other: &str, reasons: &[String]) -> String {
    match verdict {
        EdgeVerdict::Agrees => "used, and the loops through it agree".into(),
        EdgeVerdict::Unchecked => format!(
            "used, but no loop runs through it, so nothing checks it: a trusted pair of {other} or {weak} with a third robot would close one"
        ),
        EdgeVerdict::NotUsable => format!(
            "not trusted on its own ({}): views of the workspace both {weak} and {other} see would let it count",
            reasons.join("; ")
        ),
        EdgeVerdict::Disagrees => format!(
            "trusted on its own, but it alone disagrees with the loops through it and is left out: check {weak}'s and {other}'s pose files and hand-eyes"
        ),
        EdgeVerdict::Ambiguous => format!(
            "trusted on its own, but it lies in a loop that disagrees where the wrong pair cannot be told, and is left out: another trusted pair of {weak} would tell"
        ),
    }
}

/// Plans the cell `c` (from [`super::multi_robot::calibrate_robots`], with its `fused` clouds). Errors: a
/// bad configuration, a pair's plan that fails.
pub fn plan_robots(
    c: &CellCalibration,
    fused: &FusedRobots,
    cfg: &PlanConfig,
) -> Result<RobotsPlan> {
    cfg.validate()?;
    let names: Vec<&str> = fused.robots.iter().map(|r| r.name.as_str()).collect();
    if names.len() < 2 || c.robots.len() + 1 != names.len() {
        return Err(Error::InvalidInput(format!(
            "the plan of a cell of robots needs one fused cloud per robot ({} clouds, {} robots)",
            names.len(),
            c.robots.len() + 1
        )));
    }
    let radius = rms_radius(&fused.clouds[0].cloud.points);
    let bases: Vec<BaseStrength> = c
        .robots
        .iter()
        .map(|r| BaseStrength {
            robot: r.name.clone(),
            calibrated: r.transform.is_some(),
            trusted: r.trust.trusted,
            sigma_mm: r.covariance.map(|cov| directions_sigma_mm(&cov, radius)),
            pairs_used: r.pairs_used.len(),
        })
        .collect();
    // The weakest: the first robot without a pose, else the largest 1-σ (the first of equals).
    let weakest = bases
        .iter()
        .enumerate()
        .max_by(|(ia, a), (ib, b)| {
            let s = |x: &BaseStrength| x.sigma_mm.unwrap_or(f64::INFINITY);
            s(a).total_cmp(&s(b)).then(ib.cmp(ia))
        })
        .map(|(k, _)| k)
        .unwrap_or(0);
    let weak = c.robots[weakest].name.as_str();
    let touching: Vec<usize> = (0..c.pairs.len())
        .filter(|&e| {
            let q = &c.pairs[e].calibration;
            q.reference == weak || q.other == weak
        })
        .collect();
    let pairs = touching
        .iter()
        .map(|&e| {
            let p = &c.pairs[e];
            let q = &p.calibration;
            let other = if q.reference == weak {
                &q.other
            } else {
                &q.reference
            };
            PairAdvice {
                pair: format!("{} - {}", q.reference, q.other),
                verdict: p.check.verdict,
                overlap: q.overlap,
                advice: advice(p.check.verdict, weak, other, &q.trust.reasons),
            }
        })
        .collect();
    let best = touching
        .iter()
        .copied()
        .max_by(|&a, &b| {
            let o = |e: usize| c.pairs[e].calibration.overlap.unwrap_or(-1.0);
            o(a).total_cmp(&o(b)).then(b.cmp(&a))
        })
        .ok_or_else(|| Error::InvalidInput(format!("no pair touches robot {weak:?}")))?;
    let q = &c.pairs[best].calibration;
    let index = |name: &str| {
        names
            .iter()
            .position(|x| *x == name)
            .ok_or_else(|| Error::InvalidInput(format!("robot {name:?} was not fused")))
    };
    let (i, j) = (index(&q.reference)?, index(&q.other)?);
    let pair_fused = fused.pair(i, j, CellPriors::default());
    let plan = plan_pair((&fused.robots[i], &fused.robots[j]), q, &pair_fused, cfg)?;
    Ok(RobotsPlan {
        radius_m: radius,
        bases,
        weakest: weak.to_string(),
        pairs,
        planned_pair: [q.reference.clone(), q.other.clone()],
        pair_inputs_sigma_mm: directions_sigma_mm(&q.inputs_covariance, radius),
        pair_registration_sigma_mm: directions_sigma_mm(
            &(q.covariance - q.inputs_covariance),
            radius,
        ),
        plan,
    })
}
