//! RANSAC over 3-point correspondence samples, deterministic for a seed at any thread count.
//!
//! * **Sampling.** With `guided` (default) sampling follows the pairwise length-consistency graph of the
//!   correspondences: a first match is drawn with probability proportional to how many matches are
//!   consistent with it, the other two among those. Inlier matches are all mutually consistent, so this
//!   finds an all-inlier triple orders of magnitude sooner than uniform sampling when inliers are rare
//!   (low overlap). Without it, three distinct matches are drawn uniformly.
//! * **Two-point hypotheses** when the caller bounds the tilt to a few degrees (level robot bases): a yaw
//!   and a translation from two matches, so an all-inlier sample needs two inliers instead of three.
//! * **Pre-checks** before any fit: edge-length similarity of the two triangles, then, after the
//!   closed-form fit, each of the three pairs within the inlier distance.
//! * **Scoring**: number of correspondences within the inlier distance.
//! * **Early stop** by confidence, between fixed-size batches (the loop of
//!   [`crate::registration::consensus`], shared with the feature initialiser's RANSAC), with the success probability of the
//!   sampler actually used (for guided sampling, estimated from the best inlier set).
//! * **Verification**: the best distinct hypotheses are refitted on their inliers (two rounds) and
//!   re-counted; the one with the most inliers wins, ties broken by cloud fitness (the fraction of source
//!   points with a target neighbour within the inlier distance).
//!
//! Iteration `k` draws from its own random stream (`Rng::stream(seed, k)`) and batches are reduced in
//! iteration order, so the result is bit-identical whatever the number of threads.

use crate::error::{check, Error, Result};
use crate::geometry::cloud::{to_p64, transform_point};
use crate::geometry::transform::pose_error;
use crate::geometry::Rng;
use crate::index::KdIndex;
use crate::registration::consensus::{consensus_loop, draw_streams, samples_needed, LoopLimits};
use crate::registration::correspondence::Correspondence;
use crate::registration::rigid_fit::rigid_fit;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Prior knowledge about the answer, used to reject hypotheses before they are scored. In a robot cell:
/// both bases upright (the transform is nearly a rotation about z) and a rough distance between them.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseConstraint {
    /// Largest angle between `R·z` and `z` (degrees): the tilt of the transform's rotation.
    pub max_tilt_deg: Option<f64>,
    /// Allowed range of the translation's length (cloud units).
    pub translation_range: Option<[f64; 2]>,
}

impl PoseConstraint {
    /// True when `t` satisfies every stated bound.
    pub fn accepts(&self, t: &Isometry3<f64>) -> bool {
        if let Some(max) = self.max_tilt_deg {
            let z = t.rotation * nalgebra::Vector3::z();
            if z.z.clamp(-1.0, 1.0).acos().to_degrees() > max {
                return false;
            }
        }
        if let Some([lo, hi]) = self.translation_range {
            let d = t.translation.vector.norm();
            if d < lo || d > hi {
                return false;
            }
        }
        true
    }

    /// The same bounds with the translation's length also at least `min` (cloud units; `min` ≤ 0 changes
    /// nothing).
    pub fn with_min_translation(mut self, min: f64) -> Self {
        if min > 0.0 {
            self.translation_range = Some(match self.translation_range {
                Some([lo, hi]) => [lo.max(min), hi],
                None => [min, f64::MAX],
            });
        }
        self
    }

    /// True when no bound is set.
    pub fn is_empty(&self) -> bool {
        self.max_tilt_deg.is_none() && self.translation_range.is_none()
    }
}

/// Parameters of [`ransac`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RansacConfig {
    /// A correspondence is an inlier when `‖T·p − q‖` is below this (cloud units; default 0.05, 5 cm for
    /// clouds in metres). The `register` pipeline overwrites it with
    /// [`RegisterConfig::ransac_distance_voxels`](crate::registration::RegisterConfig::ransac_distance_voxels)
    /// times the global voxel.
    pub inlier_distance: f64,
    /// Edge-length similarity required of a sample's two triangles, in (0, 1] (default 0.9).
    pub edge_similarity: f64,
    /// Largest number of samples drawn (default 100 000).
    pub max_iterations: usize,
    /// Fewest samples drawn whatever the stop rule says (default 20 000): a wrong but self-consistent
    /// hypothesis early on must not end the search (sampling is cheap next to feature computation).
    pub min_iterations: usize,
    /// Stop once an all-inlier sample has been drawn with this probability (default 0.9999).
    pub confidence: f64,
    /// Sample along the length-consistency graph (default true; see the module docs).
    pub guided: bool,
    /// How many distinct best hypotheses are verified on the full clouds (default 50).
    pub verify_top: usize,
    /// Hypotheses that violate this are discarded before scoring (default: no constraint).
    pub constraint: PoseConstraint,
}

impl Default for RansacConfig {
    fn default() -> Self {
        RansacConfig {
            inlier_distance: 0.05,
            edge_similarity: 0.9,
            max_iterations: 100_000,
            min_iterations: 20_000,
            confidence: 0.9999,
            guided: true,
            verify_top: 50,
            constraint: PoseConstraint::default(),
        }
    }
}

impl RansacConfig {
    /// Checks the ranges; the error names the field (`ransac.…`).
    pub fn validate(&self) -> Result<()> {
        self.validate_shape()?;
        check::positive("ransac.inlier_distance", self.inlier_distance)
    }

    /// Every check but `inlier_distance`, which the `register` pipeline sets from the voxel.
    pub(crate) fn validate_shape(&self) -> Result<()> {
        check::fraction("ransac.edge_similarity", self.edge_similarity)?;
        check::at_least("ransac.max_iterations", self.max_iterations, 1)?;
        check::fraction("ransac.confidence", self.confidence)?;
        check::at_least("ransac.verify_top", self.verify_top, 1)?;
        if let Some(t) = self.constraint.max_tilt_deg {
            if !(t.is_finite() && t >= 0.0) {
                return Err(Error::config(
                    "ransac.constraint.max_tilt_deg",
                    format!("must be an angle ≥ 0 degrees, got {t}"),
                ));
            }
        }
        if let Some([lo, hi]) = self.constraint.translation_range {
            if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi) {
                return Err(Error::config(
                    "ransac.constraint.translation_range",
                    format!("must be [min, max] with 0 ≤ min ≤ max, got [{lo}, {hi}]"),
                ));
            }
        }
        Ok(())
    }
}

/// What [`ransac`] found.
#[derive(Clone, Debug)]
pub struct RansacResult {
    /// Source-to-target transform.
    pub transform: Isometry3<f64>,
    /// Correspondences within the inlier distance of `transform`.
    pub inlier_count: usize,
    /// Number of correspondences considered.
    pub correspondence_count: usize,
    /// Samples drawn.
    pub iterations: usize,
    /// Fraction of source points with a target neighbour within the inlier distance.
    pub fitness: f64,
    /// Hypotheses verified on the clouds.
    pub verified: usize,
    /// Every verified hypothesis: (correspondence inliers, cloud fitness, transform), best first by count.
    pub candidates: Vec<(usize, f64, Isometry3<f64>)>,
}

/// Tilt bounds up to this (degrees) switch the sampler to two-point yaw-and-translation hypotheses.
const MAX_TILT_FOR_TWO_POINT_DEG: f64 = 10.0;

/// The rotation about z and the translation that map `p1`, `p2` onto `q1`, `q2` (least squares in the
/// horizontal plane; vertical offset from the midpoints). `None` when the pair is nearly vertical or does not
/// fit within `tau`.
fn yaw_fit(
    p1: &[f32; 3],
    p2: &[f32; 3],
    q1: &[f32; 3],
    q2: &[f32; 3],
    tau: f64,
) -> Option<Isometry3<f64>> {
    let (p1, p2, q1, q2) = (to_p64(p1), to_p64(p2), to_p64(q1), to_p64(q2));
    let (dp, dq) = (p2 - p1, q2 - q1);
    if dp.xy().norm() < tau || dq.xy().norm() < tau {
        return None;
    }
    let yaw = dq.y.atan2(dq.x) - dp.y.atan2(dp.x);
    let r = nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), yaw);
    let pm = nalgebra::center(&p1, &p2);
    let qm = nalgebra::center(&q1, &q2);
    let t = Isometry3::from_parts(nalgebra::Translation3::from(qm.coords - r * pm.coords), r);
    ((t * p1 - q1).norm() <= tau && (t * p2 - q2).norm() <= tau).then_some(t)
}

/// Samples drawn per parallel batch; the stop rule is checked between batches.
const BATCH: usize = 2048;
/// Above this many correspondences the consistency graph is not built (its cost grows quadratically).
const MAX_GRAPH: usize = 12_000;

struct Hypothesis {
    count: usize,
    iteration: usize,
    t: Isometry3<f64>,
}

/// Points as three coordinate arrays, for loops the compiler vectorises.
struct Soa {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

impl Soa {
    fn new(points: &[[f32; 3]]) -> Self {
        Soa {
            x: points.iter().map(|p| p[0]).collect(),
            y: points.iter().map(|p| p[1]).collect(),
            z: points.iter().map(|p| p[2]).collect(),
        }
    }
}

/// Lanes of the chunked loops below.
const LANES: usize = 16;

/// The consistency graph ([`consistency_graph`]): one row of bits per match, bit `j` of row `i` set when
/// match `j`'s lengths to match `i`'s agree (symmetric, no self-loops). Bits rather than lists: the rows
/// are filled without appends (a graph of 8.7k matches has 12M edges, 50 MB as lists and 9.5 MB as
/// bits), a membership test is one bit, and counting a row's neighbours in a set is a popcount.
#[derive(Default)]
struct Graph {
    /// 64-bit words per row.
    words: usize,
    bits: Vec<u64>,
    degree: Vec<u32>,
}

impl Graph {
    /// The number of matches (rows).
    fn len(&self) -> usize {
        self.degree.len()
    }

    /// Row `i`'s words.
    fn row(&self, i: usize) -> &[u64] {
        &self.bits[i * self.words..(i + 1) * self.words]
    }

    /// The neighbours of `i`.
    fn degree(&self, i: usize) -> usize {
        self.degree[i] as usize
    }

    /// `i` and `j` agree.
    fn contains(&self, i: usize, j: usize) -> bool {
        self.row(i)[j / 64] >> (j % 64) & 1 == 1
    }

    /// The `k`-th neighbour of `i` in ascending order (`k < degree(i)`).
    fn nth(&self, i: usize, mut k: usize) -> usize {
        for (w, &word) in self.row(i).iter().enumerate() {
            let c = word.count_ones() as usize;
            if k < c {
                let mut x = word;
                for _ in 0..k {
                    x &= x - 1;
                }
                return w * 64 + x.trailing_zeros() as usize;
            }
            k -= c;
        }
        panic!("neighbour {k} beyond the degree of {i}")
    }

    /// The neighbours of `i`, ascending.
    #[cfg(test)]
    fn neighbours(&self, i: usize) -> Vec<u32> {
        (0..self.degree(i)).map(|k| self.nth(i, k) as u32).collect()
    }
}

/// The consistency graph of the matches `(ps[i], qs[i])`: `i` and `j` agree when their lengths in both
/// clouds differ by less than `tol` and both exceed `min_len`. The test is symmetric bit for bit, so each
/// pair is tested once: in 64 x 64 blocks of the bit matrix, the blocks on and above the diagonal are
/// tested (rows in parallel, 16 matches at a time into a row's bits) and those below are their transposes.
fn consistency_graph(ps: &[[f32; 3]], qs: &[[f32; 3]], tol: f32, min_len: f32) -> Graph {
    let n = ps.len();
    let words = n.div_ceil(64);
    let (p, q) = (Soa::new(ps), Soa::new(qs));
    let min2 = min_len * min_len;
    let mut bits = vec![0u64; n * words];
    bits.par_chunks_mut(words.max(1))
        .take(n)
        .enumerate()
        .for_each(|(i, row)| graph_row(&p, &q, i, (tol, min2), row));
    // Block (b, c) below the diagonal (c < b) is the transpose of block (c, b): rows 64c.. at word b.
    let block_rows = |b: usize| 64 * b..(64 * b + 64).min(n);
    let lower: Vec<Vec<[u64; 64]>> = (0..words)
        .into_par_iter()
        .map(|b| {
            (0..b)
                .map(|c| {
                    let mut m = [0u64; 64];
                    for (k, r) in block_rows(c).enumerate() {
                        m[k] = bits[r * words + b];
                    }
                    transpose64(&mut m);
                    m
                })
                .collect()
        })
        .collect();
    let degree: Vec<u32> = bits
        .par_chunks_mut(64 * words.max(1))
        .zip(lower)
        .flat_map_iter(|(rows, blocks)| {
            for (c, m) in blocks.iter().enumerate() {
                for (k, row) in rows.chunks_mut(words).enumerate() {
                    row[c] = m[k];
                }
            }
            rows.chunks(words)
                .map(|row| row.iter().map(|w| w.count_ones()).sum::<u32>())
                .collect::<Vec<_>>()
        })
        .collect();
    Graph {
        words,
        bits,
        degree,
    }
}

/// Transposes a 64 x 64 bit matrix in place (row `r` is `m[r]`, column `c` its bit `c`): swaps of ever
/// smaller off-diagonal blocks (32, 16, ... 1 bits), each a few masked shifts per word.
fn transpose64(m: &mut [u64; 64]) {
    let mut width = 32;
    let mut mask: u64 = 0x0000_0000_FFFF_FFFF;
    while width != 0 {
        let mut r = 0;
        while r < 64 {
            for k in r..r + width {
                let t = ((m[k] >> width) ^ m[k + width]) & mask;
                m[k] ^= t << width;
                m[k + width] ^= t;
            }
            r += 2 * width;
        }
        width >>= 1;
        mask ^= mask << width;
    }
}

crate::simd::dispatch_simd! {
    /// Row `i` of the consistency graph of the matches `(p, q)` (`limits`: the tolerance and the squared
    /// least length) into `row`'s bits from its own 64-bit word on (the diagonal block and those right of
    /// it), 16 matches at a time.
    fn graph_row(p: &Soa, q: &Soa, i: usize, limits: (f32, f32), row: &mut [u64]) = graph_row_generic;
}

#[inline(always)]
fn graph_row_generic(p: &Soa, q: &Soa, i: usize, (tol, min2): (f32, f32), row: &mut [u64]) {
    let n = p.x.len();
    let (pi, qi) = ([p.x[i], p.y[i], p.z[i]], [q.x[i], q.y[i], q.z[i]]);
    let full = n - n % LANES;
    for start in (64 * (i / 64)..full).step_by(LANES) {
        let r = start..start + LANES;
        let lane = |v: &[f32]| -> [f32; LANES] { v[r.clone()].try_into().expect("full lane") };
        let (px, py, pz) = (lane(&p.x), lane(&p.y), lane(&p.z));
        let (qx, qy, qz) = (lane(&q.x), lane(&q.y), lane(&q.z));
        let mut ok = [false; LANES];
        for k in 0..LANES {
            let (pj, qj) = ([px[k], py[k], pz[k]], [qx[k], qy[k], qz[k]]);
            ok[k] = edge_agrees(&pj, &qj, &pi, &qi, tol, min2);
        }
        let mut mask = 0u64;
        for (k, &o) in ok.iter().enumerate() {
            mask |= (o as u64) << k;
        }
        row[start / 64] |= mask << (start % 64);
    }
    for j in full.max(64 * (i / 64))..n {
        let (pj, qj) = ([p.x[j], p.y[j], p.z[j]], [q.x[j], q.y[j], q.z[j]]);
        row[j / 64] |= (edge_agrees(&pj, &qj, &pi, &qi, tol, min2) as u64) << (j % 64);
    }
    row[i / 64] &= !(1u64 << (i % 64));
}

/// `x²` (as `powi(2)`, which does not vectorise).
#[inline]
fn sq(x: f32) -> f32 {
    x * x
}

/// [`consistency_graph`]'s test: match `j`'s lengths to match `i`'s points agree within `tol`, both
/// longer than `√min2`.
#[inline(always)]
fn edge_agrees(
    pj: &[f32; 3],
    qj: &[f32; 3],
    pi: &[f32; 3],
    qi: &[f32; 3],
    tol: f32,
    min2: f32,
) -> bool {
    let dp2 = sq(pj[0] - pi[0]) + sq(pj[1] - pi[1]) + sq(pj[2] - pi[2]);
    let dq2 = sq(qj[0] - qi[0]) + sq(qj[1] - qi[1]) + sq(qj[2] - qi[2]);
    ((dp2.sqrt() - dq2.sqrt()).abs() < tol) & (dp2 > min2) & (dq2 > min2)
}

#[inline]
fn dist(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Robust global registration from putative correspondences (see the module docs).
///
/// `source` and `target` are the (downsampled) clouds the correspondences index into, and `target_index`
/// a kd-tree over `target`. `seed` seeds the sampler: the result is the same for a seed at any thread count.
pub fn ransac(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    target_index: &KdIndex,
    corr: &[Correspondence],
    cfg: &RansacConfig,
    seed: u64,
) -> Result<RansacResult> {
    ransac_sided(source, target, target_index, corr, cfg, seed, None)
}

/// Normals that carry the side each surface was seen from (they point toward the sensors), one per point
/// of each cloud: a hypothesis that maps a sampled match's source normal onto the opposite side of its
/// target normal (a surface seen from above laid onto one seen from below) is discarded.
#[derive(Clone, Copy, Debug)]
pub struct SideNormals<'a> {
    /// Source normals.
    pub source: &'a [[f32; 3]],
    /// Target normals.
    pub target: &'a [[f32; 3]],
    /// Smallest cosine between a sampled match's mapped source normal and its target normal.
    pub min_cos: f32,
}

/// As [`ransac`], with `sides`: every sampled match must keep its surface's side under the hypothesis.
///
/// The stages: the matches as point pairs ([`Matches`]), the sampler over them ([`Sampler`]), the
/// consensus loop keeping the best distinct hypotheses, then their verification on the clouds
/// ([`verify_on_clouds`]).
pub fn ransac_sided(
    source: &[[f32; 3]],
    target: &[[f32; 3]],
    target_index: &KdIndex,
    corr: &[Correspondence],
    cfg: &RansacConfig,
    seed: u64,
    sides: Option<SideNormals>,
) -> Result<RansacResult> {
    if cfg.inlier_distance.is_nan() || cfg.inlier_distance <= 0.0 {
        return Err(Error::Config {
            field: "ransac.inlier_distance".into(),
            msg: "must be positive".into(),
        });
    }
    if corr.len() < 3 {
        return Err(Error::Failed(format!(
            "only {} feature correspondences: too few for RANSAC (the clouds share too little distinctive geometry)",
            corr.len()
        )));
    }
    let m = Matches::new(source, target, corr, sides, cfg.inlier_distance);
    let sampler = Sampler::new(&m, cfg);
    // With a small tilt bound (level robot bases) a hypothesis is a yaw and a translation: two matches
    // determine it, and an all-inlier pair is far likelier than an all-inlier triple.
    let two_point = cfg
        .constraint
        .max_tilt_deg
        .is_some_and(|t| t <= MAX_TILT_FOR_TWO_POINT_DEG);
    let hypothesis = |rng: &mut Rng, it: usize| hypothesis(&m, &sampler, cfg, two_point, rng, it);
    let keep = cfg.verify_top.max(1);
    let mut top: Vec<Hypothesis> = Vec::new();
    let ln_fail = (1.0 - cfg.confidence.clamp(0.0, 0.999_999_999)).ln();
    let limits = LoopLimits {
        max_iterations: cfg.max_iterations.max(1),
        min_iterations: cfg.min_iterations,
        batch: BATCH,
    };
    let done = consensus_loop(
        &limits,
        |its| draw_streams(seed, its, &hypothesis),
        |mut batch| {
            batch.sort_by(|x, y| y.count.cmp(&x.count).then(x.iteration.cmp(&y.iteration)));
            merge_top(&mut top, batch, keep, m.tau);
            let best = top.first()?;
            let p = sampler.success_probability(&m, best, two_point);
            (p > 0.0).then(|| samples_needed(p, ln_fail))
        },
    );
    if top.is_empty() {
        return Err(Error::Failed(format!(
            "RANSAC found no consistent hypothesis in {done} samples of {} correspondences",
            m.len()
        )));
    }
    let (fitness, inliers, t, verified) = verify_on_clouds(&m, &top, source, target_index, cfg);
    Ok(RansacResult {
        transform: t,
        inlier_count: inliers,
        correspondence_count: m.len(),
        iterations: done,
        fitness,
        verified: verified.len(),
        candidates: verified.iter().map(|&(f, c, t)| (c, f, t)).collect(),
    })
}

/// Source normals and target normals of the matches, and the smallest cosine between a mapped source
/// normal and its target normal.
type MatchSides = (Vec<[f32; 3]>, Vec<[f32; 3]>, f32);

/// The putative matches as point pairs (`ps[k]` in the source, `qs[k]` in the target), with their side
/// normals when given, and what scoring a hypothesis against them needs.
struct Matches {
    ps: Vec<[f32; 3]>,
    qs: Vec<[f32; 3]>,
    ps_soa: Soa,
    qs_soa: Soa,
    sides: Option<MatchSides>,
    /// Inlier distance, cloud units.
    tau: f64,
    /// Its square, in `f32`.
    tau2: f32,
}

impl Matches {
    fn new(
        source: &[[f32; 3]],
        target: &[[f32; 3]],
        corr: &[Correspondence],
        sides: Option<SideNormals>,
        tau: f64,
    ) -> Self {
        let ps: Vec<[f32; 3]> = corr.iter().map(|c| source[c.source as usize]).collect();
        let qs: Vec<[f32; 3]> = corr.iter().map(|c| target[c.target as usize]).collect();
        Matches {
            ps_soa: Soa::new(&ps),
            qs_soa: Soa::new(&qs),
            ps,
            qs,
            sides: sides.map(|sd| {
                (
                    corr.iter().map(|c| sd.source[c.source as usize]).collect(),
                    corr.iter().map(|c| sd.target[c.target as usize]).collect(),
                    sd.min_cos,
                )
            }),
            tau,
            tau2: (tau * tau) as f32,
        }
    }

    fn len(&self) -> usize {
        self.ps.len()
    }

    /// Matches within the inlier distance under `t`.
    fn count_inliers(&self, t: &Isometry3<f64>) -> usize {
        m_count(&Affine32::from(t), &self.ps_soa, &self.qs_soa, self.tau2)
    }

    /// Every match of `sample` keeps its surface's side under `t` (true without side normals).
    fn keeps_sides(&self, t: &Isometry3<f64>, sample: &[usize]) -> bool {
        let Some((ns, nt, min_cos)) = &self.sides else {
            return true;
        };
        sample.iter().all(|&k| {
            let n = t.rotation * nalgebra::Vector3::new(ns[k][0], ns[k][1], ns[k][2]).cast::<f64>();
            let m = nalgebra::Vector3::new(nt[k][0], nt[k][1], nt[k][2]).cast::<f64>();
            n.dot(&m) >= *min_cos as f64
        })
    }

    /// Matches `a` and `b` span similar lengths in both clouds (ratio at least `similarity`).
    fn edge_ok(&self, a: usize, b: usize, similarity: f64) -> bool {
        let dp = dist(&self.ps[a], &self.ps[b]) as f64;
        let dq = dist(&self.qs[a], &self.qs[b]) as f64;
        dp.min(dq) >= similarity * dp.max(dq)
    }
}

/// Where samples come from: along the length-consistency graph (guided; the first match drawn in proportion
/// to its degree, the others among its neighbours) or uniformly.
struct Sampler {
    guided: bool,
    graph: Graph,
    /// Cumulative degree, for degree-proportional draws of the first match.
    cum: Vec<u64>,
    total_degree: u64,
    n: usize,
}

impl Sampler {
    fn new(m: &Matches, cfg: &RansacConfig) -> Self {
        let n = m.len();
        let guided = cfg.guided && n <= MAX_GRAPH;
        let graph = if guided {
            consistency_graph(&m.ps, &m.qs, 2.0 * m.tau as f32, m.tau as f32)
        } else {
            Graph::default()
        };
        let cum: Vec<u64> = (0..graph.len())
            .scan(0u64, |s, a| {
                *s += graph.degree(a).saturating_sub(1) as u64;
                Some(*s)
            })
            .collect();
        let total_degree = cum.last().copied().unwrap_or(0);
        Sampler {
            guided: guided && total_degree > 0,
            graph,
            cum,
            total_degree,
            n,
        }
    }

    /// `k` (2 or 3) distinct match indices (the third repeats the second for `k == 2`), or `None` for a
    /// draw that cannot form a sample.
    fn draw(&self, rng: &mut Rng, k: usize) -> Option<[usize; 3]> {
        if self.guided {
            let r = rng.next_u64() % self.total_degree;
            let a = self.cum.partition_point(|&x| x <= r);
            let deg = self.graph.degree(a);
            if deg < 2 {
                return None;
            }
            let b = self.graph.nth(a, rng.below(deg));
            if k == 2 {
                return Some([a, b, b]);
            }
            let c = self.graph.nth(a, rng.below(deg));
            if b == c || !self.graph.contains(b, c) {
                return None;
            }
            Some([a, b, c])
        } else {
            let n = self.n;
            let (a, b) = (rng.below(n), rng.below(n));
            let c = if k == 2 { b } else { rng.below(n) };
            if a == b || (k == 3 && (b == c || a == c)) {
                return None;
            }
            Some([a, b, c])
        }
    }

    /// Probability that one sample is all-inlier under the best hypothesis so far, for this sampler.
    fn success_probability(&self, m: &Matches, best: &Hypothesis, two_point: bool) -> f64 {
        if self.guided {
            guided_success_probability(
                &best.t,
                &m.ps,
                &m.qs,
                m.tau2,
                &self.graph,
                self.total_degree,
                two_point,
            )
        } else {
            let w = best.count as f64 / self.n as f64;
            if two_point {
                w * w
            } else {
                w * w * w
            }
        }
    }
}

/// One hypothesis from one draw: a yaw and translation from two matches (`two_point`) or a rigid fit of
/// three, kept when the sample's lengths agree, every sampled match lies within the inlier distance and
/// keeps its side, and the constraint accepts it; scored by its inlier count.
fn hypothesis(
    m: &Matches,
    sampler: &Sampler,
    cfg: &RansacConfig,
    two_point: bool,
    rng: &mut Rng,
    it: usize,
) -> Option<Hypothesis> {
    let sim = cfg.edge_similarity;
    let t = if two_point {
        let [a, b, _] = sampler.draw(rng, 2)?;
        if !m.edge_ok(a, b, sim) {
            return None;
        }
        let t = yaw_fit(&m.ps[a], &m.ps[b], &m.qs[a], &m.qs[b], m.tau)?;
        if !m.keeps_sides(&t, &[a, b]) {
            return None;
        }
        t
    } else {
        let [a, b, c] = sampler.draw(rng, 3)?;
        if !(m.edge_ok(a, b, sim) && m.edge_ok(b, c, sim) && m.edge_ok(a, c, sim)) {
            return None;
        }
        let src = [to_p64(&m.ps[a]), to_p64(&m.ps[b]), to_p64(&m.ps[c])];
        let dst = [to_p64(&m.qs[a]), to_p64(&m.qs[b]), to_p64(&m.qs[c])];
        let t = rigid_fit(&src, &dst, None)?;
        for k in 0..3 {
            if (t * src[k] - dst[k]).norm() > m.tau {
                return None;
            }
        }
        if !m.keeps_sides(&t, &[a, b, c]) {
            return None;
        }
        t
    };
    if !cfg.constraint.accepts(&t) {
        return None;
    }
    Some(Hypothesis {
        count: m.count_inliers(&t),
        iteration: it,
        t,
    })
}

/// `(cloud fitness, match inliers, transform)` of a verified hypothesis.
type Verified = (f64, usize, Isometry3<f64>);

/// Refits each kept hypothesis on its inliers and scores it on the clouds; returns the winner's fitness
/// (on the whole source), inlier count and transform, and every verified hypothesis.
///
/// The winner has the most correspondence inliers after refitting (RANSAC's own criterion); cloud fitness
/// only breaks ties. Measured: at low overlap, wrong hypotheses that lay big planes onto each other reach
/// a higher cloud fitness than the truth (3DLoMatch: 0.41 against 0.27), but not more consistent feature
/// matches; and among near-equal hypotheses the fitness favours a loose one.
fn verify_on_clouds(
    m: &Matches,
    top: &[Hypothesis],
    source: &[[f32; 3]],
    target_index: &KdIndex,
    cfg: &RansacConfig,
) -> (f64, usize, Isometry3<f64>, Vec<Verified>) {
    // A stride sample of at most 2000 source points is plenty to rank them.
    let step = source.len().div_ceil(2000).max(1);
    let sample: Vec<[f32; 3]> = source.iter().step_by(step).copied().collect();
    // Cloud fitness (a tie-breaker) only for the first FITNESS_RANKED by count: a long list is kept for a
    // later verification, not for this ranking.
    const FITNESS_RANKED: usize = 50;
    let verified: Vec<Verified> = top
        .par_iter()
        .enumerate()
        .map(|(k, h)| {
            let refitted = refit(&h.t, &m.ps, &m.qs, m.tau2);
            let t = if cfg.constraint.accepts(&refitted) {
                refitted
            } else {
                h.t
            };
            let fit = if k < FITNESS_RANKED {
                cloud_fitness(&sample, target_index, &t, m.tau)
            } else {
                0.0
            };
            (fit, m.count_inliers(&t), t)
        })
        .collect();
    let (fitness, inliers, t) = verified
        .iter()
        .copied()
        .enumerate()
        .max_by(|(ia, a), (ib, b)| a.1.cmp(&b.1).then(a.0.total_cmp(&b.0)).then(ib.cmp(ia)))
        .map(|(_, v)| v)
        .expect("non-empty");
    let fitness = if step > 1 {
        cloud_fitness(source, target_index, &t, m.tau)
    } else {
        fitness
    };
    (fitness, inliers, t, verified)
}

/// A rigid transform as an `f32` 3x4 matrix, for fast scoring.
struct Affine32([[f32; 4]; 3]);

impl From<&Isometry3<f64>> for Affine32 {
    fn from(t: &Isometry3<f64>) -> Self {
        let m = t.to_homogeneous();
        let mut a = [[0f32; 4]; 3];
        for (r, row) in a.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = m[(r, c)] as f32;
            }
        }
        Affine32(a)
    }
}

crate::simd::dispatch_simd! {
    /// Number of pairs `(p, q)` with `‖m·p − q‖² < tau2`.
    fn m_count(m: &Affine32, p: &Soa, q: &Soa, tau2: f32) -> usize = m_count_generic;
}

#[inline(always)]
fn m_count_generic(m: &Affine32, p: &Soa, q: &Soa, tau2: f32) -> usize {
    let a = &m.0;
    let mut total = 0usize;
    let chunks =
        p.x.chunks(LANES)
            .zip(p.y.chunks(LANES))
            .zip(p.z.chunks(LANES))
            .zip(
                q.x.chunks(LANES)
                    .zip(q.y.chunks(LANES))
                    .zip(q.z.chunks(LANES)),
            );
    for (((px, py), pz), ((qx, qy), qz)) in chunks {
        let mut c = 0u32;
        for (((((&x, &y), &z), &u), &v), &w) in px.iter().zip(py).zip(pz).zip(qx).zip(qy).zip(qz) {
            let dx = a[0][0] * x + a[0][1] * y + a[0][2] * z + a[0][3] - u;
            let dy = a[1][0] * x + a[1][1] * y + a[1][2] * z + a[1][3] - v;
            let dz = a[2][0] * x + a[2][1] * y + a[2][2] * z + a[2][3] - w;
            c += u32::from(dx * dx + dy * dy + dz * dz < tau2);
        }
        total += c as usize;
    }
    total
}

/// Keeps the `keep` best hypotheses that differ from each other (by more than 5° or 3 inlier distances).
fn merge_top(top: &mut Vec<Hypothesis>, batch: Vec<Hypothesis>, keep: usize, tau: f64) {
    // A full list only takes hypotheses at least as good as its last one.
    let floor = if top.len() >= keep {
        top.last().map_or(0, |h| h.count)
    } else {
        0
    };
    let mut all: Vec<Hypothesis> = std::mem::take(top);
    all.extend(batch.into_iter().filter(|h| h.count >= floor));
    all.sort_by(|x, y| y.count.cmp(&x.count).then(x.iteration.cmp(&y.iteration)));
    for h in all {
        if top.len() >= keep {
            break;
        }
        let dup = top.iter().any(|k| {
            let (r, d) = pose_error(&k.t, &h.t);
            r < 5.0 && d < 3.0 * tau
        });
        if !dup {
            top.push(h);
        }
    }
}

/// Success probability of one guided sample given the inlier set of the current best hypothesis.
fn guided_success_probability(
    t: &Isometry3<f64>,
    ps: &[[f32; 3]],
    qs: &[[f32; 3]],
    tau2: f32,
    graph: &Graph,
    total_degree: u64,
    two_point: bool,
) -> f64 {
    let mut inlier = vec![0u64; graph.words];
    for (j, (p, q)) in ps.iter().zip(qs).enumerate() {
        let tp = transform_point(t, p);
        let ok = (tp[0] - q[0]).powi(2) + (tp[1] - q[1]).powi(2) + (tp[2] - q[2]).powi(2) < tau2;
        inlier[j / 64] |= (ok as u64) << (j % 64);
    }
    let mut p = 0.0;
    for i in 0..graph.len() {
        let n = graph.degree(i);
        if inlier[i / 64] >> (i % 64) & 1 == 0 || n < 2 {
            continue;
        }
        let deg = n as f64;
        let good = graph
            .row(i)
            .iter()
            .zip(&inlier)
            .map(|(a, b)| (a & b).count_ones())
            .sum::<u32>() as f64;
        let p_first = (n - 1) as f64 / total_degree as f64;
        // The further draws inlier (for triples, their mutual consistency is then almost sure).
        p += if two_point {
            p_first * (good / deg)
        } else {
            p_first * (good / deg) * ((good - 1.0).max(0.0) / deg)
        };
    }
    p
}

/// Refits `t` on its inlier correspondences (two rounds).
fn refit(t: &Isometry3<f64>, ps: &[[f32; 3]], qs: &[[f32; 3]], tau2: f32) -> Isometry3<f64> {
    let mut t = *t;
    for _ in 0..2 {
        let (src, dst): (Vec<Point3<f64>>, Vec<Point3<f64>>) = ps
            .iter()
            .zip(qs)
            .filter(|(p, q)| {
                let tp = transform_point(&t, p);
                (tp[0] - q[0]).powi(2) + (tp[1] - q[1]).powi(2) + (tp[2] - q[2]).powi(2) < tau2
            })
            .map(|(p, q)| (to_p64(p), to_p64(q)))
            .unzip();
        match rigid_fit(&src, &dst, None) {
            Some(n) => t = n,
            None => break,
        }
    }
    t
}

/// Fraction of `source` points with a target point (after `t`) closer than `tau` (an existence query:
/// the search stops at the first such point).
pub fn cloud_fitness(
    source: &[[f32; 3]],
    target_index: &KdIndex,
    t: &Isometry3<f64>,
    tau: f64,
) -> f64 {
    if source.is_empty() {
        return 0.0;
    }
    let tau2 = (tau * tau) as f32;
    let hits = source
        .par_iter()
        .filter(|p| target_index.any_closer_than(&transform_point(t, p), tau2))
        .count();
    hits as f64 / source.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimum translation joins a stated range (the larger lower bound wins) or makes one, and 0
    /// changes nothing.
    #[test]
    fn a_minimum_translation_joins_the_range() {
        let at = |d: f64| Isometry3::translation(d, 0.0, 0.0);
        let none = PoseConstraint::default();
        assert_eq!(none.clone().with_min_translation(0.0), none);
        let c = none.with_min_translation(0.12);
        assert!(!c.is_empty());
        assert!(!c.accepts(&at(0.03)) && c.accepts(&at(0.2)) && c.accepts(&at(50.0)));
        let ranged = PoseConstraint {
            max_tilt_deg: Some(5.0),
            translation_range: Some([0.05, 1.5]),
        };
        let c = ranged.with_min_translation(0.12);
        assert_eq!(c.translation_range, Some([0.12, 1.5]));
        assert_eq!(c.max_tilt_deg, Some(5.0));
        let far = PoseConstraint {
            max_tilt_deg: None,
            translation_range: Some([0.9, 1.5]),
        };
        assert_eq!(
            far.with_min_translation(0.12).translation_range,
            Some([0.9, 1.5])
        );
    }

    /// A 64 x 64 bit transpose against the bit-by-bit definition.
    #[test]
    fn transpose64_is_the_transpose() {
        let mut s = 3u64;
        let m: [u64; 64] = std::array::from_fn(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s
        });
        let mut t = m;
        transpose64(&mut t);
        for (r, row) in m.iter().enumerate() {
            for (c, col) in t.iter().enumerate() {
                assert_eq!((col >> r) & 1, (row >> c) & 1, "({r}, {c})");
            }
        }
    }

    /// The row-parallel graph is the graph of testing each pair once and mirroring it (the oracle), with
    /// ascending rows and no self-loops, for sizes with and without a partial last lane and word; its
    /// degrees, membership tests and `nth` neighbours agree with the lists.
    #[test]
    fn consistency_graph_matches_the_pairwise_oracle() {
        let mut s = 7u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        for n in [0, 1, 15, 16, 17, 64, 65, 203, 320] {
            let ps: Vec<[f32; 3]> = (0..n).map(|_| [r(), r(), r()]).collect();
            // Half the matches are the source moved rigidly (consistent), half noise.
            let qs: Vec<[f32; 3]> = ps
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    if k % 2 == 0 {
                        [p[0] + 1.0, p[2], p[1]]
                    } else {
                        [r(), r(), r()]
                    }
                })
                .collect();
            let (tol, min_len) = (0.05f32, 0.02f32);
            let graph = consistency_graph(&ps, &qs, tol, min_len);
            let g: Vec<Vec<u32>> = (0..graph.len()).map(|i| graph.neighbours(i)).collect();
            for (i, row) in g.iter().enumerate() {
                assert_eq!(graph.degree(i), row.len());
                for j in 0..n {
                    assert_eq!(graph.contains(i, j), row.binary_search(&(j as u32)).is_ok());
                }
            }
            let mut oracle = vec![Vec::new(); n];
            for i in 0..n {
                for j in i + 1..n {
                    if edge_agrees(&ps[j], &qs[j], &ps[i], &qs[i], tol, min_len * min_len) {
                        oracle[i].push(j as u32);
                        oracle[j].push(i as u32);
                    }
                }
            }
            for row in oracle.iter_mut() {
                row.sort_unstable();
            }
            assert_eq!(g, oracle, "n = {n}");
            if n == 203 {
                let edges: usize = g.iter().map(|r| r.len()).sum();
                assert!(edges > 1000, "{edges}");
            }
        }
    }
}
