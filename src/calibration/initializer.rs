//! Initialisers: ways to get a first `T_base1_base2` that trimmed ICP then refines.
//!
//! The depth-only global registration (FPFH + RANSAC under the cell's priors) is one; a user-supplied guess
//! is another; the checkerboard, marker and 2D-feature methods plug in here too.

use crate::calibration::visibility::{
    free_space_violation, self_consistent_margin, RobotSight, VisibilityConfig,
};
use crate::error::Result;
use crate::fusion::FusedCloud;
use crate::registration::pipeline::Ambiguity;
use crate::registration::{
    register_request, HypothesisPrior, PoseConstraint, RegisterConfig, RegisterRequest,
};
use nalgebra::{Isometry3, Matrix6, Vector6};
use serde::{Deserialize, Serialize};

/// What an initialiser gets to work with: both robots' fused clouds in their own base frames.
pub struct InitializerInput<'a> {
    /// The reference robot's fused cloud (base1 frame, metres).
    pub reference: &'a FusedCloud,
    /// The other robot's fused cloud (base2 frame, metres).
    pub other: &'a FusedCloud,
    /// Constraint from the cell's priors (may be empty).
    pub constraint: &'a PoseConstraint,
    /// Seed for randomised steps.
    pub seed: u64,
}

/// An initial estimate of `T_base1_base2` with its uncertainty.
#[derive(Clone, Debug)]
pub struct InitialGuess {
    /// Maps base2 coordinates into base1.
    pub transform: Isometry3<f64>,
    /// 1-σ rotation uncertainty, degrees.
    pub sigma_rotation_deg: f64,
    /// 1-σ translation uncertainty, metres.
    pub sigma_translation_m: f64,
    /// A short description of how it was obtained.
    pub detail: String,
    /// A far-away second answer that the data supports almost as well (initialisers that search).
    pub ambiguity: Option<Ambiguity>,
    /// Other distinct hypotheses of a search, for the refinement to refine and judge at full resolution
    /// beside `transform` (empty for initialisers that give one answer).
    pub alternatives: Vec<Isometry3<f64>>,
}

impl InitialGuess {
    /// A diagonal covariance of `[rx, ry, rz (rad), tx, ty, tz (m)]` from the stated 1-σ values.
    pub fn covariance(&self) -> Matrix6<f64> {
        let r = self.sigma_rotation_deg.to_radians().powi(2);
        let t = self.sigma_translation_m.powi(2);
        Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
    }
}

/// A way to obtain an initial `T_base1_base2`.
pub trait Initializer {
    /// The method's name as the command line spells it (`depth`, `guess`, ...).
    fn name(&self) -> &str;
    /// Computes the initial estimate.
    fn initialize(&self, input: &InitializerInput) -> Result<InitialGuess>;
    /// Whether it uses the fused clouds of [`InitializerInput`] (default true); those that do not can run
    /// without fusing (`calibrate --no-refine`), and then get empty clouds.
    fn needs_clouds(&self) -> bool {
        true
    }
}

/// How the depth initialiser searches for hypotheses ([`GlobalRegistration`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SearchConfig {
    /// Besides the cell search (sided normals, one-way matches, the priors' constraint, hypotheses weighed
    /// by the free-space test), also run `register`'s own global stage on the same clouds (its defaults:
    /// normals signed locally, mutual matches, no constraint, no free-space weights) and pool its
    /// hypotheses, less those the priors refuse (default true). The two searches fail on different cells:
    /// a hand-made foreign cell with nothing in range behind a square table was found only by the second
    /// ("Right on any cell", docs/accuracy.md), while the free-space weights decide cells that share a
    /// third of the scene.
    pub plain: bool,
    /// Distinct hypotheses each search hands to the refinement, best first (default 3).
    pub hypotheses_per_search: usize,
}

impl Default for SearchConfig {
    fn default() -> Self {
        SearchConfig {
            plain: true,
            hypotheses_per_search: 3,
        }
    }
}

impl SearchConfig {
    /// Checks the ranges; the error names the field (`search.…`).
    pub fn validate(&self) -> Result<()> {
        crate::error::check::at_least(
            "search.hypotheses_per_search",
            self.hypotheses_per_search,
            1,
        )
    }
}

/// Depth only: FPFH features, RANSAC under the priors, verified on the clouds (the default).
#[derive(Clone, Debug)]
pub struct GlobalRegistration {
    /// Registration settings (its RANSAC constraint is replaced by the priors' constraint). Default: those
    /// of [`crate::calibration::config::CalibrateConfig`].
    pub config: RegisterConfig,
    /// Weigh the hypotheses by their free-space consistency with both robots' depth frames
    /// ([`crate::calibration::visibility`]) when the fused clouds carry their frames' depth views
    /// (default on).
    pub visibility: Option<VisibilityConfig>,
    /// Which searches run and how many hypotheses each hands on.
    pub search: SearchConfig,
}

impl Initializer for GlobalRegistration {
    fn name(&self) -> &str {
        "depth"
    }
    fn initialize(&self, input: &InitializerInput) -> Result<InitialGuess> {
        let mut cfg = self.config.clone();
        cfg.seed = input.seed;
        cfg.ransac.constraint = input.constraint.clone();
        // Only the global stage: one coarse ICP level is enough for a starting point, and the hold test of
        // weak directions is for the refined answer.
        cfg.icp_levels = 1;
        cfg.degeneracy_slide_voxels = 0.0;
        let (reference, other) = (input.reference, input.other);
        let (rs, os) = (sight(reference, cfg.sided), sight(other, cfg.sided));
        let vis = self
            .visibility
            .as_ref()
            .filter(|_| !reference.views.is_empty() && !other.views.is_empty())
            .map(|v| {
                let (margin_m, own) = self_consistent_margin(&rs, &os, v);
                log::info!(
                    "free-space margin {:.1} mm (each robot's own frames disagree with its cloud at {:.1}%)",
                    margin_m * 1e3,
                    own * 1e2
                );
                VisibilityConfig {
                    margin_m,
                    ..v.clone()
                }
            });
        let prior = |t: &Isometry3<f64>| -> f64 {
            let v = vis.as_ref().expect("only used with views");
            let f = free_space_violation(&rs, &os, t, v);
            (-f / v.penalty_scale).exp()
        };
        // The cell search and `register`'s own (below) run side by side: each is deterministic at any
        // thread count, and their hypotheses are pooled in a fixed order.
        let plain_cfg = RegisterConfig {
            seed: input.seed,
            icp_levels: 1,
            degeneracy_slide_voxels: 0.0,
            ..RegisterConfig::default()
        };
        // Each search's answer is only a start (its covariance is not used): no re-associated information.
        let search = |cfg: &RegisterConfig, prior: Option<HypothesisPrior>| {
            register_request(RegisterRequest {
                prior,
                check_extents: false,
                reassociate: false,
                ..RegisterRequest::new(&other.cloud, &reference.cloud, cfg)
            })
        };
        let (r, p) = rayon::join(
            || search(&cfg, vis.as_ref().map(|_| &prior as HypothesisPrior)),
            || self.search.plain.then(|| search(&plain_cfg, None)),
        );
        let r = r?;
        let g = r.global.as_ref().expect("global stage ran");
        log::info!("depth initialiser stages (ms): {:?}", r.timings_ms);
        let per_search = self.search.hypotheses_per_search.max(1);
        let mut pool: Vec<Isometry3<f64>> = vec![r.transform];
        let distinct = |pool: &[Isometry3<f64>], h: &Isometry3<f64>| {
            pool.iter().all(|k| {
                let (deg, m) = crate::geometry::transform::pose_error(h, k);
                deg > cfg.ambiguity_min_deg || m > cfg.ambiguity_min_voxels * r.voxel
            })
        };
        for h in r.hypotheses.iter().take(per_search) {
            if distinct(&pool, h) {
                pool.push(*h);
            }
        }
        if let Some(p) = p {
            let p = p?;
            log::info!("plain search stages (ms): {:?}", p.timings_ms);
            let accepted = p
                .hypotheses
                .iter()
                .filter(|h| input.constraint.accepts(h))
                .take(per_search);
            for h in accepted {
                if distinct(&pool, h) {
                    pool.push(*h);
                }
            }
        }
        Ok(InitialGuess {
            transform: r.transform,
            // A coarse registration is good to about a voxel, over the half-extent of the cloud.
            sigma_rotation_deg: (r.voxel / (0.5 * input.reference.cloud.extent()).max(r.voxel))
                .atan()
                .to_degrees(),
            sigma_translation_m: r.voxel,
            detail: format!(
                "FPFH + RANSAC: {} correspondences, {} inliers, {} samples, fitness {:.3}, voxel {:.4} m",
                g.correspondences, g.inliers, g.iterations, g.fitness, r.voxel
            ),
            ambiguity: r.ambiguity.clone(),
            alternatives: pool.split_off(1),
        })
    }
}

/// A transform the user already knows roughly (e.g. from a tape measure or an earlier calibration).
#[derive(Clone, Debug)]
pub struct UserGuess {
    /// The guess of `T_base1_base2`.
    pub transform: Isometry3<f64>,
    /// Where it came from (a file name).
    pub source: String,
}

impl Initializer for UserGuess {
    fn name(&self) -> &str {
        "guess"
    }
    fn needs_clouds(&self) -> bool {
        false
    }
    fn initialize(&self, _input: &InitializerInput) -> Result<InitialGuess> {
        Ok(InitialGuess {
            transform: self.transform,
            sigma_rotation_deg: 5.0,
            sigma_translation_m: 0.05,
            detail: format!("user guess from {}", self.source),
            ambiguity: None,
            alternatives: Vec::new(),
        })
    }
}

/// The free-space test's view of a fused cloud: its normals are its sides when the registration is sided.
pub(crate) fn sight(f: &FusedCloud, sided: bool) -> RobotSight<'_> {
    RobotSight {
        points: &f.cloud.points,
        sides: f
            .cloud
            .normals
            .as_deref()
            .filter(|s| sided && s.len() == f.cloud.points.len()),
        views: &f.views,
    }
}
