//! Cells of three or more robots: every pair of robots calibrated by the two-robot engine (the same
//! fusion, global stage, refinement and trust checks), then one consistent solution for all bases from a
//! pose graph over the trusted pairs ([`crate::calibration::pose_graph`]), the reference base fixed.
//!
//! Each robot is fused once; each pair `(i, j)` (the robots in order: the reference, then the others in
//! manifest order; `i` before `j`) is refined as a two-robot cell with `i` as its reference. The cell's
//! `[priors]` apply to every pair except `base_distance_m`, which states the distance of the reference
//! and the first other robot only. A robot is calibrated when trusted pairs that agree with their loops
//! link it to the reference; otherwise it is named, with every pair's reason, and given no pose.

use crate::calibration::config::CalibrateConfig;
use crate::calibration::fused::{fuse_robots, read_priors, FusedRobots};
use crate::calibration::initializer::Initializer;
use crate::calibration::pose_graph::{solve_graph, EdgeCheck, EdgeVerdict, GraphEdge};
use crate::calibration::robot_to_robot::{refine_pair, Calibration};
use crate::calibration::uncertainty::{normalised_error, NormalisedError};
use crate::cell::{Cell, CellRobot};
use crate::error::{Error, Result};
use crate::geometry::transform::pose_error;
use crate::registration::Trust;
use nalgebra::{Isometry3, Matrix6};
use std::time::Instant;

/// One robot's base in the joint solution.
#[derive(Clone, Debug)]
pub struct RobotBase {
    /// The robot's name.
    pub name: String,
    /// `T_reference_robot` (maps this robot's base coordinates into the reference base, metres); `None`
    /// when no trusted pair links it to the reference.
    pub transform: Option<Isometry3<f64>>,
    /// Its covariance, `[rx, ry, rz (rad), tx, ty, tz (m)]` as a left increment in the reference base frame,
    /// from the graph (the pairs' covariances, inputs included, combined).
    pub covariance: Option<Matrix6<f64>>,
    /// Trusted when it has a pose and no other base stands within `min_base_distance_m` of it; without a
    /// pose the reasons name every pair that could have given it one.
    pub trust: Trust,
    /// Against `ground_truth.json` when it knows this robot: (degrees, metres).
    pub error_vs_truth: Option<(f64, f64)>,
    /// That error normalised by the covariance.
    pub normalised_error: Option<NormalisedError>,
    /// The pairs (indices into [`CellCalibration::pairs`]) used in the solution that touch this robot.
    pub pairs_used: Vec<usize>,
}

/// One pair's own calibration and how it fits the joint solution.
#[derive(Clone, Debug)]
pub struct PairCalibration {
    /// The two-robot result: `reference` is the pair's first robot, `transform` its `T_first_second`.
    pub calibration: Calibration,
    /// The pair against the joint solution: used or dropped, its residual and loop error.
    pub check: EdgeCheck,
}

/// The result of [`calibrate_robots`].
#[derive(Clone, Debug)]
pub struct CellCalibration {
    /// The reference robot (fixed at the identity).
    pub reference: String,
    /// Every other robot, in manifest order.
    pub robots: Vec<RobotBase>,
    /// Every pair of robots, the reference's pairs first.
    pub pairs: Vec<PairCalibration>,
    /// Trusted when every robot is calibrated.
    pub trust: Trust,
    /// Wall time per stage, milliseconds (the pairs under `pairs`, their sum).
    pub timings_ms: Vec<(String, f64)>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
}

impl CellCalibration {
    /// The pair `(reference, first other robot)` as a two-robot result in the joint solution's terms: its
    /// transform, covariance and errors are the joint ones for that robot (the pair's own when the robot
    /// is not calibrated), its trust the whole cell's, its quality figures the pair's own. This is what the
    /// two-robot report shows first.
    pub fn headline(&self) -> Calibration {
        let mut c = self.pairs[0].calibration.clone();
        let r = &self.robots[0];
        if let (Some(t), Some(cov)) = (r.transform, r.covariance) {
            c.transform = t;
            c.covariance = cov;
            c.error_vs_truth = r.error_vs_truth;
            c.normalised_error = r.normalised_error;
        }
        c.trust = self.trust.clone();
        c.warnings = self.warnings.clone();
        c.timings_ms = self.timings_ms.clone();
        c
    }
}

/// Names of every robot in solving order: the reference, then the others in manifest order.
fn ordered(cell: &Cell) -> Vec<&CellRobot> {
    let reference = cell.reference();
    std::iter::once(reference)
        .chain(cell.robots.iter().filter(|r| r.name != reference.name))
        .collect()
}

/// Calibrates every base of a cell of two or more robots against the reference (module docs). Returns the
/// result and each robot's fused cloud (in solving order: the reference first).
pub fn calibrate_robots(
    cell: &Cell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<(CellCalibration, FusedRobots)> {
    cfg.validate()?;
    let robots = ordered(cell);
    let n = robots.len();
    if n < 2 {
        return Err(Error::InvalidInput(format!(
            "{}: the cell needs two robots, it names only {:?}",
            cell.dir.join("cell.toml").display(),
            robots[0].name
        )));
    }
    let t0 = Instant::now();
    progress(&format!("fusing the frames of {n} robots"));
    let fused = fuse_robots(&robots, cfg)?;
    let priors = read_priors(cell, cfg)?;
    let mut other_priors = priors.clone();
    other_priors.base_distance_m = None;
    other_priors.base_distance_tolerance_m = None;
    let truth = cell.ground_truth()?;
    let truth_of = |k: usize| -> Option<Isometry3<f64>> {
        truth
            .as_ref()?
            .base_of(&robots[k].name, &robots[0].name, &robots[1].name)
    };
    let fuse_ms = t0.elapsed().as_secs_f64() * 1e3;
    let pairs: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .collect();
    let t_pairs = Instant::now();
    let mut calibrations = Vec::with_capacity(pairs.len());
    for (k, &(i, j)) in pairs.iter().enumerate() {
        let p = if (i, j) == (0, 1) {
            priors.clone()
        } else {
            other_priors.clone()
        };
        let pair_cell = fused.pair(i, j, p);
        let pair_truth = match (truth_of(i), truth_of(j)) {
            (Some(a), Some(b)) => Some(a.inverse() * b),
            _ => None,
        };
        let label = format!(
            "pair {} - {} ({} of {})",
            robots[i].name,
            robots[j].name,
            k + 1,
            pairs.len()
        );
        progress(&label);
        let mut sub = |s: &str| progress(&format!("{label}: {s}"));
        let (a, b) = (&pair_cell.robots[0], &pair_cell.robots[1]);
        let c = refine_pair(
            (a, b),
            &pair_cell,
            initializer,
            cfg,
            true,
            pair_truth,
            &mut sub,
        )?;
        log::info!(
            "{label}: trusted {}{}",
            c.trust.trusted,
            c.error_vs_truth.map_or(String::new(), |(r, m)| format!(
                ", {r:.3}° / {:.2} mm from the truth",
                m * 1e3
            ))
        );
        calibrations.push(c);
    }
    let pairs_ms = t_pairs.elapsed().as_secs_f64() * 1e3;
    let t_graph = Instant::now();
    let edges: Vec<GraphEdge> = pairs
        .iter()
        .zip(&calibrations)
        .map(|(&(i, j), c)| GraphEdge {
            from: i,
            to: j,
            measured: c.transform,
            covariance: c.covariance,
            usable: c.trust.trusted,
        })
        .collect();
    let solution = solve_graph(n, 0, &edges, &cfg.pose_graph)?;
    let graph_ms = t_graph.elapsed().as_secs_f64() * 1e3;
    let names: Vec<&str> = robots.iter().map(|r| r.name.as_str()).collect();
    let pair_name = |k: usize| format!("{} - {}", names[pairs[k].0], names[pairs[k].1]);
    let mut warnings = Vec::new();
    for (k, e) in solution.edges.iter().enumerate() {
        let residual = e.residual.map_or(String::new(), |(r, m)| {
            format!(" ({r:.3}° / {:.1} mm from the joint solution)", m * 1e3)
        });
        match e.verdict {
            EdgeVerdict::Disagrees => warnings.push(format!(
                "pair {} was trusted on its own but disagrees with the loops through it{residual}, normalised {:.1}; left out of the solution",
                pair_name(k),
                e.loop_error.unwrap_or(f64::NAN)
            )),
            EdgeVerdict::Ambiguous => warnings.push(format!(
                "pair {} is one of several trusted pairs whose loop disagrees (normalised {:.1}); which of them is wrong cannot be told, so none is used",
                pair_name(k),
                e.loop_error.unwrap_or(f64::NAN)
            )),
            _ => {}
        }
    }
    let mut trust = Trust::new();
    let mut bases = Vec::with_capacity(n - 1);
    for k in 1..n {
        let used: Vec<usize> = (0..pairs.len())
            .filter(|&e| {
                (pairs[e].0 == k || pairs[e].1 == k)
                    && matches!(
                        solution.edges[e].verdict,
                        EdgeVerdict::Agrees | EdgeVerdict::Unchecked
                    )
            })
            .collect();
        let mut t = Trust::new();
        let transform = solution.poses[k];
        let covariance = solution.covariances[k];
        if transform.is_none() {
            let why: Vec<String> = (0..pairs.len())
                .filter(|&e| pairs[e].0 == k || pairs[e].1 == k)
                .map(|e| {
                    let c = &calibrations[e];
                    let verdict = match solution.edges[e].verdict {
                        EdgeVerdict::NotUsable => format!("not trusted ({})", c.trust.reasons.join("; ")),
                        EdgeVerdict::Disagrees => "trusted, but it disagrees with its loops".to_string(),
                        EdgeVerdict::Ambiguous => "trusted, but in a loop that disagrees where the wrong pair cannot be told".to_string(),
                        EdgeVerdict::Agrees | EdgeVerdict::Unchecked => {
                            "used, but it does not reach the reference".to_string()
                        }
                    };
                    format!("pair {}: {verdict}", pair_name(e))
                })
                .collect();
            t.fail(
                format!(
                    "robot {:?} is not calibrated: no trusted pair links it to {:?}. {}",
                    names[k],
                    names[0],
                    why.join(". ")
                ),
                format!(
                    "capture views of robot {:?} that share the workspace with another robot's views, and check its hand-eye, intrinsics and pose file",
                    names[k]
                ),
            );
            for c in (0..pairs.len())
                .filter(|&e| pairs[e].0 == k || pairs[e].1 == k)
                .map(|e| &calibrations[e])
            {
                for s in &c.trust.suggestions {
                    if !t.suggestions.contains(s) {
                        t.suggestions.push(s.clone());
                    }
                }
            }
        }
        let true_base = truth_of(k);
        bases.push(RobotBase {
            name: names[k].to_string(),
            transform,
            covariance,
            error_vs_truth: match (transform, true_base) {
                (Some(e), Some(g)) => Some(pose_error(&e, &g)),
                _ => None,
            },
            normalised_error: match (transform, true_base, covariance) {
                (Some(e), Some(g), Some(c)) => normalised_error(&e, &g, &c),
                _ => None,
            },
            trust: t.clone(),
            pairs_used: used,
        });
        trust.merge(&t);
    }
    // Two bases on one footprint cannot both be right, whatever the pairs say (`min_base_distance_m`).
    let mut at: Vec<(usize, Isometry3<f64>)> = vec![(0, Isometry3::identity())];
    at.extend((1..n).filter_map(|k| solution.poses[k].map(|t| (k, t))));
    for (a, ta) in &at {
        for (b, tb) in at.iter().filter(|(b, _)| b > a) {
            let d = (ta.translation.vector - tb.translation.vector).norm();
            if d < cfg.min_base_distance_m {
                let reason = format!(
                    "robots {:?} and {:?} would stand {d:.3} m apart, closer than two robots' bases can (min_base_distance_m {:.2} m): their frames may be one robot's",
                    names[*a], names[*b], cfg.min_base_distance_m
                );
                let hint =
                    "check that each robot's entry in cell.toml names its own pose file and frames";
                for k in [*a, *b].into_iter().filter(|&k| k > 0) {
                    bases[k - 1].trust.fail(reason.clone(), hint);
                }
                trust.fail(reason, hint);
            }
        }
    }
    let timings_ms = vec![
        ("fuse".to_string(), fuse_ms),
        ("pairs".to_string(), pairs_ms),
        ("pose_graph".to_string(), graph_ms),
    ];
    let pairs = calibrations
        .into_iter()
        .zip(solution.edges)
        .map(|(calibration, check)| PairCalibration { calibration, check })
        .collect();
    Ok((
        CellCalibration {
            reference: names[0].to_string(),
            robots: bases,
            pairs,
            trust,
            timings_ms,
            warnings,
        },
        fused,
    ))
}
