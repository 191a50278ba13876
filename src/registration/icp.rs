//! Trimmed robust ICP, composed from parts in the manner of small_gicp:
//!
//! 1. **correspondences**: nearest target point of each transformed source point (kd-tree), within
//!    `max_correspondence_distance`;
//! 2. **trimming**: keep the closest fraction ξ of the source points. With [`Trim::Auto`] ξ is chosen
//!    each iteration by minimising Chetverikov's FTrICP objective `ψ(ξ) = e(ξ) / ξ^(1+λ)` (e = trimmed mean
//!    squared distance), which estimates the overlap ratio on the fly;
//! 3. **factor**: point-to-plane (`nᵀ(T p − q)`, needs target normals), point-to-point (`T p − q`), or
//!    generalized ICP (plane-to-plane: `eᵀ(C_q + R C_p Rᵀ)⁻¹e` with `e = q − T p`, needs both clouds'
//!    [`crate::preprocess::normals::estimate_covariances`]);
//! 4. **robust kernel**: IRLS weights from a [`RobustKernel`] on each pair's residual norm, at a scale
//!    re-estimated each iteration from the RMS of the kept pairs' residual norms;
//! 5. **optimiser**: one Gauss-Newton step on a left increment `[ω, v]` per iteration, Anderson-accelerated
//!    while the steps are large ([`crate::registration::anderson`]);
//! 6. **termination**: the step is below both tolerances (`converged = true`), the plain steps return to a
//!    pose of the last [`MAX_CYCLE`] iterations within those tolerances (a cycle of alternating
//!    correspondences: `converged = true`, the cycle's extent in [`IcpResult::cycle`]), or the iteration
//!    budget is spent (`converged = false`).
//!
//! The increment, the information matrix and the covariance are all in the parameterisation
//! `T ← exp([ω]×)·T + v`: rotation (radians) about the target frame's origin, then translation (cloud units).

use crate::error::{check, Error, Result};
use crate::geometry::cloud::{to_v64, transform_point};
use crate::geometry::outer::OuterSum6;
use crate::geometry::transform::apply_left_increment;
use crate::index::{KdIndex, NearestMemo};
use crate::preprocess::normals::LazyNormals;
use crate::registration::anderson::Anderson;
use crate::registration::kernel::RobustKernel;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The residual minimised.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpFactor {
    /// Distance along the target normal (needs target normals).
    #[default]
    PointToPlane,
    /// Euclidean distance.
    PointToPoint,
    /// Generalized ICP (Segal et al. 2009, plane-to-plane): the Mahalanobis distance under the sum of both
    /// points' local surface covariances (needs source and target covariances). Less biased than
    /// point-to-plane where the two clouds sample a surface differently (measured on simulated cells from
    /// the truth: see docs/accuracy.md).
    Gicp,
}

/// A cloud as ICP uses it: points and whatever per-point geometry the factor needs.
#[derive(Clone, Copy, Debug)]
pub struct IcpCloud<'a> {
    /// The points.
    pub points: &'a [[f32; 3]],
    /// Unit normals (sign free), one per point: point-to-plane needs them on the target, and when the
    /// target has them the reported information matrix is the point-to-plane one whatever the factor.
    pub normals: Option<&'a [[f32; 3]]>,
    /// Regularised local covariances `[xx, xy, xz, yy, yz, zz]`, one per point (GICP needs them on both).
    pub covariances: Option<&'a [[f32; 6]]>,
}

impl<'a> IcpCloud<'a> {
    /// Points only.
    pub fn points(points: &'a [[f32; 3]]) -> Self {
        IcpCloud {
            points,
            normals: None,
            covariances: None,
        }
    }
}

/// How much of the source is kept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Trim {
    /// Every correspondence within the distance limit.
    None,
    /// A fixed overlap ratio ξ in (0, 1].
    Fixed(f64),
    /// FTrICP: ξ in `[min_overlap, 1]` minimising `e(ξ)/ξ^(1+λ)`.
    Auto {
        /// Smallest overlap considered (default 0.05).
        min_overlap: f64,
        /// Chetverikov's λ (default 2).
        lambda: f64,
    },
}

impl Default for Trim {
    fn default() -> Self {
        Trim::Auto {
            min_overlap: 0.05,
            lambda: 2.0,
        }
    }
}

/// Parameters of one ICP run at one resolution.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IcpConfig {
    /// Residual type (default point-to-plane).
    pub factor: IcpFactor,
    /// Robust kernel (default Huber).
    pub kernel: RobustKernel,
    /// Kernel scale as a multiple of the RMS of the kept residuals (default 3).
    pub kernel_scale_sigmas: f64,
    /// Smallest kernel scale (cloud units; default 0: none).
    pub min_kernel_scale: f64,
    /// Pairs farther apart than this are never used (cloud units; default 0.05, 5 cm for clouds in
    /// metres). The `register` pipeline overwrites it at each ICP level with
    /// [`RegisterConfig::icp_distance_voxels`](crate::registration::RegisterConfig::icp_distance_voxels)
    /// times that level's voxel.
    pub max_correspondence_distance: f64,
    /// Trimming (default FTrICP automatic overlap).
    pub trim: Trim,
    /// Iteration budget (default 40).
    pub max_iterations: usize,
    /// Converged when the rotation step is below this (radians; default 1e-5).
    pub rotation_tolerance: f64,
    /// Converged when the translation step is below this (cloud units; default 1e-5, 10 µm for clouds in
    /// metres). The `register` pipeline overwrites it at each ICP level with 1e-3 times that level's voxel.
    pub translation_tolerance: f64,
    /// Pairs whose normals differ by more than this are not used, degrees (sign-free; needs normals on
    /// both clouds, ignored otherwise). `None` (default) uses every pair. Rejects pairs between different
    /// surfaces, e.g. a face one robot saw with the edge of a face the other saw.
    pub max_normal_angle_deg: Option<f64>,
    /// Both clouds' normals carry the side their surfaces were seen from (they point toward the sensors):
    /// the normal test above becomes signed, and pairs whose normals point to opposite sides are never
    /// used even without `max_normal_angle_deg` (default false).
    pub sided: bool,
    /// Anderson acceleration of the iterations (AA-ICP, [`crate::registration::anderson`]): the number of
    /// past steps combined, 0 for none (default 3), at most 20. It acts only while a step exceeds 100
    /// times the tolerances (a rough start): near the solution the steps are taken plain, so a start near
    /// it gives the unaccelerated result exactly. A proposal that raises the truncated point-to-point
    /// energy (`Σ min(d², τ²)` over the source points, τ the correspondence distance) is dropped for the
    /// plain step, at the cost of one more correspondence search.
    pub acceleration: usize,
}

impl Default for IcpConfig {
    fn default() -> Self {
        IcpConfig {
            factor: IcpFactor::PointToPlane,
            kernel: RobustKernel::Huber,
            kernel_scale_sigmas: 3.0,
            min_kernel_scale: 0.0,
            max_correspondence_distance: 0.05,
            trim: Trim::default(),
            max_iterations: 40,
            rotation_tolerance: 1e-5,
            translation_tolerance: 1e-5,
            max_normal_angle_deg: None,
            sided: false,
            acceleration: 3,
        }
    }
}

impl IcpConfig {
    /// Checks the ranges; the error names the field (`icp.…`).
    pub fn validate(&self) -> Result<()> {
        self.validate_shape()?;
        check::positive(
            "icp.max_correspondence_distance",
            self.max_correspondence_distance,
        )?;
        check::positive("icp.translation_tolerance", self.translation_tolerance)
    }

    /// Every check but the two fields the `register` pipeline sets per level.
    pub(crate) fn validate_shape(&self) -> Result<()> {
        check::positive("icp.kernel_scale_sigmas", self.kernel_scale_sigmas)?;
        check::non_negative("icp.min_kernel_scale", self.min_kernel_scale)?;
        check::at_least("icp.max_iterations", self.max_iterations, 1)?;
        check::positive("icp.rotation_tolerance", self.rotation_tolerance)?;
        check::at_most("icp.acceleration", self.acceleration, 20)?;
        if let Some(a) = self.max_normal_angle_deg {
            check::angle_deg("icp.max_normal_angle_deg", a)?;
        }
        match self.trim {
            Trim::None => Ok(()),
            Trim::Fixed(xi) => check::fraction("icp.trim.fixed", xi),
            Trim::Auto {
                min_overlap,
                lambda,
            } => {
                check::fraction("icp.trim.auto.min_overlap", min_overlap)?;
                check::positive("icp.trim.auto.lambda", lambda)
            }
        }
    }
}

/// Result of an ICP run.
#[derive(Clone, Debug)]
pub struct IcpResult {
    /// Source-to-target transform.
    pub transform: Isometry3<f64>,
    /// Iterations run.
    pub iterations: usize,
    /// True when the step fell below both tolerances within the budget, or the steps came back to a pose
    /// visited before (then [`IcpResult::cycle`] holds the motion left).
    pub converged: bool,
    /// When the iterations settled into a cycle instead of a fixed point (the pairs alternate between two
    /// or more sets, each step undoing the last): its extent, the largest step within it. The answer can
    /// lie anywhere on the cycle, so a covariance should cover this much motion.
    pub cycle: Option<IcpCycle>,
    /// Fraction of source points with a target point within `max_correspondence_distance`.
    pub fitness: f64,
    /// RMS point-to-point distance of those pairs (cloud units).
    pub inlier_rmse: f64,
    /// Overlap ratio ξ kept by the trimming at the last iteration.
    pub overlap: f64,
    /// RMS of the kept residuals at the end (cloud units).
    pub residual_sigma: f64,
    /// Number of pairs used in the last step.
    pub pairs: usize,
    /// Information matrix `JᵀWJ` at the solution (unit-less weights; order ω then v).
    pub information: Matrix6<f64>,
    /// `Σ w r²` at the solution.
    pub weighted_sse: f64,
    /// `Σ_b g_b g_bᵀ` at the solution, where `g_b = Σ w J r` over the reported rows of the kept pairs
    /// whose source points fall in spatial block `b` (cubes of [`block_edge`] of the kept source points):
    /// the "meat" of a cluster-robust covariance `H⁻¹ M H⁻¹` ([`IcpResult::information`] is `H`).
    /// Residuals that are correlated within a block (a misfit shared by a surface patch) add up here
    /// instead of averaging out as `σ² H⁻¹` assumes.
    pub block_scores: Matrix6<f64>,
    /// Number of spatial blocks holding kept pairs (the clusters of [`IcpResult::block_scores`]).
    pub blocks: usize,
    /// One record per iteration, in order (the last one is the solution's, with no step).
    pub history: Vec<IcpIteration>,
}

/// The extent of an ICP cycle ([`IcpResult::cycle`]): its period and its largest step's parts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IcpCycle {
    /// Poses in the cycle (2 to [`MAX_CYCLE`]).
    pub period: usize,
    /// The largest rotation step within the cycle, radians.
    pub rotation: f64,
    /// The largest translation step within the cycle, cloud units.
    pub translation: f64,
}

/// The longest cycle [`icp`] recognises: a plain step that lands within the tolerances of one of the last
/// this many poses ends the iterations.
pub const MAX_CYCLE: usize = 4;

/// What one ICP iteration saw and did: its correspondences, the kept pairs' residuals and the step it took.
/// Recording it changes no result.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IcpIteration {
    /// Source points with a target point within the correspondence distance (and normal test).
    pub pairs: usize,
    /// Pairs kept by the trimming and used in the step.
    pub kept: usize,
    /// `pairs` over the source points, 0–1.
    pub fitness: f64,
    /// RMS point-to-point distance of all `pairs` (cloud units).
    pub rmse: f64,
    /// RMS of the kept pairs' residuals (cloud units; point-to-plane when the target has normals).
    pub residual_sigma: f64,
    /// Rotation of the Gauss-Newton step computed at this iteration, radians (`None` for the last record);
    /// under acceleration the move taken can be longer.
    pub step_rotation: Option<f64>,
    /// Translation of that step (cloud units; `None` for the last record).
    pub step_translation: Option<f64>,
    /// Wall time of the iteration (correspondences, trimming, normal equations, step; and the search at an
    /// accelerated pose that was dropped before it), milliseconds.
    pub time_ms: f64,
}

struct Pair {
    i: u32,
    j: u32,
    d2: f32,
    /// The source point after the current transform.
    pw: [f32; 3],
}

/// Chooses the number of pairs to keep among `sorted_d2` (ascending) out of `n_source` points.
fn trimmed_count(sorted_d2: &[f32], n_source: usize, trim: Trim) -> usize {
    let m = sorted_d2.len();
    match trim {
        Trim::None => m,
        Trim::Fixed(xi) => ((xi * n_source as f64).round() as usize).clamp(3.min(m), m),
        Trim::Auto {
            min_overlap,
            lambda,
        } => {
            if m == 0 {
                return 0;
            }
            // ψ is evaluated on a grid of 0.5% steps of ξ (and at the largest possible ξ).
            let n = n_source as f64;
            let mut prefix = Vec::with_capacity(m);
            let mut acc = 0f64;
            for d in sorted_d2 {
                acc += *d as f64;
                prefix.push(acc);
            }
            // A floor on e (0.1% of the mean squared distance) keeps exact zeros of noise-free data from
            // making every small ξ look perfect.
            let floor = 1e-3 * acc / m as f64;
            let psi = |cnt: usize| {
                let xi = cnt as f64 / n;
                (prefix[cnt - 1] / cnt as f64 + floor) / xi.powf(1.0 + lambda)
            };
            let start = ((min_overlap * n).ceil() as usize).clamp(1, m);
            let step = ((0.005 * n) as usize).max(1);
            // Ties (e.g. a noise-free overlap where e = 0) go to the larger ξ.
            let mut best = (f64::INFINITY, start);
            let mut cnt = start;
            loop {
                let v = psi(cnt);
                if v <= best.0 {
                    best = (v, cnt);
                }
                if cnt == m {
                    break;
                }
                cnt = (cnt + step).min(m);
            }
            best.1.max(3.min(m))
        }
    }
}

/// One residual row `r = uᵀ(p_w − q)` and its Jacobian `[(p_w × u)ᵀ, uᵀ]` for the update
/// `p_w ← p_w + ω × p_w + v`.
#[inline]
fn row(pw: &[f32; 3], q: &[f32; 3], u: &Vector3<f64>) -> (Vector6<f64>, f64) {
    (jacobian(pw, u), u.dot(&(to_v64(pw) - to_v64(q))))
}

/// The Jacobian `[(p_w × u)ᵀ, uᵀ]` of [`row`].
#[inline]
fn jacobian(pw: &[f32; 3], u: &Vector3<f64>) -> Vector6<f64> {
    let c = to_v64(pw).cross(u);
    Vector6::new(c.x, c.y, c.z, u.x, u.y, u.z)
}

/// A 3x3 symmetric matrix from its packed upper triangle `[xx, xy, xz, yy, yz, zz]`.
#[inline]
fn unpack(c: &[f32; 6]) -> Matrix3<f64> {
    let c = c.map(|x| x as f64);
    Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5])
}

/// The rows of one pair: up to three `(Jacobian, residual)` and the pair's residual norm.
type PairRows = ([(Vector6<f64>, f64); 3], usize, f64);

/// Pairs per chunk of [`Rows::normal_equations`]' reduction (fixed: the same bits at any thread count).
const CHUNK: usize = 512;

/// The residual rows of the kept pairs. A point-to-plane row is kept as its target normal and residual (20
/// bytes, the one pass that reads the target) and its Jacobian made where it is used: over hundreds of
/// thousands of pairs, writing whole rows out (184 bytes a pair) and reading them back costs more. The
/// other factors' rows (GICP's whitening takes a 3x3 inverse and a Cholesky factor a pair) are stored.
enum Rows<'p> {
    /// The pairs, and per pair the target normal and the point-to-plane residual.
    Plane(&'p [Pair], Vec<([f32; 3], f64)>),
    Stored(Vec<PairRows>),
}

impl<'p> Rows<'p> {
    /// The point-to-plane rows of `kept` against `problem`'s target normals.
    fn plane(problem: &Problem, kept: &'p [Pair]) -> Self {
        let ns = problem.normals.as_ref().expect("checked");
        Rows::Plane(
            kept,
            kept.par_iter()
                .map(|pr| {
                    let n = ns.get(pr.j as usize);
                    let q = &problem.target[pr.j as usize];
                    (n, row(&pr.pw, q, &to_v64(&n)).1)
                })
                .collect(),
        )
    }

    fn len(&self) -> usize {
        match self {
            Rows::Plane(kept, _) => kept.len(),
            Rows::Stored(rows) => rows.len(),
        }
    }

    /// The rows of pair `k`.
    #[inline]
    fn get(&self, k: usize) -> PairRows {
        match self {
            Rows::Plane(kept, nr) => {
                // `row`, with the normal and residual kept.
                let (n, r) = nr[k];
                let z = (Vector6::zeros(), 0.0);
                ([(jacobian(&kept[k].pw, &to_v64(&n)), r), z, z], 1, r.abs())
            }
            Rows::Stored(rows) => rows[k],
        }
    }

    /// RMS of the pairs' residual norms, and RMS of their individual rows.
    fn residual_scales(&self) -> (f64, f64) {
        let (rows, ss) = match self {
            Rows::Plane(_, nr) => (
                nr.len(),
                nr.iter().map(|(_, r)| r.abs() * r.abs()).sum::<f64>(),
            ),
            Rows::Stored(pairs) => (
                pairs.iter().map(|p| p.1).sum(),
                pairs.iter().map(|p| p.2 * p.2).sum(),
            ),
        };
        let n = self.len().max(1) as f64;
        ((ss / n).sqrt(), (ss / rows.max(1) as f64).sqrt())
    }

    /// Accumulates `JᵀWJ`, `JᵀWr` and `Σ w r²` over the rows, with the kernel weight of each pair's residual
    /// norm at scale `c`. Fixed-size chunks summed in order: the same bits at any thread count.
    fn normal_equations(&self, kernel: RobustKernel, c: f64) -> (Matrix6<f64>, Vector6<f64>, f64) {
        let len = self.len();
        (0..len.div_ceil(CHUNK))
            .into_par_iter()
            .map(|chunk| {
                let (mut h, mut g, mut sse) = (OuterSum6::default(), Vector6::zeros(), 0.0);
                for k in chunk * CHUNK..((chunk + 1) * CHUNK).min(len) {
                    let (rows, n, norm) = self.get(k);
                    let w = kernel.weight(norm, c);
                    for (j, r) in &rows[..n] {
                        h.add(j, w);
                        g += j * (w * r);
                        sse += w * r * r;
                    }
                }
                (h.matrix(), g, sse)
            })
            .collect::<Vec<_>>()
            .into_iter()
            .fold((Matrix6::zeros(), Vector6::zeros(), 0.0), |a, b| {
                (a.0 + b.0, a.1 + b.1, a.2 + b.2)
            })
    }
}

/// Runs ICP from `init`, moving `source` onto `target` (indexed by `target_index`). Point-to-plane needs
/// target normals; GICP needs covariances on both clouds.
pub fn icp(
    source: &IcpCloud,
    target: &IcpCloud,
    target_index: &KdIndex,
    init: &Isometry3<f64>,
    cfg: &IcpConfig,
) -> Result<IcpResult> {
    icp_with(source, target, None, target_index, init, cfg)
}

/// As [`icp`], with the target's normals computed on first use (`lazy`, over `target.points`; its
/// `normals` must be `None`): at a fine level only the target points paired with the source sample ever
/// need a normal. The result is the one eager normals give, bit for bit.
pub fn icp_lazy_normals(
    source: &IcpCloud,
    target: &IcpCloud,
    lazy: &LazyNormals,
    target_index: &KdIndex,
    init: &Isometry3<f64>,
    cfg: &IcpConfig,
) -> Result<IcpResult> {
    if target.normals.is_some() {
        return Err(Error::InvalidInput(
            "ICP with lazy normals takes a target without normals".into(),
        ));
    }
    icp_with(source, target, Some(lazy), target_index, init, cfg)
}

/// The target's normals: a slice, computed on first use, or none.
#[derive(Clone, Copy)]
enum TargetNormals<'a> {
    Slice(&'a [[f32; 3]]),
    Lazy(&'a LazyNormals<'a>),
}

impl TargetNormals<'_> {
    #[inline]
    fn get(&self, j: usize) -> [f32; 3] {
        match self {
            TargetNormals::Slice(n) => n[j],
            TargetNormals::Lazy(l) => l.get(j),
        }
    }
}

/// Cos of the largest angle allowed between a pair's normals, with both clouds' normals (`sided`: opposite
/// sides never pair; otherwise sign-free).
type NormalGate<'a> = (f32, &'a [[f32; 3]], TargetNormals<'a>);

/// Source and target covariances, packed upper triangles (cloud units²).
type CovariancePair<'a> = (&'a [[f32; 6]], &'a [[f32; 6]]);

/// One ICP problem, checked: the clouds, the factor's data and the pairing rules. Each iteration is
/// [`Self::correspondences`] → trimming → [`Self::rows`] → the normal equations → a Gauss-Newton step.
struct Problem<'a> {
    /// Source points (moved by the estimate).
    source: &'a [[f32; 3]],
    /// Target points.
    target: &'a [[f32; 3]],
    /// The target's index.
    index: &'a KdIndex,
    /// The target's normals, when it has (or computes) them.
    normals: Option<TargetNormals<'a>>,
    /// Source and target covariances (GICP only).
    covariances: Option<CovariancePair<'a>>,
    /// The normal-compatibility gate, when one applies.
    gate: Option<NormalGate<'a>>,
    /// The settings.
    cfg: &'a IcpConfig,
    /// Squared correspondence distance limit, cloud units².
    maxd2: f32,
}

impl<'a> Problem<'a> {
    /// Checks the settings and the clouds against the factor and gathers what the iterations need.
    fn new(
        source: &'a IcpCloud,
        target: &'a IcpCloud,
        lazy: Option<&'a LazyNormals>,
        index: &'a KdIndex,
        cfg: &'a IcpConfig,
    ) -> Result<Self> {
        if cfg.max_correspondence_distance.is_nan()
            || cfg.max_correspondence_distance <= 0.0
            || cfg.translation_tolerance.is_nan()
            || cfg.translation_tolerance <= 0.0
        {
            return Err(Error::Config {
                field: "icp.max_correspondence_distance / icp.translation_tolerance".into(),
                msg: "must be positive".into(),
            });
        }
        if source.points.len() < 3 || target.points.len() < 3 {
            return Err(Error::InvalidInput(format!(
                "ICP needs at least 3 points in each cloud (source {}, target {})",
                source.points.len(),
                target.points.len()
            )));
        }
        let lengths_ok = |c: &IcpCloud| {
            c.normals.is_none_or(|n| n.len() == c.points.len())
                && c.covariances.is_none_or(|v| v.len() == c.points.len())
        };
        if !lengths_ok(source) || !lengths_ok(target) {
            return Err(Error::InvalidInput(
                "ICP needs one normal / covariance per point".into(),
            ));
        }
        if index.len() != target.points.len() {
            return Err(Error::InvalidInput(format!(
                "ICP's target index holds {} points, the target {}: it must be built over the target",
                index.len(),
                target.points.len()
            )));
        }
        let normals: Option<TargetNormals> = match (target.normals, lazy) {
            (Some(n), _) => Some(TargetNormals::Slice(n)),
            (None, Some(l)) => Some(TargetNormals::Lazy(l)),
            (None, None) => None,
        };
        let covariances = match cfg.factor {
            IcpFactor::PointToPlane => {
                if normals.is_none() {
                    return Err(Error::InvalidInput(
                        "point-to-plane ICP needs target normals".into(),
                    ));
                }
                None
            }
            IcpFactor::PointToPoint => None,
            IcpFactor::Gicp => match (source.covariances, target.covariances) {
                (Some(s), Some(t)) => Some((s, t)),
                _ => {
                    return Err(Error::InvalidInput(
                        "GICP needs source and target covariances".into(),
                    ))
                }
            },
        };
        let gate = match (cfg.max_normal_angle_deg, source.normals, normals) {
            (Some(a), Some(ns), Some(nt)) => Some((a.to_radians().cos() as f32, ns, nt)),
            (None, Some(ns), Some(nt)) if cfg.sided => Some((0.0, ns, nt)),
            _ => None,
        };
        Ok(Problem {
            source: source.points,
            target: target.points,
            index,
            normals,
            covariances,
            gate,
            cfg,
            maxd2: (cfg.max_correspondence_distance * cfg.max_correspondence_distance) as f32,
        })
    }

    /// Every source point's nearest target point within the distance limit under `t` that passes the
    /// normal gate, in source order. `memos` (one per source point, from the previous call or
    /// [`NearestMemo::EMPTY`]) lets a point that has moved little since keep its answer without a search
    /// ([`KdIndex::nearest_within_memo`]: always the answer a search gives) and is updated.
    fn correspondences(&self, t: &Isometry3<f64>, memos: &mut [NearestMemo]) -> Vec<Pair> {
        debug_assert_eq!(memos.len(), self.source.len());
        let rot32: [[f32; 3]; 3] = {
            let m = t.rotation.to_rotation_matrix();
            std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)] as f32))
        };
        let (maxd2, sided) = (self.maxd2, self.cfg.sided);
        self.source
            .par_iter()
            .zip(memos.par_iter_mut())
            .enumerate()
            .filter_map(|(i, (p, memo))| {
                let pw = transform_point(t, p);
                // Pairs beyond the distance limit are never used: a bounded search skips them early.
                let (j, d2) = self.index.nearest_within_memo(&pw, maxd2, memo)?;
                if let Some((cmin, ns, nt)) = self.gate {
                    let n = ns[i];
                    let m = &rot32;
                    let nt = nt.get(j);
                    let dot: f32 = (0..3)
                        .map(|r| (m[r][0] * n[0] + m[r][1] * n[1] + m[r][2] * n[2]) * nt[r])
                        .sum();
                    if (if sided { dot } else { dot.abs() }) < cmin {
                        return None;
                    }
                }
                (d2 <= maxd2).then_some(Pair {
                    i: i as u32,
                    j: j as u32,
                    d2,
                    pw,
                })
            })
            .collect()
    }

    /// The point-to-plane row of a pair (the target point's normal), as [`Rows::plane`] was first written:
    /// its oracle.
    #[cfg(test)]
    fn plane_rows(&self, pr: &Pair) -> PairRows {
        let ns = self.normals.expect("checked");
        let r = row(
            &pr.pw,
            &self.target[pr.j as usize],
            &to_v64(&ns.get(pr.j as usize)),
        );
        let z = (Vector6::zeros(), 0.0);
        ([r, z, z], 1, r.1.abs())
    }

    /// The residual rows of the kept pairs under `t`: one for point-to-plane, three for point-to-point
    /// and GICP (whitened by the pair's combined covariance).
    fn rows<'p>(&'p self, kept: &'p [Pair], t: &Isometry3<f64>) -> Rows<'p> {
        Rows::Stored(match self.cfg.factor {
            IcpFactor::PointToPlane => return Rows::plane(self, kept),
            IcpFactor::PointToPoint => kept
                .par_iter()
                .map(|pr| {
                    let q = &self.target[pr.j as usize];
                    let r = [Vector3::x(), Vector3::y(), Vector3::z()].map(|u| row(&pr.pw, q, &u));
                    (r, 3, (pr.d2 as f64).sqrt())
                })
                .collect(),
            IcpFactor::Gicp => {
                let (cs, ct) = self.covariances.expect("checked");
                let rot = t.rotation.to_rotation_matrix();
                let rm = rot.matrix();
                kept.par_iter()
                    .map(|pr| {
                        let q = &self.target[pr.j as usize];
                        let c = unpack(&ct[pr.j as usize])
                            + rm * unpack(&cs[pr.i as usize]) * rm.transpose();
                        // Ω = C⁻¹ = L Lᵀ: the rows are the columns of L, so that Σ r² = eᵀΩe.
                        let l = c
                            .try_inverse()
                            .and_then(|o| o.cholesky())
                            .map(|ch| ch.l())
                            .unwrap_or_else(Matrix3::identity);
                        let r = [0, 1, 2].map(|k| row(&pr.pw, q, &l.column(k).into_owned()));
                        let norm = r.iter().map(|x| x.1 * x.1).sum::<f64>().sqrt();
                        (r, 3, norm)
                    })
                    .collect()
            }
        })
    }

    /// The kernel scale for rows whose pair residual RMS is `pair_sigma`: `kernel_scale_sigmas` of it, at
    /// least `min_kernel_scale`. The RMS of the kept pairs, not a MAD: trimming has already removed the
    /// gross outliers, and a MAD-based scale would let a large consistent subset silence a smaller one.
    fn kernel_scale(&self, pair_sigma: f64) -> f64 {
        (self.cfg.kernel_scale_sigmas * pair_sigma.max(1e-12))
            .max(self.cfg.min_kernel_scale)
            .max(1e-12)
    }

    /// Leaves in `pairs` (in source order) those the trimming keeps, the nearest (ties to the smaller
    /// source index), and gives every pair's squared distance, sorted. Only the distances are sorted: the
    /// kept pairs stay in source order, so the rows read the target in the source's spatial order.
    fn trim(&self, pairs: &mut Vec<Pair>) -> Vec<f32> {
        let mut d2s: Vec<f32> = pairs.par_iter().map(|p| p.d2).collect();
        crate::stats::sort_f32(&mut d2s);
        let keep = trimmed_count(&d2s, self.source.len(), self.cfg.trim);
        if keep == 0 {
            pairs.clear();
        } else if keep < pairs.len() {
            // Those below the bar, then as many at it as there is room for: the first in source order.
            let bar = d2s[keep - 1];
            let mut at_bar = keep - d2s.partition_point(|&d| d < bar);
            pairs.retain(|p| {
                let take = p.d2 < bar || (p.d2 == bar && at_bar > 0);
                if p.d2 == bar && take {
                    at_bar -= 1;
                }
                take
            });
        }
        d2s
    }

    /// The rows of what is reported ([`Problem::reported_system`]): point-to-plane whenever the target has
    /// normals, else the factor's own.
    fn reported_rows<'p>(&'p self, kept: &'p [Pair], t: &Isometry3<f64>) -> Rows<'p> {
        if self.normals.is_some() {
            Rows::plane(self, kept)
        } else {
            self.rows(kept, t)
        }
    }

    /// What is reported (information, residual σ, weighted SSE): the point-to-plane system whenever the
    /// target has normals, so that covariance and degeneracy mean the same whatever the factor; else the
    /// factor's own system `(h, row_sigma, sse)`.
    fn reported_system(
        &self,
        kept: &[Pair],
        own: (Matrix6<f64>, f64, f64),
    ) -> (Matrix6<f64>, f64, f64) {
        if self.cfg.factor != IcpFactor::PointToPlane && self.normals.is_some() {
            let prow = Rows::plane(self, kept);
            let (ps, _) = prow.residual_scales();
            let (ph, _, psse) = prow.normal_equations(self.cfg.kernel, self.kernel_scale(ps));
            (ph, ps.max(1e-12), psse)
        } else {
            (own.0, own.1.max(1e-12), own.2)
        }
    }
}

impl Problem<'_> {
    /// [`IcpResult::block_scores`] and the number of blocks, from the kept pairs under `t`, with the rows
    /// and kernel weights of [`Problem::reported_system`].
    fn block_scores(&self, kept: &[Pair], t: &Isometry3<f64>) -> (Matrix6<f64>, usize) {
        if kept.is_empty() {
            return (Matrix6::zeros(), 0);
        }
        let rows = self.reported_rows(kept, t);
        let (ps, _) = rows.residual_scales();
        let c = self.kernel_scale(ps);
        let moved: Vec<[f32; 3]> = kept.iter().map(|p| p.pw).collect();
        let edge = block_edge(&moved);
        let mut blocks: std::collections::BTreeMap<[i64; 3], Vector6<f64>> = Default::default();
        for (k, pr) in kept.iter().enumerate() {
            let (rs, n, norm) = rows.get(k);
            let w = self.cfg.kernel.weight(norm, c);
            let key = pr.pw.map(|x| (x as f64 / edge).floor() as i64);
            let g = blocks.entry(key).or_insert_with(Vector6::zeros);
            for (j, r) in &rs[..n] {
                *g += j * (w * r);
            }
        }
        let m = blocks
            .values()
            .fold(Matrix6::zeros(), |a, g| a + g * g.transpose());
        (m, blocks.len())
    }
}

/// The information of the estimating equation with re-association: the derivative of the reported
/// gradient `Σ w J r` (the kept pairs' point-to-plane rows when the target has normals, kernel weights at
/// the scale found at `t`) with respect to the pose, by central differences of `step` (cloud units) along
/// three rotations about the kept points' centroid (moving them `step` at their RMS radius) and three
/// translations, each difference with correspondences and trimming found anew. `JᵀWJ` at `t` is this
/// derivative for correspondences held fixed; where sliding to other correspondences costs less than the
/// fixed pairs predict (a valley the pairs cannot see), this one is smaller. Same coordinates as
/// [`IcpResult::information`] (increments `[ω, v]` about the origin), symmetrised.
pub fn reassociated_information(
    source: &IcpCloud,
    target: &IcpCloud,
    lazy: Option<&LazyNormals>,
    target_index: &KdIndex,
    t: &Isometry3<f64>,
    cfg: &IcpConfig,
    step: f64,
) -> Result<Matrix6<f64>> {
    let problem = Problem::new(source, target, lazy, target_index, cfg)?;
    let kept_at = |pose: &Isometry3<f64>| {
        let mut pairs =
            problem.correspondences(pose, &mut vec![NearestMemo::EMPTY; problem.source.len()]);
        problem.trim(&mut pairs);
        pairs
    };
    let kept = kept_at(t);
    if kept.len() < 6 {
        return Err(Error::Failed(
            "too few pairs for the re-associated information".into(),
        ));
    }
    let c = problem.kernel_scale(problem.reported_rows(&kept, t).residual_scales().0);
    // Within half the kernel's scale the weights stay near their values at `t`: a longer step would
    // measure the kernel's bounded influence (and the trimming), not the cost's curvature.
    let step = step.min(0.5 * c).max(1e-12);
    let moved: Vec<[f32; 3]> = kept.iter().map(|p| p.pw).collect();
    let n = moved.len() as f64;
    let centre = moved.iter().fold(Vector3::zeros(), |a, p| a + to_v64(p)) / n;
    let radius = rms_radius(&moved).max(1e-12);
    // Basis of unit moves (cloud units at the RMS radius), as left increments [ω, v] about the origin.
    let mut basis = Matrix6::zeros();
    for k in 0..3 {
        let w = Vector3::ith(k, 1.0) / radius;
        let v = centre.cross(&w);
        basis.set_column(k, &Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z));
        basis[(k + 3, k + 3)] = 1.0;
    }
    let gradient = |pose: &Isometry3<f64>| -> Vector6<f64> {
        let kept = kept_at(pose);
        problem
            .reported_rows(&kept, pose)
            .normal_equations(cfg.kernel, c)
            .1
    };
    // K[:, k] = Bᵀ (g(+step b_k) − g(−step b_k)) / 2 step: the derivative in the basis' coordinates.
    let mut k_s = Matrix6::zeros();
    for k in 0..6 {
        let b: Vector6<f64> = basis.column(k).into_owned() * step;
        let gp = gradient(&apply_left_increment(t, &b));
        let gm = gradient(&apply_left_increment(t, &(-b)));
        k_s.set_column(k, &(basis.transpose() * (gp - gm) / (2.0 * step)));
    }
    let k_s = 0.5 * (k_s + k_s.transpose());
    // Back to [ω, v]: H = B⁻ᵀ K B⁻¹.
    let bi = basis
        .try_inverse()
        .ok_or_else(|| Error::Failed("singular basis".into()))?;
    Ok(bi.transpose() * k_s * bi)
}

/// Edge of the spatial blocks of [`IcpResult::block_scores`]: a quarter of the points' RMS radius
/// (cloud units).
fn block_edge(points: &[[f32; 3]]) -> f64 {
    (BLOCK_RADIUS_FRACTION * rms_radius(points)).max(1e-12)
}

/// [`block_edge`] over the points' RMS radius. On the real 3DLoMatch pair the cluster-robust 1-σ changed
/// little between an eighth, a quarter and a half (largest rotation 0.115°, 0.124°, 0.145°); a quarter
/// leaves 50-500 blocks on the pairs measured, enough to estimate a 6x6 matrix.
const BLOCK_RADIUS_FRACTION: f64 = 0.25;

/// The Gauss-Newton step of `h δ = −g` (a tiny Levenberg damping keeps a rank-deficient system
/// solvable); `None` when even LU fails.
fn gauss_newton_step(h: &Matrix6<f64>, g: &Vector6<f64>) -> Option<Vector6<f64>> {
    let damp = 1e-9 * h.trace().max(1e-30);
    let hd = h + Matrix6::identity() * damp;
    match hd.cholesky() {
        Some(ch) => Some(ch.solve(&(-g))),
        None => hd.lu().solve(&(-g)),
    }
}

/// Steps larger than this many tolerances (either part) are accelerated; smaller ones are taken plain.
const ACCELERATE_TOLERANCES: f64 = 100.0;

/// Anderson acceleration's state in [`icp_with`]: poses are parameterised by their left increment from the
/// initial pose.
struct Accelerated {
    anderson: Anderson,
    /// The plain step's pose and the energy before it, while an accelerated pose awaits its check.
    proposal: Option<(Isometry3<f64>, f64)>,
    /// The energy at the current pose.
    energy: f64,
}

impl Accelerated {
    /// The pose to evaluate next after the step from `t` to `plain`.
    fn propose(
        &mut self,
        init: &Isometry3<f64>,
        t: &Isometry3<f64>,
        plain: Isometry3<f64>,
    ) -> Isometry3<f64> {
        let (u, g) = (increment_from(init, t), increment_from(init, &plain));
        let next = self.anderson.next(&u, &g);
        if next == g {
            return plain;
        }
        self.proposal = Some((plain, self.energy));
        apply_left_increment(init, &next)
    }
}

/// The left increment `[ω, v]` that takes `from` to `to` (the inverse of [`apply_left_increment`]).
fn increment_from(from: &Isometry3<f64>, to: &Isometry3<f64>) -> Vector6<f64> {
    let rel = to * from.inverse();
    let w = rel.rotation.scaled_axis();
    let v = rel.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// RMS distance of `points` from their centroid (cloud units): the lever arm that turns a rotation into a
/// displacement.
fn rms_radius(points: &[[f32; 3]]) -> f64 {
    let n = points.len().max(1) as f64;
    let c = points.iter().fold(Vector3::zeros(), |a, p| a + to_v64(p)) / n;
    (points
        .iter()
        .map(|p| (to_v64(p) - c).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
}

/// The truncated point-to-point energy `Σ min(d², τ²)` over all `n_source` points: a source point without a
/// pair within τ counts τ².
fn truncated_energy(pairs: &[Pair], n_source: usize, maxd2: f32) -> f64 {
    let paired: f64 = pairs.iter().map(|p| p.d2 as f64).sum();
    paired + (n_source - pairs.len()) as f64 * maxd2 as f64
}

/// [`icp`] and [`icp_lazy_normals`]: iterate pairs → trim → rows → normal equations → step until the step
/// is below the tolerances or `max_iterations`.
fn icp_with(
    source: &IcpCloud,
    target: &IcpCloud,
    lazy: Option<&LazyNormals>,
    target_index: &KdIndex,
    init: &Isometry3<f64>,
    cfg: &IcpConfig,
) -> Result<IcpResult> {
    let problem = Problem::new(source, target, lazy, target_index, cfg)?;
    let n_source = problem.source.len();
    let mut t = *init;
    let mut converged = false;
    let mut iterations = 0;
    let mut last = None;
    let mut history = Vec::new();
    let mut accel = (cfg.acceleration > 0).then(|| Accelerated {
        anderson: Anderson::new(cfg.acceleration, rms_radius(problem.source)),
        proposal: None,
        energy: f64::INFINITY,
    });
    // Time of a pass whose accelerated pose was dropped, counted into the next record.
    let mut carried_ms = 0.0;
    // The pose and the kept pairs of the record in `last`.
    let mut last_kept: (Isometry3<f64>, Vec<Pair>) = (t, Vec::new());
    // What each source point's last search found: while it moves little, its answer stands.
    let mut memos = vec![NearestMemo::EMPTY; problem.source.len()];
    // The poses the last iterations were evaluated at (most recent last) and the steps taken from them.
    let mut recent: Vec<(Isometry3<f64>, f64, f64)> = Vec::with_capacity(MAX_CYCLE + 1);
    let mut cycle = None;
    for it in 0..=cfg.max_iterations {
        let it_start = std::time::Instant::now();
        let mut pairs = problem.correspondences(&t, &mut memos);
        if let Some(a) = accel.as_mut() {
            let energy = truncated_energy(&pairs, n_source, problem.maxd2);
            if let Some((plain, before)) = a.proposal.take() {
                if energy > before {
                    // The accelerated pose is worse than the one it left: take the plain step instead.
                    a.anderson.reset();
                    t = plain;
                    carried_ms += it_start.elapsed().as_secs_f64() * 1e3;
                    continue;
                }
            }
            a.energy = energy;
        }
        if pairs.len() < 6 {
            return Err(Error::Failed(format!(
                "ICP lost the overlap: {} of {} source points have a target point within {:.4}",
                pairs.len(),
                n_source,
                cfg.max_correspondence_distance
            )));
        }
        let paired = pairs.len();
        let d2s = problem.trim(&mut pairs);
        let keep = pairs.len();
        let fitness = paired as f64 / n_source as f64;
        let rmse = (d2s.iter().map(|&d| d as f64).sum::<f64>() / d2s.len() as f64).sqrt();
        let kept = &pairs[..];
        let rows = problem.rows(kept, &t);
        let (pair_sigma, row_sigma) = rows.residual_scales();
        let (h, g, sse) = rows.normal_equations(cfg.kernel, problem.kernel_scale(pair_sigma));
        let (info, sigma, wsse) = problem.reported_system(kept, (h, row_sigma, sse));
        history.push(IcpIteration {
            pairs: paired,
            kept: keep,
            fitness,
            rmse,
            residual_sigma: sigma,
            step_rotation: None,
            step_translation: None,
            time_ms: carried_ms + it_start.elapsed().as_secs_f64() * 1e3,
        });
        last = Some(IcpResult {
            transform: t,
            iterations,
            converged,
            fitness,
            inlier_rmse: rmse,
            overlap: keep as f64 / n_source as f64,
            residual_sigma: sigma,
            pairs: keep,
            information: info,
            weighted_sse: wsse,
            cycle: None,
            block_scores: Matrix6::zeros(),
            blocks: 0,
            history: Vec::new(),
        });
        last_kept = (t, pairs);
        if converged || it == cfg.max_iterations {
            break;
        }
        let Some(delta) = gauss_newton_step(&h, &g) else {
            break;
        };
        let plain = apply_left_increment(&t, &delta);
        iterations += 1;
        let rot = Vector3::new(delta[0], delta[1], delta[2]).norm();
        let tr = Vector3::new(delta[3], delta[4], delta[5]).norm();
        if let Some(h) = history.last_mut() {
            h.step_rotation = Some(rot);
            h.step_translation = Some(tr);
            h.time_ms = carried_ms + it_start.elapsed().as_secs_f64() * 1e3;
        }
        carried_ms = 0.0;
        if rot < cfg.rotation_tolerance && tr < cfg.translation_tolerance {
            converged = true;
        }
        let far = rot > ACCELERATE_TOLERANCES * cfg.rotation_tolerance
            || tr > ACCELERATE_TOLERANCES * cfg.translation_tolerance;
        recent.push((t, rot, tr));
        if recent.len() > MAX_CYCLE {
            recent.remove(0);
        }
        if !converged && !far {
            cycle = find_cycle(&recent, &plain, cfg);
            converged = cycle.is_some();
        }
        // Acceleration only while the steps are large (100 tolerances): near the solution the plain
        // steps are noise-sized and an extrapolation of them is mostly rejected, costing a pass each.
        t = match accel.as_mut() {
            Some(a) if far => a.propose(init, &t, plain),
            Some(a) => {
                a.anderson.reset();
                plain
            }
            None => plain,
        };
    }
    let mut r = last.expect("at least one iteration");
    let (kt, kept) = last_kept;
    (r.block_scores, r.blocks) = problem.block_scores(&kept, &kt);
    r.iterations = iterations;
    r.converged = converged;
    r.cycle = cycle;
    r.history = history;
    Ok(r)
}

/// Whether the plain step to `next` returns to one of the `recent` poses before the current one (the last
/// entry) within the tolerances: a cycle of period 2 to [`MAX_CYCLE`]. Its extent is the largest step taken
/// from the poses in it. Pairs that alternate between two sets (a point near the boundary of two target
/// points' cells, a pair trimmed and let in by turns) make such cycles: the steps stop shrinking though
/// the pose goes nowhere.
fn find_cycle(
    recent: &[(Isometry3<f64>, f64, f64)],
    next: &Isometry3<f64>,
    cfg: &IcpConfig,
) -> Option<IcpCycle> {
    let n = recent.len();
    (2..=n).find_map(|period| {
        let d = increment_from(&recent[n - period].0, next);
        let back = Vector3::new(d[0], d[1], d[2]).norm() < cfg.rotation_tolerance
            && Vector3::new(d[3], d[4], d[5]).norm() < cfg.translation_tolerance;
        back.then(|| {
            let steps = &recent[n - period..];
            IcpCycle {
                period,
                rotation: steps.iter().map(|s| s.1).fold(0.0, f64::max),
                translation: steps.iter().map(|s| s.2).fold(0.0, f64::max),
            }
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::{pose_error, random_isometry};
    use crate::geometry::Rng;
    use crate::preprocess::normals::{
        estimate_covariances, estimate_normals, LazyNormals, NormalConfig,
    };

    fn box_surface(rng: &mut Rng, n: usize) -> Vec<[f32; 3]> {
        // Points on three orthogonal planes and a bump: well-constrained in 6 DoF.
        (0..n)
            .map(|k| {
                let (a, b) = (rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
                match k % 4 {
                    0 => [a, b, 0.0],
                    1 => [a, 0.0, b],
                    2 => [0.0, a, b],
                    _ => [0.5 + 0.2 * a, 0.5 + 0.2 * b, 0.1 * (6.0 * a).sin()],
                }
                .map(|v| v as f32)
            })
            .collect()
    }

    /// A pose `deg` degrees about z and `x` along x from the identity.
    fn pose(deg: f64, x: f64) -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(x, 0.0, 0.0),
            Vector3::new(0.0, 0.0, deg.to_radians()),
        )
    }

    #[test]
    fn a_step_back_to_an_earlier_pose_is_a_cycle_and_a_creep_is_not() {
        let cfg = IcpConfig::default();
        let step = |a: &Isometry3<f64>, b: &Isometry3<f64>| {
            let d = increment_from(a, b);
            (
                Vector3::new(d[0], d[1], d[2]).norm(),
                Vector3::new(d[3], d[4], d[5]).norm(),
            )
        };
        // Two poses 0.01° / 0.1 mm apart, visited by turns: the next step lands back on the first.
        let (a, b) = (pose(0.0, 0.0), pose(0.01, 1e-4));
        let (r, t) = step(&a, &b);
        let recent = [(a, r, t), (b, r, t)];
        let c = find_cycle(&recent, &a, &cfg).expect("a period-2 cycle");
        assert_eq!(c.period, 2);
        assert!(
            (c.rotation - 0.01f64.to_radians()).abs() < 1e-12
                && (c.translation - 1e-4).abs() < 1e-12
        );
        // Three poses in turn; the largest step of the cycle is its extent.
        let p = [pose(0.0, 0.0), pose(0.02, 0.0), pose(0.01, 3e-4)];
        let recent: Vec<_> = (0..3)
            .map(|k| {
                let (r, t) = step(&p[k], &p[(k + 1) % 3]);
                (p[k], r, t)
            })
            .collect();
        let c = find_cycle(&recent, &p[0], &cfg).expect("a period-3 cycle");
        assert_eq!(c.period, 3);
        let largest = (0..3).map(|k| recent[k].1).fold(0.0, f64::max);
        assert_eq!(c.rotation, largest);
        assert!((c.translation - step(&p[1], &p[2]).1).abs() < 1e-12);
        // Within the tolerances of the earlier pose is back; twice the rotation tolerance away is not.
        let near = pose(1e-5f64.to_degrees() * 0.5, 0.0);
        assert!(find_cycle(&recent[1..], &near, &cfg).is_none());
        assert!(find_cycle(&recent, &near, &cfg).is_some());
        assert!(find_cycle(&recent, &pose(2e-5f64.to_degrees(), 0.0), &cfg).is_none());
        // A slow creep (each step twice the tolerances, always the same way) never comes back.
        let creep: Vec<_> = (0..MAX_CYCLE)
            .map(|k| (pose(0.0, 2e-5 * k as f64), 0.0, 2e-5))
            .collect();
        assert!(find_cycle(&creep, &pose(0.0, 2e-5 * MAX_CYCLE as f64), &cfg).is_none());
        // A single pose (nothing before the current one) has no cycle.
        assert!(find_cycle(&recent[..1], &a, &cfg).is_none());
    }

    #[test]
    fn converges_from_small_offsets_all_factors() {
        let mut rng = Rng::new(21);
        let target = box_surface(&mut rng, 6000);
        let idx = KdIndex::new(&target);
        let ncfg = NormalConfig::default();
        let normals = estimate_normals(&target, &idx, &ncfg);
        let (target_cov, _) = estimate_covariances(&target, &idx, &ncfg);
        for factor in [
            IcpFactor::PointToPlane,
            IcpFactor::PointToPoint,
            IcpFactor::Gicp,
        ] {
            for _ in 0..5 {
                let truth = random_isometry(&mut rng, 0.08, 0.04);
                // Source: a resampled copy of the surface, moved by truth⁻¹.
                let src: Vec<[f32; 3]> = box_surface(&mut rng, 3000)
                    .iter()
                    .map(|p| transform_point(&truth.inverse(), p))
                    .collect();
                let src_idx = KdIndex::new(&src);
                let (src_cov, _) = estimate_covariances(&src, &src_idx, &ncfg);
                let gicp = factor == IcpFactor::Gicp;
                let cfg = IcpConfig {
                    factor,
                    max_correspondence_distance: 0.2,
                    translation_tolerance: 1e-6,
                    max_iterations: 100,
                    ..Default::default()
                };
                let r = icp(
                    &IcpCloud {
                        points: &src,
                        normals: None,
                        covariances: gicp.then_some(&src_cov[..]),
                    },
                    &IcpCloud {
                        points: &target,
                        normals: Some(&normals),
                        covariances: gicp.then_some(&target_cov[..]),
                    },
                    &idx,
                    &Isometry3::identity(),
                    &cfg,
                )
                .unwrap();
                let (rd, td) = pose_error(&r.transform, &truth);
                let dt = r.transform.translation.vector - truth.translation.vector;
                // Point-to-point is limited by the 2 cm sample spacing of the resampled surfaces.
                let (rb, tb) = match factor {
                    IcpFactor::PointToPlane | IcpFactor::Gicp => (0.1, 2e-3),
                    IcpFactor::PointToPoint => (0.3, 5e-3),
                };
                assert!(
                    rd < rb && td < tb,
                    "{factor:?}: {rd}° {td} {dt:?} it {} conv {} overlap {} fit {}",
                    r.iterations,
                    r.converged,
                    r.overlap,
                    r.fitness
                );
                assert!(r.fitness > 0.95);
            }
        }
    }

    /// The normal equations and residual scales of point-to-plane pairs kept as their target normal and
    /// residual, the Jacobians made in place, are those of whole rows stored first and summed as full 6x6
    /// outer products in chunks of 512 (the form they replace), bit for bit, for every kernel, over
    /// several chunks and a partial last one.
    #[test]
    fn rows_computed_in_place_sum_as_stored_rows() {
        let mut rng = Rng::new(23);
        let target = box_surface(&mut rng, 6000);
        let idx = KdIndex::new(&target);
        let normals = estimate_normals(&target, &idx, &NormalConfig::default());
        let src = box_surface(&mut rng, 2300);
        let cfg = IcpConfig {
            max_correspondence_distance: 0.2,
            ..Default::default()
        };
        let (source, tgt) = (
            IcpCloud::points(&src),
            IcpCloud {
                points: &target,
                normals: Some(&normals),
                covariances: None,
            },
        );
        let problem = Problem::new(&source, &tgt, None, &idx, &cfg).unwrap();
        let t = random_isometry(&mut rng, 0.03, 0.02);
        let mut pairs = problem.correspondences(&t, &mut vec![NearestMemo::EMPTY; src.len()]);
        problem.trim(&mut pairs);
        let kept = &pairs[..];
        assert!(kept.len() > 3 * CHUNK, "{} pairs", kept.len());
        let stored: Vec<PairRows> = kept.iter().map(|p| problem.plane_rows(p)).collect();
        let oracle = |kernel: RobustKernel, c: f64| {
            stored
                .chunks(512)
                .map(|chunk| {
                    let mut acc = (Matrix6::zeros(), Vector6::zeros(), 0.0);
                    for (rows, n, norm) in chunk {
                        let w = kernel.weight(*norm, c);
                        for (j, r) in &rows[..*n] {
                            acc.0 += j * j.transpose() * w;
                            acc.1 += j * (w * r);
                            acc.2 += w * r * r;
                        }
                    }
                    acc
                })
                .fold((Matrix6::zeros(), Vector6::zeros(), 0.0), |a, b| {
                    (a.0 + b.0, a.1 + b.1, a.2 + b.2)
                })
        };
        let (in_place, kept_rows) = (Rows::plane(&problem, kept), Rows::Stored(stored.clone()));
        let (ps, rs) = in_place.residual_scales();
        assert_eq!((ps, rs), kept_rows.residual_scales());
        let n = stored.len() as f64;
        let ss: f64 = stored.iter().map(|p| p.2 * p.2).sum();
        assert_eq!(ps, (ss / n).sqrt());
        for kernel in [
            RobustKernel::None,
            RobustKernel::Huber,
            RobustKernel::Tukey,
            RobustKernel::Cauchy,
            RobustKernel::GemanMcClure,
        ] {
            let c = 3.0 * ps;
            let want = oracle(kernel, c);
            assert_eq!(in_place.normal_equations(kernel, c), want, "{kernel:?}");
            assert_eq!(kept_rows.normal_equations(kernel, c), want, "{kernel:?}");
        }
    }

    /// Lazy target normals give the eager result bit for bit, computing only the paired points' normals;
    /// a target with normals of its own is refused.
    #[test]
    fn lazy_normals_give_the_eager_result() {
        let mut rng = Rng::new(22);
        let target = box_surface(&mut rng, 8000);
        let idx = KdIndex::new(&target);
        let ncfg = NormalConfig::default();
        let normals = estimate_normals(&target, &idx, &ncfg);
        let truth = random_isometry(&mut rng, 0.05, 0.03);
        let src: Vec<[f32; 3]> = box_surface(&mut rng, 1000)
            .iter()
            .map(|p| transform_point(&truth.inverse(), p))
            .collect();
        let cfg = IcpConfig {
            max_correspondence_distance: 0.2,
            ..Default::default()
        };
        let source = IcpCloud::points(&src);
        let eager = icp(
            &source,
            &IcpCloud {
                points: &target,
                normals: Some(&normals),
                covariances: None,
            },
            &idx,
            &Isometry3::identity(),
            &cfg,
        )
        .unwrap();
        let lazy = LazyNormals::new(&target, &idx, ncfg);
        let r = icp_lazy_normals(
            &source,
            &IcpCloud::points(&target),
            &lazy,
            &idx,
            &Isometry3::identity(),
            &cfg,
        )
        .unwrap();
        assert_eq!(r.transform, eager.transform);
        assert_eq!(r.information, eager.information);
        assert_eq!(r.iterations, eager.iterations);
        assert!(lazy.computed() < target.len() / 2, "{}", lazy.computed());
        let with_normals = IcpCloud {
            points: &target,
            normals: Some(&normals),
            covariances: None,
        };
        assert!(icp_lazy_normals(
            &source,
            &with_normals,
            &lazy,
            &idx,
            &Isometry3::identity(),
            &cfg
        )
        .is_err());
    }

    /// Points on a shallow elliptic bowl `z = 0.2 x² + 0.08 y²` over [-1, 1]², where point-to-plane ICP
    /// corrects a sideways offset only through the curvature: linear, slow convergence.
    fn bowl(rng: &mut Rng, n: usize) -> Vec<[f32; 3]> {
        (0..n)
            .map(|_| {
                let (x, y) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
                [x, y, 0.2 * x * x + 0.08 * y * y].map(|v| v as f32)
            })
            .collect()
    }

    /// Anderson acceleration: from far starts on a slowly converging surface the same poses in fewer steps;
    /// from a start near the solution, where every step is small, exactly the plain result.
    #[test]
    fn acceleration_takes_fewer_steps_to_the_same_pose() {
        let mut rng = Rng::new(23);
        let target = bowl(&mut rng, 40_000);
        let idx = KdIndex::new(&target);
        let normals = estimate_normals(&target, &idx, &NormalConfig::default());
        let tgt = IcpCloud {
            points: &target,
            normals: Some(&normals),
            covariances: None,
        };
        // The central part of the bowl, so that every source point has the surface under it.
        let src: Vec<[f32; 3]> = bowl(&mut rng, 8000)
            .into_iter()
            .filter(|p| p[0].abs() < 0.7 && p[1].abs() < 0.7)
            .collect();
        let source = IcpCloud::points(&src);
        let run = |init: &Isometry3<f64>, acceleration: usize| {
            let cfg = IcpConfig {
                max_correspondence_distance: 0.3,
                max_iterations: 300,
                acceleration,
                ..Default::default()
            };
            icp(&source, &tgt, &idx, init, &cfg).unwrap()
        };
        let (mut plain_steps, mut fast_steps) = (0, 0);
        for _ in 0..4 {
            let init = random_isometry(&mut rng, 0.1, 0.15);
            let (plain, fast) = (run(&init, 0), run(&init, 3));
            assert!(plain.converged && fast.converged);
            for r in [&plain, &fast] {
                let (rd, td) = pose_error(&r.transform, &Isometry3::identity());
                assert!(rd < 0.05 && td < 1e-3, "{rd}° {td}");
            }
            plain_steps += plain.iterations;
            fast_steps += fast.iterations;
        }
        // Measured: 105 against 126 steps.
        assert!(
            fast_steps * 10 < plain_steps * 9,
            "{fast_steps} vs {plain_steps}"
        );
        let near = random_isometry(&mut rng, 1e-4, 1e-5);
        let (plain, fast) = (run(&near, 0), run(&near, 3));
        assert_eq!(plain.transform, fast.transform);
        assert_eq!(plain.iterations, fast.iterations);
        assert!(IcpConfig {
            acceleration: 21,
            ..Default::default()
        }
        .validate()
        .is_err());
    }

    #[test]
    fn auto_trim_estimates_overlap() {
        // 60% of the source sits on the target surface, 40% is far off it.
        let d2: Vec<f32> = (0..1000)
            .map(|k| {
                if k < 600 {
                    1e-6 * (k % 7) as f32
                } else {
                    0.01 + 1e-4 * k as f32
                }
            })
            .collect();
        let mut s = d2.clone();
        s.sort_by(|a, b| a.total_cmp(b));
        let keep = trimmed_count(&s, 1000, Trim::default());
        assert!((560..=640).contains(&keep), "{keep}");
    }

    /// The re-associated information agrees with `JᵀWJ` where the pairs cannot slide (a box's three faces
    /// and a bump) and vanishes where they can (a plane's own directions); the block scores are a sum of
    /// outer products over several blocks.
    #[test]
    fn reassociated_information_sees_what_sliding_costs() {
        let mut rng = Rng::new(5);
        let eig_scaled = |h: &Matrix6<f64>, pts: &[[f32; 3]]| {
            let l = rms_radius(pts);
            let n = pts.len() as f64;
            let c = pts.iter().fold(Vector3::zeros(), |a, p| a + to_v64(p)) / n;
            let h = crate::registration::quality::information_about(h, &c);
            let s = Matrix6::from_diagonal(&Vector6::new(1.0 / l, 1.0 / l, 1.0 / l, 1.0, 1.0, 1.0));
            (s * h * s).symmetric_eigen().eigenvalues
        };
        let plane = |rng: &mut Rng, n: usize| -> Vec<[f32; 3]> {
            (0..n)
                .map(|_| {
                    [
                        rng.uniform(0.0, 1.0) as f32,
                        rng.uniform(0.0, 1.0) as f32,
                        0.0,
                    ]
                })
                .collect()
        };
        for (name, target, src) in [
            (
                "box",
                box_surface(&mut rng, 8000),
                box_surface(&mut rng, 3000),
            ),
            ("plane", plane(&mut rng, 8000), plane(&mut rng, 3000)),
        ] {
            let idx = KdIndex::new(&target);
            let normals = estimate_normals(&target, &idx, &NormalConfig::default());
            let cfg = IcpConfig {
                max_correspondence_distance: 0.1,
                translation_tolerance: 1e-6,
                max_iterations: 60,
                ..Default::default()
            };
            let (sc, tc) = (
                IcpCloud {
                    points: &src,
                    normals: None,
                    covariances: None,
                },
                IcpCloud {
                    points: &target,
                    normals: Some(&normals),
                    covariances: None,
                },
            );
            let r = icp(&sc, &tc, &idx, &Isometry3::identity(), &cfg).unwrap();
            let k =
                reassociated_information(&sc, &tc, None, &idx, &r.transform, &cfg, 0.02).unwrap();
            let (ek, eh) = (eig_scaled(&k, &src), eig_scaled(&r.information, &src));
            let (kmax, hmax) = (ek.max(), eh.max());
            assert!((kmax / hmax - 1.0).abs() < 0.2, "{name}: {kmax} vs {hmax}");
            let weak = ek.iter().filter(|&&x| x < 1e-3 * kmax).count();
            match name {
                "box" => assert!(ek.min() > 0.2 * eh.min(), "{name}: {ek} vs {eh}"),
                _ => assert_eq!(weak, 3, "{name}: {ek}"),
            }
            assert!(r.blocks > 8, "{name}: {} blocks", r.blocks);
            assert!(r.block_scores.symmetric_eigen().eigenvalues.min() > -1e-12);
        }
    }
}
