//! Verification of global hypotheses by a short ICP and a normal-space-balanced alignment score.
//!
//! RANSAC ranks hypotheses by how many feature matches they explain. Where the scene repeats itself
//! (several boxes, cylinders and spheres on one table) a wrong hypothesis that lays one object onto a similar
//! one explains as many matches as the truth, and a large plane makes every hypothesis that lays it onto
//! itself look good by cloud fitness. This stage refines each candidate with a few ICP iterations and scores
//! how tightly it then aligns the surfaces, with the source points sampled evenly over normal directions
//! (Rusinkiewicz's normal-space sampling): a dominant plane is one direction among many, so the score
//! rewards the hypothesis that aligns *all* the shared geometry.

use crate::geometry::cloud::{to_v64, transform_point};
use crate::index::KdIndex;
use crate::registration::icp::{icp, IcpCloud, IcpConfig, IcpFactor, Trim};
use crate::registration::kernel::RobustKernel;
use crate::registration::ransac::PoseConstraint;
use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`verify_candidates`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerifyConfig {
    /// Hypotheses verified at most: RANSAC's best distinct ones by feature inliers (weighed by the
    /// caller's prior, if any) (default 50).
    pub max_candidates: usize,
    /// Source points sampled for the short ICP and the score, spread over normal directions (default 3000).
    pub sample_points: usize,
    /// ICP iterations per candidate (default 15).
    pub icp_iterations: usize,
    /// Two stages: every candidate first gets a third of the iterations on a third of the sample, and only
    /// the best this many (by score × prior) go on to the full refinement (default 8).
    pub refine_top: usize,
    /// ICP correspondence distance, in voxels (default 2).
    pub icp_distance_voxels: f64,
    /// A sampled point counts fully when its point-to-plane distance after refinement is 0 and not at all
    /// from this many voxels on (`1 − (d/τ)²`; default 0.25).
    pub tight_distance_voxels: f64,
    /// Largest angle between the source and target normals of a pair that counts, degrees (default 30).
    pub max_normal_angle_deg: f64,
}

impl Default for VerifyConfig {
    fn default() -> Self {
        VerifyConfig {
            max_candidates: 50,
            sample_points: 3000,
            icp_iterations: 15,
            refine_top: 8,
            icp_distance_voxels: 2.0,
            tight_distance_voxels: 0.25,
            max_normal_angle_deg: 30.0,
        }
    }
}

impl VerifyConfig {
    /// Checks the ranges; the error names the field (`verify.…`).
    pub fn validate(&self) -> crate::Result<()> {
        use crate::error::check;
        check::at_least("verify.max_candidates", self.max_candidates, 1)?;
        check::at_least("verify.sample_points", self.sample_points, 1)?;
        check::positive("verify.icp_distance_voxels", self.icp_distance_voxels)?;
        check::positive("verify.tight_distance_voxels", self.tight_distance_voxels)?;
        check::angle_deg("verify.max_normal_angle_deg", self.max_normal_angle_deg)
    }
}

/// A candidate after verification.
#[derive(Clone, Debug)]
pub struct Verified {
    /// The refined transform.
    pub transform: Isometry3<f64>,
    /// Its alignment score, 0–1 (mean over the sampled points).
    pub score: f64,
    /// Index of the candidate it came from.
    pub candidate: usize,
}

/// Key of a unit normal's direction, sign-free: 4 cells per axis of the canonical (first non-zero
/// component positive) vector.
pub(crate) fn normal_bin(n: &[f32; 3]) -> u16 {
    let s = if n[2] < 0.0 || (n[2] == 0.0 && (n[1] < 0.0 || (n[1] == 0.0 && n[0] < 0.0))) {
        -1.0
    } else {
        1.0
    };
    let q = |x: f32| (((s * x + 1.0) * 2.0).floor() as i32).clamp(0, 3) as u16;
    q(n[0]) * 16 + q(n[1]) * 4 + q(n[2])
}

/// About `count` indices of `normals`, the same number from each occupied direction bin (all of a bin when
/// it has fewer), in index order within a bin. Deterministic.
pub fn normal_space_sample(normals: &[[f32; 3]], count: usize) -> Vec<usize> {
    let mut bins: Vec<Vec<usize>> = vec![Vec::new(); 64];
    for (i, n) in normals.iter().enumerate() {
        bins[normal_bin(n) as usize].push(i);
    }
    let mut sizes: Vec<usize> = bins.iter().map(|b| b.len()).filter(|&l| l > 0).collect();
    sizes.sort_unstable();
    // The per-bin quota q such that Σ min(size, q) ≈ count.
    let mut q = count;
    let mut left = count;
    for (k, &s) in sizes.iter().enumerate() {
        let share = left / (sizes.len() - k);
        if s <= share {
            left -= s;
        } else {
            q = share.max(1);
            break;
        }
    }
    let mut out = Vec::with_capacity(count);
    for b in &bins {
        if b.len() <= q {
            out.extend_from_slice(b);
        } else {
            let step = b.len() as f64 / q as f64;
            out.extend((0..q).map(|k| b[(k as f64 * step) as usize]));
        }
    }
    out.sort_unstable();
    out
}

/// A caller's plausibility of a hypothesis (source-to-target transform), in [0, 1], multiplying its score
/// (e.g. the free-space consistency of a robot-to-robot hypothesis, [`crate::calibration::visibility`]).
pub type HypothesisPrior<'a> = &'a (dyn Fn(&Isometry3<f64>) -> f64 + Sync);

/// Refines every candidate with a short point-to-plane ICP on a normal-space sample of `source` and scores
/// the result (see the module docs), times `prior` when given; candidates whose refinement leaves
/// `constraint` score 0. Two stages (see [`VerifyConfig::refine_top`]). Returns the fully refined ones
/// best first, then the rest (ties keep the candidates' order). `voxel` is the clouds' resolution (cloud
/// units); both clouds need normals. With `sided` the normals carry the side each surface was seen from
/// (they point toward the sensors): pairs from opposite sides neither steer the short ICP nor score.
#[allow(clippy::too_many_arguments)]
pub fn verify_candidates(
    source: &[[f32; 3]],
    source_normals: &[[f32; 3]],
    target: &[[f32; 3]],
    target_normals: &[[f32; 3]],
    target_index: &KdIndex,
    candidates: &[Isometry3<f64>],
    voxel: f64,
    constraint: &PoseConstraint,
    prior: Option<HypothesisPrior>,
    sided: bool,
    cfg: &VerifyConfig,
) -> Vec<Verified> {
    let pick = normal_space_sample(source_normals, cfg.sample_points.max(30));
    let v = Verifier {
        pts: pick.iter().map(|&i| source[i]).collect(),
        nrm: pick.iter().map(|&i| source_normals[i]).collect(),
        target: IcpCloud {
            points: target,
            normals: Some(target_normals),
            covariances: None,
        },
        target_normals,
        target_index,
        icp: IcpConfig {
            factor: IcpFactor::PointToPlane,
            kernel: RobustKernel::Huber,
            max_correspondence_distance: cfg.icp_distance_voxels * voxel,
            translation_tolerance: 1e-3 * voxel,
            max_iterations: cfg.icp_iterations,
            trim: Trim::default(),
            sided,
            ..IcpConfig::default()
        },
        tau: cfg.tight_distance_voxels * voxel,
        reach2: (cfg.icp_distance_voxels * voxel).powi(2) as f32,
        cos_max: cfg.max_normal_angle_deg.to_radians().cos(),
        sided,
        constraint,
        prior,
    };
    let order = |v: &mut Vec<Verified>| {
        v.sort_by(|a, b| {
            b.score
                .total_cmp(&a.score)
                .then(a.candidate.cmp(&b.candidate))
        })
    };
    // Stage 1: all candidates, coarsely.
    let mut first: Vec<Verified> = candidates
        .par_iter()
        .enumerate()
        .map(|(k, c)| {
            let (transform, score) = v.refine(c, 3, cfg.icp_iterations.div_ceil(3));
            Verified {
                transform,
                score,
                candidate: k,
            }
        })
        .collect();
    order(&mut first);
    // Stage 2: the best few, fully.
    let n = cfg.refine_top.max(1).min(first.len());
    let rest = first.split_off(n);
    let mut best: Vec<Verified> = first
        .par_iter()
        .map(|c| {
            let (transform, score) = v.refine(&c.transform, 1, cfg.icp_iterations);
            Verified {
                transform,
                score,
                candidate: c.candidate,
            }
        })
        .collect();
    order(&mut best);
    best.extend(rest);
    best
}

/// The verification's sample of the source and its settings: refines a candidate with a short ICP and
/// scores it.
struct Verifier<'a> {
    /// The normal-space sample of the source, and its normals.
    pts: Vec<[f32; 3]>,
    nrm: Vec<[f32; 3]>,
    target: IcpCloud<'a>,
    target_normals: &'a [[f32; 3]],
    target_index: &'a KdIndex,
    /// The short ICP's settings (its iteration budget is set per stage).
    icp: IcpConfig,
    /// Tight distance of the score, cloud units.
    tau: f64,
    /// Squared reach of a pair, cloud units².
    reach2: f32,
    /// Smallest cosine between a pair's normals.
    cos_max: f64,
    sided: bool,
    constraint: &'a PoseConstraint,
    prior: Option<HypothesisPrior<'a>>,
}

impl Verifier<'_> {
    /// The alignment score of `t` on every `step`-th sample point, in [0, 1]: each point within reach whose
    /// normal agrees scores `1 − (d/τ)²` by its point-to-plane distance `d` (0 beyond τ).
    fn score(&self, t: &Isometry3<f64>, step: usize) -> f64 {
        let rot = t.rotation;
        let (target, target_normals) = (self.target.points, self.target_normals);
        let (sum, n) = self
            .pts
            .iter()
            .zip(&self.nrm)
            .step_by(step)
            .map(|(p, n)| {
                let pw = transform_point(t, p);
                // The nearest within reach (the search is bounded by it): beyond it the point scores 0.
                let Some((j, _)) = self.target_index.nearest_within(&pw, self.reach2) else {
                    return 0.0;
                };
                let nt = to_v64(&target_normals[j]);
                let cos = (rot * to_v64(n)).dot(&nt);
                if (if self.sided { cos } else { cos.abs() }) < self.cos_max {
                    return 0.0;
                }
                let d = nt.dot(&(to_v64(&pw) - to_v64(&target[j]))).abs();
                (1.0 - (d / self.tau).powi(2)).max(0.0)
            })
            .fold((0.0, 0usize), |a, s| (a.0 + s, a.1 + 1));
        sum / n.max(1) as f64
    }

    /// `from` refined by at most `iterations` ICP steps on every `step`-th sample point, with its score
    /// (0 when the refinement leaves the constraint; times the prior when given).
    fn refine(
        &self,
        from: &Isometry3<f64>,
        step: usize,
        iterations: usize,
    ) -> (Isometry3<f64>, f64) {
        let sub: Vec<[f32; 3]> = self.pts.iter().step_by(step).copied().collect();
        let sub_normals: Vec<[f32; 3]> = self.nrm.iter().step_by(step).copied().collect();
        let c = IcpConfig {
            max_iterations: iterations.max(1),
            ..self.icp.clone()
        };
        let source_cloud = IcpCloud {
            points: &sub,
            normals: self.sided.then_some(sub_normals.as_slice()),
            covariances: None,
        };
        let refined = icp(&source_cloud, &self.target, self.target_index, from, &c)
            .map(|r| r.transform)
            .unwrap_or(*from);
        let s = if self.constraint.accepts(&refined) {
            let s = self.score(&refined, step);
            // The prior (in [0, 1]) cannot lift a score of 0: not evaluated then.
            match self.prior {
                Some(f) if s > 0.0 => s * f(&refined),
                _ => s,
            }
        } else {
            0.0
        };
        (refined, s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_space_sample_balances_directions() {
        // 9000 points facing up, 300 facing +x, 300 facing +y: a sample of 900 takes 300 of each.
        let mut n = vec![[0.0f32, 0.0, 1.0]; 9000];
        n.extend(vec![[1.0f32, 0.0, 0.0]; 300]);
        n.extend(vec![[0.0f32, -1.0, 0.0]; 300]);
        let s = normal_space_sample(&n, 900);
        let up = s.iter().filter(|&&i| i < 9000).count();
        assert_eq!(s.len(), 900);
        assert_eq!(up, 300);
        // Opposite normals share a bin (sign-free).
        assert_eq!(normal_bin(&[0.0, 0.0, 1.0]), normal_bin(&[0.0, 0.0, -1.0]));
        assert_ne!(normal_bin(&[0.0, 0.0, 1.0]), normal_bin(&[1.0, 0.0, 0.0]));
    }
}
