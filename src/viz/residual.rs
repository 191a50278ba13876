//! The residual of one surface against another: per point, its distance to the plane fitted to the other
//! cloud's nearest points (point-to-plane), with a histogram and summary statistics.
//!
//! Nearest neighbours come from the library's kd-tree ([`crate::index::KdIndex`]). A point whose nearest
//! neighbour on the other surface is farther than the reach has no counterpart there (the clouds do not
//! overlap at that point): its residual is NaN, it is drawn grey and left out of the histogram.

use crate::geometry::plane::fit_plane;
use crate::index::KdIndex;
use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;
use serde::Serialize;

/// Neighbours of the other surface a point's local plane is fitted to.
const NEIGHBOURS: usize = 8;

/// Point-to-plane residuals of `points` (mapped by `t` into the frame of `reference`) against the surface
/// `reference` samples, in `reference`'s units times `scale` (e.g. 1000: metres to millimetres). NaN where
/// the nearest reference point is farther than `reach` (reference units). Fewer than 3 neighbours within
/// reach, or neighbours on a line, give the distance to the nearest one. Deterministic at any thread count.
pub fn point_to_plane(
    points: &[[f32; 3]],
    t: &Isometry3<f64>,
    reference: &[[f32; 3]],
    index: &KdIndex,
    reach: f64,
    scale: f64,
) -> Vec<f32> {
    points
        .par_iter()
        .map(|p| {
            let q = t * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let qf = [q.x as f32, q.y as f32, q.z as f32];
            let near = index.within(&qf, reach as f32, NEIGHBOURS);
            let Some(&(_, d2)) = near.first() else {
                return f32::NAN;
            };
            let around: Vec<Point3<f64>> = near
                .iter()
                .map(|&(j, _)| {
                    let r = reference[j];
                    Point3::new(r[0] as f64, r[1] as f64, r[2] as f64)
                })
                .collect();
            let d = match fit_plane(&around) {
                Some(plane) => plane.distance(&q).abs(),
                None => (d2 as f64).sqrt(),
            };
            (d * scale) as f32
        })
        .collect()
}

/// A histogram of residuals over `[0, max]` in equal bins, with what falls beyond.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Histogram {
    /// Upper end of the last bin (display units).
    pub max: f64,
    /// Counts per bin.
    pub bins: Vec<usize>,
    /// Residuals above `max`.
    pub above: usize,
    /// Points without a counterpart (NaN residuals).
    pub unmatched: usize,
}

impl Histogram {
    /// Bins `values` (NaN counted as unmatched).
    pub fn new(values: &[f32], max: f64, bins: usize) -> Self {
        let mut h = Histogram {
            max,
            bins: vec![0; bins.max(1)],
            above: 0,
            unmatched: 0,
        };
        let n = h.bins.len();
        for &v in values {
            if v.is_nan() {
                h.unmatched += 1;
            } else if (v as f64) > max {
                h.above += 1;
            } else {
                let k = ((v as f64 / max) * n as f64).floor() as usize;
                h.bins[k.min(n - 1)] += 1;
            }
        }
        h
    }
}

/// Summary statistics of residuals (display units).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ResidualStats {
    /// Points with a counterpart.
    pub matched: usize,
    /// Points without one.
    pub unmatched: usize,
    /// Median of the matched residuals.
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Root mean square.
    pub rms: f64,
}

impl ResidualStats {
    /// The statistics of `values` (NaN: unmatched); zeros when nothing matched.
    pub fn new(values: &[f32]) -> Self {
        let mut v: Vec<f64> = values
            .iter()
            .filter(|x| !x.is_nan())
            .map(|&x| x as f64)
            .collect();
        v.sort_by(f64::total_cmp);
        let q = |f: f64| {
            if v.is_empty() {
                0.0
            } else {
                v[((f * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)]
            }
        };
        let rms = if v.is_empty() {
            0.0
        } else {
            (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
        };
        ResidualStats {
            matched: v.len(),
            unmatched: values.len() - v.len(),
            median: q(0.5),
            p90: q(0.9),
            p95: q(0.95),
            rms,
        }
    }
}

/// The smallest of 1, 2 or 5 times a power of ten that is at least `x` (1 for non-positive or non-finite
/// `x`): the upper end of a colour scale.
pub fn nice_ceiling(x: f64) -> f64 {
    if !(x > 0.0 && x.is_finite()) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&v| v >= x * (1.0 - 1e-12))
        .unwrap_or(10.0 * p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_to_plane_against_a_known_plane() {
        // A grid on z = 0 with 1 cm spacing; points at heights 0, 2 mm and 5 mm above it, and one far away.
        let grid: Vec<[f32; 3]> = (0..50)
            .flat_map(|i| (0..50).map(move |j| [i as f32 * 0.01, j as f32 * 0.01, 0.0]))
            .collect();
        let idx = KdIndex::new(&grid);
        let q = [
            [0.105, 0.203, 0.0],
            [0.2, 0.2, 0.002],
            [0.3, 0.1, 0.005],
            [3.0, 3.0, 0.0],
        ];
        // Moved by a translation that the residual must undo: the points are given 1 m lower.
        let lowered: Vec<[f32; 3]> = q.iter().map(|p| [p[0], p[1], p[2] - 1.0]).collect();
        let t = Isometry3::translation(0.0, 0.0, 1.0);
        let r = point_to_plane(&lowered, &t, &grid, &idx, 0.03, 1e3);
        assert!(r[0].abs() < 1e-3, "{r:?}");
        assert!((r[1] - 2.0).abs() < 1e-3, "{r:?}");
        assert!((r[2] - 5.0).abs() < 1e-3, "{r:?}");
        assert!(r[3].is_nan());
    }

    #[test]
    fn histogram_and_statistics() {
        let v = [0.1f32, 0.6, 0.6, 1.9, 2.5, f32::NAN];
        let h = Histogram::new(&v, 2.0, 4);
        assert_eq!(h.bins, vec![1, 2, 0, 1]);
        assert_eq!((h.above, h.unmatched), (1, 1));
        let s = ResidualStats::new(&v);
        assert_eq!((s.matched, s.unmatched), (5, 1));
        assert_eq!(s.median, 0.6f32 as f64);
        assert_eq!(nice_ceiling(0.37), 0.5);
        assert_eq!(nice_ceiling(2.0), 2.0);
        assert_eq!(nice_ceiling(7.1), 10.0);
        assert_eq!(nice_ceiling(0.0), 1.0);
    }
}
