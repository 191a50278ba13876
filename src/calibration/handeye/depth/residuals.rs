//! The residuals between one robot's frames under a hand-eye: every sampled point of frame `i`, moved into
//! camera `j` through the flange poses and the hand-eye, against the surface camera `j` saw there
//! (projective association, point-to-plane), with the Jacobian with respect to a hand-eye correction.
//!
//! Conventions: the correction is a twist `δ = [ω (rad), v (m)]` in the camera frame, `T_ee_cam' = T_ee_cam
//! · exp(δ)`. With `A = T_cam_j_cam_i = X⁻¹ · T_base_ee_j⁻¹ · T_base_ee_i · X` (rotation `R`) and a point
//! `p` of camera `i`, the point in camera `j` is `q = exp(δ)⁻¹ · A · exp(δ) · p`, and to first order
//! `dq/dω = −R·[p]× + [q]×`, `dq/dv = R − I`: the translation is seen only through the rotation between
//! the frames.

use crate::calibration::consistency::{
    sample_view, splitmix, Axis, ConsistencyConfig, Sample, SmoothDepth,
};
use crate::camera::distortion::undistort_is_identity;
use crate::camera::{DepthView, Intrinsics};
use crate::geometry::outer::OuterSum6;
use crate::registration::RobustKernel;
use nalgebra::{Isometry3, Matrix3, Matrix6, RowVector6, Vector3, Vector6};
use rayon::prelude::*;
use std::collections::BTreeMap;

/// A view's surface at pixel `(u, v)`: the point (camera frame, metres) and its unit normal oriented
/// toward the camera (the side the camera saw), from the view's block depths one block to each side.
/// `None` where the view has no smooth surface there.
pub(crate) fn surface_at(
    depth: &SmoothDepth,
    intr: &Intrinsics,
    u: f64,
    v: f64,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let b = depth.view.block as f64;
    // Without distortion a pixel's ray is `x` from its column and `y` from its row (what
    // `Intrinsics::deproject` computes, without the call).
    let separable = undistort_is_identity(intr.model, &intr.coeffs);
    let smooth = |au: &Axis, av: &Axis| -> Option<Vector3<f64>> {
        let (near, far) = depth.depth_on(au, av)?;
        if far - near > 1e-9 || near <= 0.0 {
            return None;
        }
        let p = if separable {
            let (x, y) = ((au.x() - intr.ppx) / intr.fx, (av.x() - intr.ppy) / intr.fy);
            [x * near, y * near, near]
        } else {
            intr.deproject([au.x(), av.x()], near)
        };
        Some(Vector3::new(p[0], p[1], p[2]))
    };
    // The five lookups share their columns and rows.
    let (cu, cv) = (depth.axis(u), depth.axis(v));
    let p = smooth(&cu, &cv)?;
    let du = smooth(&depth.axis(u + b), &cv)? - smooth(&depth.axis(u - b), &cv)?;
    let dv = smooth(&cu, &depth.axis(v + b))? - smooth(&cu, &depth.axis(v - b))?;
    let n = du.cross(&dv);
    let len = n.norm();
    if len.is_nan() || len <= 0.0 {
        return None;
    }
    let n = n / len;
    Some((p, if n.dot(&p) > 0.0 { -n } else { n }))
}

/// A test's row for the hand-eye change `[ω, v]` (camera frame): the point `p` of one frame, moved into the
/// other camera as `q = r·p + t`, against the surface normal `nj` there. The row is
/// `njᵀ [ [q]× − r [p]×,  r − I ]`; with `a = rᵀ nj` and `uᵀ [w]× = (u × w)ᵀ` that is
/// `[ nj × q − a × p,  a − nj ]` (two cross products instead of a 3x3 matrix product per test).
#[inline]
fn hand_eye_row(
    nj: &Vector3<f64>,
    q: &Vector3<f64>,
    p: &Vector3<f64>,
    r: &Matrix3<f64>,
) -> RowVector6<f64> {
    let a = r.tr_mul(nj);
    let jw = nj.cross(q) - a.cross(p);
    let jv = a - nj;
    RowVector6::new(jw[0], jw[1], jw[2], jv[0], jv[1], jv[2])
}

pub(crate) fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// One frame's sampled points with their normals, in its camera frame.
#[derive(Clone, Debug, Default)]
pub(crate) struct FramePoints {
    pub(crate) points: Vec<Vector3<f64>>,
    pub(crate) normals: Vec<Vector3<f64>>,
}

/// Samples each view's smooth blocks (the consistency check's sample) and keeps those with a normal.
pub(crate) fn frame_points(depths: &[SmoothDepth], intr: &Intrinsics) -> Vec<FramePoints> {
    depths
        .par_iter()
        .map(|depth| {
            let samples: Vec<Sample> = sample_view(depth.view, intr, depth.cfg);
            let mut out = FramePoints::default();
            for s in samples {
                if let Some((p, n)) = surface_at(depth, intr, s.u as f64, s.v as f64) {
                    out.points.push(p);
                    out.normals.push(n);
                }
            }
            out
        })
        .collect()
}

/// Samples each view's smooth blocks spread over the directions of their normals (normal-space
/// sampling, Rusinkiewicz and Levoy 2001) and keeps those with a normal: the blocks are binned by their
/// normal (camera frame), `bins` steps per axis, and taken from the bins in turn, each bin in a fixed
/// pseudo-random order, until `n` are taken. A view mostly of table and floor then still gives the few
/// blocks whose normals pin the other directions (the objects' sides) a share of the sample.
pub(crate) fn frame_points_by_normals(
    depths: &[SmoothDepth],
    intr: &Intrinsics,
    n: usize,
    bins: u32,
) -> Vec<FramePoints> {
    let bins = bins.max(1);
    let bin = |x: f64| {
        ((x + 1.0) * 0.5 * bins as f64)
            .floor()
            .clamp(0.0, (bins - 1) as f64) as u32
    };
    depths
        .par_iter()
        .map(|depth| {
            let every = ConsistencyConfig {
                sample_points: usize::MAX,
                ..depth.cfg.clone()
            };
            // Per bin (in key order): (rank, index into `found`).
            let mut binned: BTreeMap<[u32; 3], Vec<(u64, usize)>> = BTreeMap::new();
            let mut found = Vec::new();
            for (k, s) in sample_view(depth.view, intr, &every).iter().enumerate() {
                if let Some((p, nrm)) = surface_at(depth, intr, s.u as f64, s.v as f64) {
                    binned
                        .entry([bin(nrm.x), bin(nrm.y), bin(nrm.z)])
                        .or_default()
                        .push((splitmix(k as u64), found.len()));
                    found.push((p, nrm));
                }
            }
            let mut lists: Vec<Vec<(u64, usize)>> = binned.into_values().collect();
            for l in &mut lists {
                // Highest rank last: `pop` takes the bins' members in ascending rank.
                l.sort_unstable_by(|a, b| b.cmp(a));
            }
            let want = n.min(found.len());
            let mut chosen = Vec::with_capacity(want);
            while chosen.len() < want {
                for l in &mut lists {
                    if chosen.len() == want {
                        break;
                    }
                    if let Some((_, i)) = l.pop() {
                        chosen.push(i);
                    }
                }
            }
            chosen.sort_unstable();
            let mut out = FramePoints::default();
            for i in chosen {
                out.points.push(found[i].0);
                out.normals.push(found[i].1);
            }
            out
        })
        .collect()
}

/// The settings the association and weighting use.
#[derive(Clone, Debug)]
pub(crate) struct Association {
    /// Residuals beyond this (metres) are not counted (occlusions, other surfaces).
    pub(crate) gate_m: f64,
    /// Cosine of the largest angle between the two frames' normals of a pair (the side-of-surface rule).
    pub(crate) min_normal_cos: f64,
    /// The robust kernel and its scale in units of the pair's depth noise σ.
    pub(crate) kernel: RobustKernel,
    /// See `kernel`.
    pub(crate) kernel_sigmas: f64,
}

/// Per-frame sums of the normal equations and residual statistics.
#[derive(Clone, Debug, Default)]
pub(crate) struct FrameSums {
    /// `Σ w JᵀJ / σ²`.
    pub(crate) h: Matrix6<f64>,
    /// `Σ w Jᵀ r / σ²`.
    pub(crate) g: Vector6<f64>,
    /// `Σ w r² / σ²`.
    pub(crate) chi2: f64,
    /// `Σ w`.
    pub(crate) weight: f64,
    /// The absolute residuals (metres) of the counted tests.
    pub(crate) abs: Vec<f32>,
    /// Tests that face a surface from behind (the side-of-surface rule) and were not counted.
    pub(crate) wrong_side: usize,
    /// Samples of this frame that took part in at least one test.
    pub(crate) samples_used: usize,
}

/// Everything the residuals need: the flange poses, the views (their smooth depths tabulated) and the
/// sampled points.
pub(crate) struct Problem<'a> {
    pub(crate) t_base_ee: Vec<Isometry3<f64>>,
    pub(crate) depths: Vec<SmoothDepth<'a>>,
    pub(crate) intr: &'a Intrinsics,
    pub(crate) points: Vec<FramePoints>,
    pub(crate) cfg: &'a ConsistencyConfig,
}

impl<'a> Problem<'a> {
    /// The problem of one robot's frames: flange poses `t_base_ee` and depth `views` (one per frame) seen
    /// through `intr`, sampled under `cfg`.
    pub(crate) fn new(
        t_base_ee: Vec<Isometry3<f64>>,
        views: &'a [DepthView],
        intr: &'a Intrinsics,
        cfg: &'a ConsistencyConfig,
    ) -> Self {
        Problem::with_sampling(t_base_ee, views, intr, cfg, 0)
    }

    /// [`Problem::new`], with each frame's sample spread over its normals in `normal_bins` bins per axis
    /// ([`frame_points_by_normals`]; 0: uniform, as [`Problem::new`]).
    pub(crate) fn with_sampling(
        t_base_ee: Vec<Isometry3<f64>>,
        views: &'a [DepthView],
        intr: &'a Intrinsics,
        cfg: &'a ConsistencyConfig,
        normal_bins: u32,
    ) -> Self {
        let depths: Vec<SmoothDepth> = views.par_iter().map(|v| SmoothDepth::new(v, cfg)).collect();
        let points = if normal_bins > 0 {
            frame_points_by_normals(&depths, intr, cfg.sample_points, normal_bins)
        } else {
            frame_points(&depths, intr)
        };
        Problem {
            t_base_ee,
            depths,
            intr,
            points,
            cfg,
        }
    }

    /// The number of frames (views).
    pub(crate) fn frames(&self) -> usize {
        self.depths.len()
    }
}

/// One camera's depth, as points are tested against it.
pub(crate) struct Target<'a> {
    /// Its depth, with the settings it was tabulated under (the noise model of its depths).
    pub(crate) depth: &'a SmoothDepth<'a>,
    pub(crate) intr: &'a Intrinsics,
    /// Image width and height, pixels.
    pub(crate) size: (f64, f64),
}

/// What a point of one frame finds in another camera's depth.
pub(crate) enum PointTest {
    /// Behind the camera, outside the image, no smooth surface there, beyond the gate, or refused.
    Miss,
    /// Refused by the side-of-surface rule, with its point-to-plane residual (m).
    WrongSide { res: f64 },
    /// A test: the surface's unit normal `nj`, the point-to-plane residual (m), its 1-σ (m) and the
    /// robust kernel's weight.
    Hit {
        nj: Vector3<f64>,
        res: f64,
        sigma: f64,
        weight: f64,
    },
}

/// Tests point `p` with normal `np` (its own camera, metres), already moved into the target camera as `q`
/// by a rotation `r`: projective association, the residual gate, then `accept(u, v, surface point,
/// surface normal)`, then the side-of-surface rule. `point_cfg` gives the point's own depth noise.
#[inline]
pub(crate) fn test_point(
    t: &Target,
    point_cfg: &ConsistencyConfig,
    asn: &Association,
    r: &Matrix3<f64>,
    (p, np): (&Vector3<f64>, &Vector3<f64>),
    q: &Vector3<f64>,
    accept: impl Fn(f64, f64, &Vector3<f64>, &Vector3<f64>) -> bool,
) -> PointTest {
    if q.z <= 1e-3 {
        return PointTest::Miss;
    }
    let [u, v] = t.intr.project([q.x, q.y, q.z]);
    let (w, h) = t.size;
    if !(u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5) {
        return PointTest::Miss;
    }
    let Some((pj, nj)) = surface_at(t.depth, t.intr, u, v) else {
        return PointTest::Miss;
    };
    let res = nj.dot(&(q - pj));
    if res.abs() > asn.gate_m || !accept(u, v, &pj, &nj) {
        return PointTest::Miss;
    }
    // Side of surface: the point's surface, seen from the target camera, must face it as the surface that
    // camera saw does.
    let ni = r * np;
    if ni.dot(&nj) < asn.min_normal_cos || ni.dot(q) > 0.0 {
        return PointTest::WrongSide { res };
    }
    let sigma = (point_cfg.sigma(p.z).powi(2) + t.depth.cfg.sigma(pj.z).powi(2))
        .sqrt()
        .max(1e-5);
    let weight = asn.kernel.weight(res / sigma, asn.kernel_sigmas);
    PointTest::Hit {
        nj,
        res,
        sigma,
        weight,
    }
}

impl PointTest {
    /// A hit's `(nj, res, sigma, weight)`; `None` for a miss, and for a side-of-surface refusal, which is
    /// also counted in `wrong_side`.
    #[inline]
    pub(crate) fn hit(self, wrong_side: &mut usize) -> Option<(Vector3<f64>, f64, f64, f64)> {
        match self {
            PointTest::Miss => None,
            PointTest::WrongSide { .. } => {
                *wrong_side += 1;
                None
            }
            PointTest::Hit {
                nj,
                res,
                sigma,
                weight,
            } => Some((nj, res, sigma, weight)),
        }
    }
}

/// How one frame's camera coordinates map into another camera's: `q = apply(p)`, with the rotation part
/// as a matrix (the side-of-surface rule turns normals with it). Each caller keeps its own arithmetic,
/// so that the tests it gets back are the ones it would have computed.
pub(crate) trait FrameMap {
    /// The rotation part.
    fn rotation(&self) -> &Matrix3<f64>;
    /// Point `p` of the first camera, in the second's coordinates (metres).
    fn apply(&self, p: &Vector3<f64>) -> Vector3<f64>;
}

/// A [`FrameMap`] as a rotation matrix and a translation: `q = r·p + t`.
pub(crate) struct MatrixMap {
    pub(crate) r: Matrix3<f64>,
    pub(crate) t: Vector3<f64>,
}

impl MatrixMap {
    pub(crate) fn of(m: &Isometry3<f64>) -> Self {
        MatrixMap {
            r: *m.rotation.to_rotation_matrix().matrix(),
            t: m.translation.vector,
        }
    }
}

impl FrameMap for MatrixMap {
    fn rotation(&self) -> &Matrix3<f64> {
        &self.r
    }
    #[inline]
    fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.r * p + self.t
    }
}

/// A point's test that found a surface ([`PointTest::Hit`]): the point's index in its frame's sample,
/// the surface's unit normal, the residual (m), its 1-σ (m) and the robust kernel's weight.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Found {
    pub(crate) k: u32,
    pub(crate) nj: Vector3<f64>,
    pub(crate) res: f64,
    pub(crate) sigma: f64,
    pub(crate) weight: f64,
}

/// The tests of one frame's sampled points in one other camera: the hits in sample order, and the
/// residuals (m) of those the side-of-surface rule refused.
#[derive(Clone, Debug, Default)]
pub(crate) struct PairTests {
    pub(crate) hits: Vec<Found>,
    pub(crate) refused: Vec<f64>,
}

impl Problem<'_> {
    /// Every frame's sampled points tested in every other camera (`map(i, j)` takes camera `i`'s
    /// coordinates into camera `j`'s), as `[i][j]` (empty for `j == i`).
    ///
    /// The tests run camera by camera: while every other frame's points are tested against one view, its
    /// depth table stays in the cache. Run frame by frame instead, each frame pair's few hundred scattered
    /// lookups each missed the cache (every other view had been read since), which cost about half of the
    /// hand-eye check's and the pose scatter's time. Deterministic at any thread count.
    pub(crate) fn test_pairs<M: FrameMap>(
        &self,
        asn: &Association,
        map: impl Fn(usize, usize) -> M + Sync,
    ) -> Vec<Vec<PairTests>> {
        let n = self.frames();
        let size = (self.intr.width as f64, self.intr.height as f64);
        let by_target: Vec<Vec<PairTests>> = (0..n)
            .into_par_iter()
            .map(|j| {
                let target = Target {
                    depth: &self.depths[j],
                    intr: self.intr,
                    size,
                };
                (0..n)
                    .map(|i| {
                        let mut out = PairTests::default();
                        if i == j {
                            return out;
                        }
                        let m = map(i, j);
                        let r = m.rotation();
                        let fp = &self.points[i];
                        for (k, (p, np)) in fp.points.iter().zip(&fp.normals).enumerate() {
                            let q = m.apply(p);
                            let test =
                                test_point(&target, self.cfg, asn, r, (p, np), &q, |_, _, _, _| {
                                    true
                                });
                            match test {
                                PointTest::Hit {
                                    nj,
                                    res,
                                    sigma,
                                    weight,
                                } => out.hits.push(Found {
                                    k: k as u32,
                                    nj,
                                    res,
                                    sigma,
                                    weight,
                                }),
                                PointTest::WrongSide { res } => out.refused.push(res),
                                PointTest::Miss => {}
                            }
                        }
                        out
                    })
                    .collect()
            })
            .collect();
        let mut by_frame: Vec<Vec<PairTests>> = (0..n).map(|_| Vec::with_capacity(n)).collect();
        for row in by_target {
            for (i, t) in row.into_iter().enumerate() {
                by_frame[i].push(t);
            }
        }
        by_frame
    }
}

impl Problem<'_> {
    /// How the residuals at hand-eye `x` (association `a`) answer to errors of the flange poses: per frame
    /// `k`, `C_k = Σ w/σ² J_xᵀ J_εk` over every test, where `J_x` is a test's row for the hand-eye change
    /// (as in [`Problem::sums`]) and `ε_k` a left increment of frame `k`'s flange pose in the base frame, a
    /// twist `[ω, v]` about `centre` (metres, base frame). A fit that solves `H δ = −g` then moves by
    /// `−H⁻¹ Σ_k C_k ε_k` to first order. Frame order; deterministic at any thread count.
    pub(crate) fn pose_sensitivity(
        &self,
        x: &Isometry3<f64>,
        a: &Association,
        centre: &Vector3<f64>,
    ) -> Vec<Matrix6<f64>> {
        let n = self.frames();
        let x_inv = x.inverse();
        let cam_base = |j: usize| x_inv * self.t_base_ee[j].inverse();
        let map = |i: usize, j: usize| MatrixMap::of(&(cam_base(j) * (self.t_base_ee[i] * x)));
        let tests = self.test_pairs(a, map);
        // Per source frame i: its own block, and the blocks of the frames its points were tested in.
        #[allow(clippy::type_complexity)]
        let per_frame: Vec<(Matrix6<f64>, Vec<(usize, Matrix6<f64>)>)> = tests
            .into_par_iter()
            .enumerate()
            .map(|(i, pairs)| {
                let mut own = Matrix6::zeros();
                let mut others = Vec::new();
                let fp = &self.points[i];
                let base_cam_i = self.t_base_ee[i] * x;
                for (j, pt) in pairs.iter().enumerate().filter(|&(j, _)| j != i) {
                    let MatrixMap { r, t: tv } = map(i, j);
                    let r_cj = *cam_base(j).rotation.to_rotation_matrix().matrix();
                    let mut block = Matrix6::zeros();
                    for f in &pt.hits {
                        let (p, nj) = (&fp.points[f.k as usize], &f.nj);
                        let q = r * p + tv;
                        let jrow = hand_eye_row(nj, &q, p, &r);
                        // The point in the base, about the centre: frame i's increment moves it by
                        // ω × (y − c) + v, seen in camera j through its rotation.
                        let y = (base_cam_i * nalgebra::Point3::from(*p)).coords - centre;
                        let nb = r_cj.transpose() * nj;
                        let ew = y.cross(&nb);
                        let erow = RowVector6::new(ew[0], ew[1], ew[2], nb[0], nb[1], nb[2]);
                        block += jrow.transpose() * erow * (f.weight / (f.sigma * f.sigma));
                    }
                    own += block;
                    // Frame j's increment moves its camera, and the point the other way.
                    others.push((j, -block));
                }
                (own, others)
            })
            .collect();
        let mut out = vec![Matrix6::zeros(); n];
        for (i, (own, others)) in per_frame.into_iter().enumerate() {
            out[i] += own;
            for (j, b) in others {
                out[j] += b;
            }
        }
        out
    }
}

impl Problem<'_> {
    /// The per-frame sums under hand-eye `x` (frame order, deterministic at any thread count).
    pub(crate) fn sums(&self, x: &Isometry3<f64>, a: &Association) -> Vec<FrameSums> {
        self.sums_of(x, &self.test_pairs(a, self.hand_eye_map(x)), a.gate_m)
    }

    /// [`Problem::sums`] at each of `gates_m` (metres, none wider than `a`'s), in that order, from one
    /// run of the tests at `a`'s gate: the same sums, bit for bit, as a run per gate.
    pub(crate) fn sums_at_gates(
        &self,
        x: &Isometry3<f64>,
        a: &Association,
        gates_m: &[f64],
    ) -> Vec<Vec<FrameSums>> {
        debug_assert!(gates_m.iter().all(|&g| g <= a.gate_m));
        let tests = self.test_pairs(a, self.hand_eye_map(x));
        gates_m
            .iter()
            .map(|&g| self.sums_of(x, &tests, g))
            .collect()
    }

    /// How hand-eye `x` takes camera `i`'s coordinates into camera `j`'s.
    fn hand_eye_map(&self, x: &Isometry3<f64>) -> impl Fn(usize, usize) -> MatrixMap + Sync + '_ {
        let (x, x_inv) = (*x, x.inverse());
        move |i: usize, j: usize| {
            MatrixMap::of(&(x_inv * self.t_base_ee[j].inverse() * self.t_base_ee[i] * x))
        }
    }

    /// The per-frame sums of `tests` (from [`Problem::test_pairs`] under hand-eye `x`) within a residual
    /// gate of `gate_m` (metres, at most the one they ran with): the tests that gate finds, since the
    /// residual gate is [`test_point`]'s first test after the surface lookup and nothing else depends on it.
    fn sums_of(&self, x: &Isometry3<f64>, tests: &[Vec<PairTests>], gate_m: f64) -> Vec<FrameSums> {
        let map = self.hand_eye_map(x);
        tests
            .par_iter()
            .enumerate()
            .map(|(i, pairs)| {
                let mut s = FrameSums::default();
                let fp = &self.points[i];
                if fp.points.is_empty() {
                    return s;
                }
                let mut used = vec![false; fp.points.len()];
                let mut h = OuterSum6::default();
                for (j, pt) in pairs.iter().enumerate().filter(|&(j, _)| j != i) {
                    let MatrixMap { r, t: tv } = map(i, j);
                    s.wrong_side += pt.refused.iter().filter(|r| r.abs() <= gate_m).count();
                    for f in pt.hits.iter().filter(|f| f.res.abs() <= gate_m) {
                        let p = &fp.points[f.k as usize];
                        let q = r * p + tv;
                        let jrow = hand_eye_row(&f.nj, &q, p, &r);
                        let ws = f.weight / (f.sigma * f.sigma);
                        h.add(&jrow.transpose(), ws);
                        s.g += jrow.transpose() * (f.res * ws);
                        s.chi2 += f.weight * (f.res / f.sigma).powi(2);
                        s.weight += f.weight;
                        s.abs.push(f.res.abs() as f32);
                        used[f.k as usize] = true;
                    }
                }
                s.h = h.matrix();
                s.samples_used = used.iter().filter(|&&u| u).count();
                s
            })
            .collect()
    }
}

/// The sums of all frames, added in frame order.
pub(crate) fn total(sums: &[FrameSums]) -> (Matrix6<f64>, Vector6<f64>, f64, f64, usize) {
    let mut h = Matrix6::zeros();
    let mut g = Vector6::zeros();
    let (mut chi2, mut w, mut n) = (0.0, 0.0, 0usize);
    for s in sums {
        h += s.h;
        g += s.g;
        chi2 += s.chi2;
        w += s.weight;
        n += s.abs.len();
    }
    (h, g, chi2, w, n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::consistency::ConsistencyConfig;
    use crate::camera::DepthImage;

    /// A tilted plane seen by two cameras: one Gauss-Newton step with the analytic Jacobian from a wrong
    /// hand-eye cuts the cost by more than 5x (a wrong Jacobian does not).
    #[test]
    fn a_gauss_newton_step_lowers_the_cost_on_a_plane() {
        let intr = Intrinsics::pinhole(160, 120, 120.0, 120.0, 79.5, 59.5);
        let cfg = ConsistencyConfig {
            sample_points: 200,
            ..ConsistencyConfig::default()
        };
        // Plane z = 0.6 + 0.2 x in the base; the flange moves and turns, the camera is 5 cm off it.
        let x = Isometry3::new(
            Vector3::new(0.02, -0.03, 0.05),
            Vector3::new(0.1, -0.05, 0.3),
        );
        let poses = [
            Isometry3::new(Vector3::new(0.0, 0.0, 0.0), Vector3::zeros()),
            Isometry3::new(Vector3::new(0.03, 0.01, 0.0), Vector3::new(0.05, 0.12, 0.2)),
        ];
        let render = |t_base_ee: &Isometry3<f64>| -> DepthView {
            let t_base_cam = t_base_ee * x;
            let mut img = DepthImage::zeros(160, 120);
            let n = Vector3::new(-0.2, 0.0, 1.0);
            let o = t_base_cam.translation.vector;
            for v in 0..120 {
                for u in 0..160 {
                    let d = intr.deproject([u as f64, v as f64], 1.0);
                    let ray = t_base_cam.rotation * Vector3::new(d[0], d[1], d[2]);
                    // n·(o + t ray) = 0.6
                    let t = (0.6 - n.dot(&o)) / n.dot(&ray);
                    img.data[(v * 160 + u) as usize] = (t * 1e4).round() as u16;
                }
            }
            let mut intr = intr.clone();
            intr.depth_scale = 1e-4;
            DepthView::new(&img, &intr, &t_base_cam, 4)
        };
        let mut intr4 = intr.clone();
        intr4.depth_scale = 1e-4;
        let views: Vec<DepthView> = poses.iter().map(render).collect();
        let problem = Problem::new(poses.to_vec(), &views, &intr4, &cfg);
        let a = Association {
            gate_m: 0.05,
            min_normal_cos: 0.5,
            kernel: RobustKernel::None,
            kernel_sigmas: 1.0,
        };
        assert!(problem.points[0].points.len() > 50);
        let x1 = x * Isometry3::new(
            Vector3::new(0.002, 0.001, -0.001),
            Vector3::new(0.004, -0.003, 0.002),
        );
        let (h, g, chi2, _, n) = total(&problem.sums(&x1, &a));
        assert!(n > 100, "{n}");
        // A Gauss-Newton step from x1 lowers the cost sharply.
        let damped = h + Matrix6::identity() * (h.trace() * 1e-9);
        let step = damped.cholesky().unwrap().solve(&(-g));
        let x2 = x1
            * Isometry3::from_parts(
                nalgebra::Translation3::new(step[3], step[4], step[5]),
                nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(step[0], step[1], step[2])),
            );
        let (_, _, chi2b, _, nb) = total(&problem.sums(&x2, &a));
        assert!(
            chi2b / (nb as f64) < 0.2 * chi2 / (n as f64),
            "{chi2} / {n} -> {chi2b} / {nb}"
        );
    }

    /// Four cameras over a plane with holes and a ramp through it.
    struct RampScene {
        /// A hand-eye slightly off the one the views were made with.
        x_off: Isometry3<f64>,
        poses: Vec<Isometry3<f64>>,
        /// At 0.1 mm depth units.
        views: Vec<DepthView>,
        intr: Intrinsics,
        cfg: ConsistencyConfig,
        /// Strict enough that the blocks' normal noise sends some tests to the wrong side.
        association: Association,
    }

    fn ramp_scene() -> RampScene {
        let intr = Intrinsics::pinhole(160, 120, 120.0, 120.0, 79.5, 59.5);
        let cfg = ConsistencyConfig {
            sample_points: 300,
            ..ConsistencyConfig::default()
        };
        let x = Isometry3::new(
            Vector3::new(0.02, -0.03, 0.05),
            Vector3::new(0.1, -0.05, 0.3),
        );
        let poses: Vec<Isometry3<f64>> = (0..4)
            .map(|k| {
                let k = k as f64;
                Isometry3::new(
                    Vector3::new(0.03 * k, 0.01 * k, -0.01 * k),
                    Vector3::new(0.05 * k, 0.12 - 0.06 * k, 0.2 * k),
                )
            })
            .collect();
        let mut intr4 = intr.clone();
        intr4.depth_scale = 1e-4;
        let views: Vec<DepthView> = poses
            .iter()
            .map(|t_base_ee| {
                let t_base_cam = t_base_ee * x;
                let mut img = DepthImage::zeros(160, 120);
                let n = Vector3::new(-0.2, 0.0, 1.0);
                let o = t_base_cam.translation.vector;
                for v in 0..120u32 {
                    for u in 0..160u32 {
                        if (u / 13 + v / 11) % 7 == 0 {
                            continue; // holes
                        }
                        let d = intr.deproject([u as f64, v as f64], 1.0);
                        let ray = t_base_cam.rotation * Vector3::new(d[0], d[1], d[2]);
                        let mut t = (0.6 - n.dot(&o)) / n.dot(&ray);
                        let hit = o + ray * t;
                        if hit.x.abs() < 0.08 && hit.y.abs() < 0.05 {
                            t *= 0.97 + 1.2 * hit.x; // a ramp through the plane
                        }
                        img.data[(v * 160 + u) as usize] = (t * 1e4).round() as u16;
                    }
                }
                DepthView::new(&img, &intr4, &t_base_cam, 4)
            })
            .collect();
        RampScene {
            x_off: x * Isometry3::new(
                Vector3::new(0.004, 0.002, -0.003),
                Vector3::new(0.01, -0.02, 0.015),
            ),
            poses,
            views,
            intr: intr4,
            cfg,
            association: Association {
                gate_m: 0.02,
                min_normal_cos: 0.9998,
                kernel: RobustKernel::Huber,
                kernel_sigmas: 1.0,
            },
        }
    }

    /// The tests run camera by camera ([`Problem::test_pairs`]) are those of the frame-by-frame loop,
    /// bit for bit and in sample order: four cameras over a slanted plane with a raised patch (depth
    /// steps) and holes, under a hand-eye slightly off, so that points hit, miss and fall on the wrong
    /// side.
    #[test]
    fn pairs_tested_by_camera_are_the_frame_by_frame_tests() {
        let RampScene {
            x_off: x1,
            poses,
            views,
            intr: intr4,
            cfg,
            association: a,
        } = ramp_scene();
        let problem = Problem::new(poses.clone(), &views, &intr4, &cfg);
        let map = |i: usize, j: usize| {
            MatrixMap::of(&(x1.inverse() * poses[j].inverse() * poses[i] * x1))
        };
        let got = problem.test_pairs(&a, map);
        let size = (160.0, 120.0);
        let (mut hits, mut wrong, mut misses) = (0, 0, 0);
        for (i, row) in got.iter().enumerate() {
            assert_eq!(row.len(), 4);
            for (j, pair) in row.iter().enumerate() {
                let mut want = PairTests::default();
                if i != j {
                    let m = map(i, j);
                    let target = Target {
                        depth: &problem.depths[j],
                        intr: &intr4,
                        size,
                    };
                    let fp = &problem.points[i];
                    for (k, (p, np)) in fp.points.iter().zip(&fp.normals).enumerate() {
                        let q = m.apply(p);
                        match test_point(&target, &cfg, &a, &m.r, (p, np), &q, |_, _, _, _| true) {
                            PointTest::Hit {
                                nj,
                                res,
                                sigma,
                                weight,
                            } => want.hits.push(Found {
                                k: k as u32,
                                nj,
                                res,
                                sigma,
                                weight,
                            }),
                            PointTest::WrongSide { res } => want.refused.push(res),
                            PointTest::Miss => misses += 1,
                        }
                    }
                }
                let bits = |t: &PairTests| -> Vec<(u32, [u64; 6])> {
                    t.hits
                        .iter()
                        .map(|f| {
                            let b = [f.nj.x, f.nj.y, f.nj.z, f.res, f.sigma, f.weight];
                            (f.k, b.map(f64::to_bits))
                        })
                        .collect()
                };
                assert_eq!(bits(pair), bits(&want), "frames {i} -> {j}");
                assert_eq!(pair.refused, want.refused, "frames {i} -> {j}");
                hits += want.hits.len();
                wrong += want.refused.len();
            }
        }
        assert!(
            hits > 500 && wrong > 5 && misses > 100,
            "{hits} hits, {wrong} wrong side, {misses} misses"
        );
    }

    /// The sums at several gates from one run of the tests at the widest are those of a run per gate, bit
    /// for bit, down to the side-of-surface refusals and the samples used; the narrower gates drop tests
    /// and refusals (or the check would not bite).
    #[test]
    fn sums_at_gates_are_the_sums_of_a_run_per_gate() {
        let scene = ramp_scene();
        let problem = Problem::new(scene.poses, &scene.views, &scene.intr, &scene.cfg);
        let (x1, wide) = (scene.x_off, scene.association);
        let gates = [0.02, 0.004, 0.0015];
        let joint = problem.sums_at_gates(&x1, &wide, &gates);
        let mut counts = Vec::new();
        for (&gate_m, got) in gates.iter().zip(&joint) {
            let want = problem.sums(&x1, &Association { gate_m, ..wide });
            assert_eq!(got.len(), want.len());
            let bits = |s: &FrameSums| {
                let mut v: Vec<u64> = s.h.iter().chain(s.g.iter()).map(|x| x.to_bits()).collect();
                v.extend([s.chi2.to_bits(), s.weight.to_bits()]);
                v.extend(s.abs.iter().map(|a| a.to_bits() as u64));
                v.extend([s.wrong_side as u64, s.samples_used as u64]);
                v
            };
            for (g, w) in got.iter().zip(&want) {
                assert_eq!(bits(g), bits(w), "gate {gate_m}");
            }
            let tests: usize = want.iter().map(|s| s.abs.len()).sum();
            let wrong: usize = want.iter().map(|s| s.wrong_side).sum();
            counts.push((tests, wrong));
        }
        assert!(
            counts[0].0 > counts[1].0 && counts[1].0 > counts[2].0 && counts[2].0 > 100,
            "{counts:?}"
        );
        assert!(counts[0].1 > counts[2].1, "{counts:?}");
    }

    /// `surface_at` (axes shared among its five lookups, rays without a call where there is no
    /// distortion) is the plain five lookups and deprojections, bit for bit: a slanted plane with holes and
    /// a rough patch, at random pixels inside and beyond the edges, for a pinhole, a Brown-Conrady camera
    /// without and with terms and a Kannala-Brandt one.
    #[test]
    fn surface_at_is_five_plain_lookups() {
        use crate::camera::DistortionModel;
        let reference = |depth: &SmoothDepth, intr: &Intrinsics, u: f64, v: f64| {
            let smooth = |u: f64, v: f64| -> Option<Vector3<f64>> {
                let (near, far) = depth.depth(u, v)?;
                if far - near > 1e-9 || near <= 0.0 {
                    return None;
                }
                let p = intr.deproject([u, v], near);
                Some(Vector3::new(p[0], p[1], p[2]))
            };
            let b = depth.view.block as f64;
            let p = smooth(u, v)?;
            let du = smooth(u + b, v)? - smooth(u - b, v)?;
            let dv = smooth(u, v + b)? - smooth(u, v - b)?;
            let n = du.cross(&dv);
            let len = n.norm();
            if len.is_nan() || len <= 0.0 {
                return None;
            }
            let n = n / len;
            Some((p, if n.dot(&p) > 0.0 { -n } else { n }))
        };
        let mut img = DepthImage::zeros(64, 48);
        for v in 0..48u32 {
            for u in 0..64u32 {
                img.data[(v * 64 + u) as usize] = if (u / 9 + v / 7) % 5 == 0 {
                    0
                } else if u < 40 {
                    800 + 3 * u + 2 * v
                } else {
                    1500 + 300 * ((u + v) % 2)
                } as u16;
            }
        }
        let cfg = ConsistencyConfig::default();
        let cameras = [
            (DistortionModel::None, [0.0; 5]),
            (DistortionModel::BrownConrady, [0.0; 5]),
            (
                DistortionModel::BrownConrady,
                [0.1, -0.2, 0.001, -0.002, 0.05],
            ),
            (DistortionModel::KannalaBrandt4, [0.0; 5]),
        ];
        for (model, coeffs) in cameras {
            let intr = Intrinsics {
                model,
                coeffs,
                ..Intrinsics::pinhole(64, 48, 50.0, 52.0, 31.2, 23.7)
            };
            let view = DepthView::new(&img, &intr, &Isometry3::identity(), 4);
            let depth = SmoothDepth::new(&view, &cfg);
            let mut rng = crate::geometry::rng::Rng::new(11);
            let mut r = move || rng.next_f64();
            let bits = |x: Option<(Vector3<f64>, Vector3<f64>)>| {
                x.map(|(p, n)| [p.x, p.y, p.z, n.x, n.y, n.z].map(f64::to_bits))
            };
            let mut found = 0;
            for _ in 0..20_000 {
                let (u, v) = (r() * 72.0 - 4.0, r() * 56.0 - 4.0);
                let want = reference(&depth, &intr, u, v);
                found += want.is_some() as usize;
                assert_eq!(
                    bits(surface_at(&depth, &intr, u, v)),
                    bits(want),
                    "({u}, {v}), {model:?}"
                );
            }
            assert!(found > 2000, "{found} surfaces, {model:?}");
        }
    }
}
