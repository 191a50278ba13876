//! Fast Point Feature Histograms (Rusu, Blodow, Beetz 2009), 33 bins: 11 for each of the three angular
//! features (α, φ, θ), with the pair-feature and weighting conventions of PCL and Open3D:
//!
//! 1. SPFH(p): histogram of the Darboux-frame features between `p` and each neighbour within `radius`
//!    (up to `max_neighbors`), each bin block normalised to sum to 100.
//! 2. FPFH(p) = SPFH(p) + per-block renormalised Σ_k SPFH(p_k) / ‖p − p_k‖².

use crate::index::KdIndex;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Number of bins of an FPFH descriptor.
pub const FPFH_BINS: usize = 33;

/// One FPFH descriptor.
pub type Fpfh = [f32; FPFH_BINS];

/// Parameters of [`compute_fpfh`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FpfhConfig {
    /// Neighbourhood radius in cloud units (the pipeline uses 5 × voxel).
    pub radius: f64,
    /// Largest number of neighbours (nearest first, the point itself included; default 100).
    pub max_neighbors: usize,
}

impl Default for FpfhConfig {
    fn default() -> Self {
        FpfhConfig {
            radius: 0.25,
            max_neighbors: 100,
        }
    }
}

impl FpfhConfig {
    /// Checks the ranges; the error names the field (`fpfh.…`).
    pub fn validate(&self) -> crate::Result<()> {
        use crate::error::check;
        check::positive("fpfh.radius", self.radius)?;
        check::at_least("fpfh.max_neighbors", self.max_neighbors, 1)
    }
}

/// The four pair features `(α as atan2, φ, θ, distance)` of PCL/Open3D for points `p1`, `p2` with unit
/// normals `n1`, `n2`; all zero when the points coincide or the geometry is degenerate.
#[inline]
pub fn pair_features(p1: [f64; 3], n1: [f64; 3], p2: [f64; 3], n2: [f64; 3]) -> [f64; 4] {
    let mut dp = sub(p2, p1);
    let f4 = norm(dp);
    if f4 == 0.0 {
        return [0.0; 4];
    }
    let (mut a, mut b) = (n1, n2);
    let angle1 = dot(n1, dp) / f4;
    let angle2 = dot(n2, dp) / f4;
    // acos is decreasing: acos|a1| > acos|a2|  ⇔  |a1| < |a2|.
    let f3 = if angle1.abs() < angle2.abs() {
        a = n2;
        b = n1;
        dp = [-dp[0], -dp[1], -dp[2]];
        -angle2
    } else {
        angle1
    };
    let v = cross(dp, a);
    let vn = norm(v);
    if vn == 0.0 {
        return [0.0; 4];
    }
    let v = [v[0] / vn, v[1] / vn, v[2] / vn];
    let w = cross(a, v);
    let f2 = dot(v, b);
    let f1 = dot(w, b).atan2(dot(a, b));
    [f1, f2, f3, f4]
}

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
#[inline]
fn f64x3(p: &[f32; 3]) -> [f64; 3] {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}

/// Bin indices (0..33) of a pair feature.
#[inline]
fn bins(pf: &[f64; 4]) -> [usize; 3] {
    // Truncation instead of `floor` (a libm call on the baseline x86-64 target): they differ only on
    // negative non-integers, which both clamp to bin 0 (NaN casts to 0 either way).
    let b = |x: f64| (x as i64).clamp(0, 10) as usize;
    [
        b(11.0 * (pf[0] + std::f64::consts::PI) / std::f64::consts::TAU),
        11 + b(11.0 * (pf[1] + 1.0) * 0.5),
        22 + b(11.0 * (pf[2] + 1.0) * 0.5),
    ]
}

/// The SPFH of one point from its neighbours (index, squared distance), the point itself among them.
fn spfh_one(i: usize, nb: &[(usize, f32)], points: &[[f32; 3]], normals: &[[f32; 3]]) -> Fpfh {
    let mut h = [0f32; FPFH_BINS];
    let others = nb.iter().filter(|&&(j, _)| j != i).count();
    if others == 0 {
        return h;
    }
    let incr = 100.0 / others as f64;
    let (pi, ni) = (f64x3(&points[i]), f64x3(&normals[i]));
    let mut acc = [0f64; FPFH_BINS];
    for &(j, _) in nb {
        if j == i {
            continue;
        }
        let pf = pair_features(pi, ni, f64x3(&points[j]), f64x3(&normals[j]));
        for b in bins(&pf) {
            acc[b] += incr;
        }
    }
    for (o, a) in h.iter_mut().zip(acc) {
        *o = a as f32;
    }
    h
}

/// Combines SPFHs into the FPFH of point `i`.
fn fpfh_one(i: usize, nb: &[(usize, f32)], spfh: &[Fpfh]) -> Fpfh {
    let mut acc = [0f32; FPFH_BINS];
    for &(j, d2) in nb {
        if j == i || d2 == 0.0 {
            continue;
        }
        let w = 1.0 / d2;
        for (a, v) in acc.iter_mut().zip(spfh[j].iter()) {
            *a += v * w;
        }
    }
    let mut out = spfh[i];
    for blk in 0..3 {
        let r = blk * 11..blk * 11 + 11;
        let s: f32 = acc[r.clone()].iter().sum();
        if s != 0.0 {
            let scale = 100.0 / s;
            for b in r {
                out[b] += acc[b] * scale;
            }
        }
    }
    out
}

/// FPFH descriptors of every point. `normals` must be unit length and consistently oriented; `index` must
/// be built over `points`. Parallel over points; the result does not depend on the thread count.
pub fn compute_fpfh(
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    index: &KdIndex,
    cfg: &FpfhConfig,
) -> Vec<Fpfh> {
    let r = cfg.radius as f32;
    let neighbourhoods: Vec<Vec<(usize, f32)>> = points
        .par_iter()
        .map(|p| index.within(p, r, cfg.max_neighbors))
        .collect();
    let spfh: Vec<Fpfh> = neighbourhoods
        .par_iter()
        .enumerate()
        .map(|(i, nb)| spfh_one(i, nb, points, normals))
        .collect();
    neighbourhoods
        .par_iter()
        .enumerate()
        .map(|(i, nb)| fpfh_one(i, nb, &spfh))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;
    use crate::preprocess::normals::{estimate_normals, orient_toward_point, NormalConfig};

    /// A direct, unoptimised transcription of the definition, with brute-force neighbour search.
    fn brute_fpfh(
        points: &[[f32; 3]],
        normals: &[[f32; 3]],
        radius: f64,
        max_nn: usize,
    ) -> Vec<Fpfh> {
        let n = points.len();
        let nbrs = |i: usize| -> Vec<(usize, f64)> {
            let mut v: Vec<(usize, f64)> = (0..n)
                .map(|j| {
                    let d = sub(f64x3(&points[j]), f64x3(&points[i]));
                    // squared distance in f32 like the index, for identical tie-breaks
                    let d2 = (0..3)
                        .map(|k| (points[j][k] - points[i][k]).powi(2))
                        .sum::<f32>() as f64;
                    let _ = d;
                    (j, d2)
                })
                .filter(|&(_, d2)| d2 <= radius * radius)
                .collect();
            v.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            v.truncate(max_nn);
            v
        };
        let mut spfh = vec![[0f64; 33]; n];
        for i in 0..n {
            let nb = nbrs(i);
            let others: Vec<_> = nb.iter().filter(|x| x.0 != i).collect();
            for &&(j, _) in &others {
                let pf = pair_features(
                    f64x3(&points[i]),
                    f64x3(&normals[i]),
                    f64x3(&points[j]),
                    f64x3(&normals[j]),
                );
                let alpha = ((11.0 * (pf[0] + std::f64::consts::PI) / (2.0 * std::f64::consts::PI))
                    .floor() as i64)
                    .clamp(0, 10) as usize;
                let phi = ((11.0 * (pf[1] + 1.0) / 2.0).floor() as i64).clamp(0, 10) as usize;
                let theta = ((11.0 * (pf[2] + 1.0) / 2.0).floor() as i64).clamp(0, 10) as usize;
                spfh[i][alpha] += 100.0 / others.len() as f64;
                spfh[i][11 + phi] += 100.0 / others.len() as f64;
                spfh[i][22 + theta] += 100.0 / others.len() as f64;
            }
        }
        (0..n)
            .map(|i| {
                let mut h = [0f64; 33];
                for (j, d2) in nbrs(i) {
                    if j == i || d2 == 0.0 {
                        continue;
                    }
                    for b in 0..33 {
                        h[b] += spfh[j][b] / d2;
                    }
                }
                let mut out = [0f32; 33];
                for blk in 0..3 {
                    let s: f64 = h[blk * 11..blk * 11 + 11].iter().sum();
                    for b in blk * 11..blk * 11 + 11 {
                        let v = if s != 0.0 { h[b] * 100.0 / s } else { 0.0 };
                        out[b] = (v + spfh[i][b]) as f32;
                    }
                }
                out
            })
            .collect()
    }

    #[test]
    fn matches_brute_force_and_is_rigid_invariant() {
        let mut rng = Rng::new(9);
        // A bumpy surface: z = 0.1 sin(3x) cos(2y).
        let pts: Vec<[f32; 3]> = (0..1500)
            .map(|_| {
                let x = rng.uniform(-1.0, 1.0);
                let y = rng.uniform(-1.0, 1.0);
                [
                    x as f32,
                    y as f32,
                    (0.1 * (3.0 * x).sin() * (2.0 * y).cos()) as f32,
                ]
            })
            .collect();
        let idx = KdIndex::new(&pts);
        let mut ns = estimate_normals(&pts, &idx, &NormalConfig::default());
        orient_toward_point(&pts, &mut ns, [0.0, 0.0, 5.0]);
        let cfg = FpfhConfig {
            radius: 0.2,
            max_neighbors: 40,
        };
        let fast = compute_fpfh(&pts, &ns, &idx, &cfg);
        let slow = brute_fpfh(&pts, &ns, cfg.radius, cfg.max_neighbors);
        for (a, b) in fast.iter().zip(&slow) {
            for k in 0..33 {
                assert!((a[k] - b[k]).abs() < 1e-3, "{k}: {} vs {}", a[k], b[k]);
            }
            let sum: f32 = a.iter().sum();
            assert!(sum == 0.0 || (sum - 600.0).abs() < 0.1, "{sum}");
        }
        // Invariance: a rotated and translated copy gives the same descriptors (up to round-off).
        let t = crate::geometry::transform::random_isometry(&mut rng, 3.0, 2.0);
        let mut c = crate::PointCloud {
            points: pts.clone(),
            normals: Some(ns.clone()),
            colors: None,
        };
        c.transform(&t);
        let idx2 = KdIndex::new(&c.points);
        let moved = compute_fpfh(&c.points, c.normals.as_ref().unwrap(), &idx2, &cfg);
        let mut worst = 0f32;
        for (a, b) in fast.iter().zip(&moved) {
            let d: f32 = a
                .iter()
                .zip(b)
                .map(|(x, y)| (x - y).powi(2))
                .sum::<f32>()
                .sqrt();
            worst = worst.max(d);
        }
        let median_norm = 100.0;
        assert!(
            worst < 0.05 * median_norm,
            "worst descriptor change {worst}"
        );
    }
}
