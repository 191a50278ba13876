//! Automatic scale: point spacing and the voxel size that every radius is derived from.
//!
//! depthcal never assumes a unit. It measures the cloud (median nearest-neighbour spacing, extent) and picks
//! the voxel size that leaves about [`ScaleConfig::target_points`] points, so that a millimetre cloud and a
//! metre cloud, an RGB-D fragment and a LiDAR scan all get sensible parameters with no flags.

use crate::error::{Error, Result};
use crate::index::KdIndex;
use crate::preprocess::voxel::count_voxels;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of the automatic voxel choice.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScaleConfig {
    /// Number of points the global-registration voxel grid should leave in each cloud (default 5000).
    pub target_points: usize,
    /// Smallest voxel, as a multiple of the point spacing (default 1.5).
    pub min_voxel_per_spacing: f64,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        ScaleConfig {
            target_points: 5000,
            min_voxel_per_spacing: 1.5,
        }
    }
}

impl ScaleConfig {
    /// Checks the ranges; the error names the field (`scale.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        check::at_least("scale.target_points", self.target_points, 1)?;
        check::positive("scale.min_voxel_per_spacing", self.min_voxel_per_spacing)
    }
}

/// Median distance from a point to its nearest neighbour (cloud units).
///
/// For large clouds the kd-tree is built only over a spatially contiguous box of about 20 000 points
/// around the cloud point nearest the per-axis median (full density, unlike a strided sample), and the
/// median is taken over up to 2000 points of the inner part of that box. The box is centred on a point of
/// the cloud, not on the median itself: the median of a hollow cloud (a sphere, two walls) lies in empty
/// space, where a box would hold no points.
pub fn estimate_spacing(points: &[[f32; 3]]) -> Result<f64> {
    if points.len() < 2 {
        return Err(Error::InvalidInput(format!(
            "a cloud needs at least 2 points to measure its spacing, this one has {}",
            points.len()
        )));
    }
    const LOCAL: usize = 20_000;
    let (sample, center, half) = if points.len() <= 2 * LOCAL {
        (points.to_vec(), [0f32; 3], f32::INFINITY)
    } else {
        let center = nearest_point(points, &median_point(points));
        let extent =
            crate::PointCloud::from_points(points.iter().step_by(16).copied().collect()).extent();
        let mut half = (0.5 * extent * (LOCAL as f64 / points.len() as f64).sqrt()) as f32;
        let inside = |h: f32| {
            points
                .par_iter()
                .filter(|p| (0..3).all(|k| (p[k] - center[k]).abs() <= h))
                .count()
        };
        for _ in 0..4 {
            let n = inside(half).max(1);
            if (LOCAL / 2..=LOCAL * 2).contains(&n) {
                break;
            }
            half *= (LOCAL as f32 / n as f32).sqrt().clamp(0.25, 4.0);
        }
        // An indexed parallel filter keeps the points' order: the same sample at any thread count.
        let local: Vec<[f32; 3]> = points
            .par_iter()
            .filter(|p| (0..3).all(|k| (p[k] - center[k]).abs() <= half))
            .copied()
            .collect();
        (local, center, half)
    };
    let index = KdIndex::new(&sample);
    let inner = 0.7 * half;
    let candidates: Vec<&[f32; 3]> = sample
        .iter()
        .filter(|p| (0..3).all(|k| (p[k] - center[k]).abs() <= inner))
        .collect();
    let step = (candidates.len() / 2000).max(1);
    let mut d: Vec<f32> = candidates
        .iter()
        .step_by(step)
        .filter_map(|p| index.knn(p, 2).get(1).map(|h| h.1.sqrt()))
        .filter(|d| *d > 0.0)
        .collect();
    if d.is_empty() {
        return Err(Error::InvalidInput(
            "all points coincide: the cloud has no extent".into(),
        ));
    }
    let mid = d.len() / 2;
    d.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Ok(d[mid] as f64)
}

/// The per-axis median of a strided sample of the points.
fn median_point(points: &[[f32; 3]]) -> [f32; 3] {
    let step = (points.len() / 5000).max(1);
    let mut out = [0f32; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let mut v: Vec<f32> = points.iter().step_by(step).map(|p| p[k]).collect();
        let mid = v.len() / 2;
        v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        *o = v[mid];
    }
    out
}

/// The point of `points` nearest `q` (ties to the smaller index); `points` is not empty. In parallel; the
/// smallest (distance, index) is the same at any thread count.
fn nearest_point(points: &[[f32; 3]], q: &[f32; 3]) -> [f32; 3] {
    let d2 = |p: &[f32; 3]| (0..3).map(|k| (p[k] - q[k]) * (p[k] - q[k])).sum::<f32>();
    let (_, i) = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| (d2(p), i))
        .reduce(
            || (f32::INFINITY, usize::MAX),
            |a, b| {
                if b.0 < a.0 || (b.0 == a.0 && b.1 < a.1) {
                    b
                } else {
                    a
                }
            },
        );
    points[i.min(points.len() - 1)]
}

/// The voxel edge that leaves about `target` occupied voxels in `points`, never below `min_voxel`.
///
/// Works on a strided sample of at most 30 000 points and refines a power-law guess (occupied voxels scale
/// like `voxel^-d` with `d` measured on the fly) in a few passes, then corrects it with one exact count on
/// the whole cloud.
pub fn voxel_for_target(points: &[[f32; 3]], target: usize, min_voxel: f64) -> Result<f64> {
    let step = (points.len() / 30_000).max(1);
    let sample: Vec<[f32; 3]> = points.iter().step_by(step).copied().collect();
    let target = target.max(10);
    if sample.len() <= target {
        return Ok(min_voxel);
    }
    let cloud = crate::PointCloud::from_points(sample);
    let extent = cloud.extent().max(min_voxel);
    // Initial guess: a surface of the cloud's extent.
    let mut v = (extent / (target as f64).sqrt()).max(min_voxel);
    let mut n = count_voxels(&cloud.points, v)? as f64;
    let mut dim = 2.0f64;
    for _ in 0..6 {
        let ratio = n / target as f64;
        if (ratio - 1.0).abs() < 0.1 {
            break;
        }
        let v_new = (v * ratio.powf(1.0 / dim)).max(min_voxel);
        if v_new == v {
            break;
        }
        let n_new = count_voxels(&cloud.points, v_new)? as f64;
        let slope = (n_new.ln() - n.ln()) / (v_new.ln() - v.ln());
        if slope.is_finite() && slope < -0.5 {
            dim = (-slope).clamp(0.5, 3.0);
        }
        v = v_new;
        n = n_new;
    }
    // The sample sees fewer occupied voxels than the full cloud where voxels hold few points (sparse
    // LiDAR): one exact count on the full cloud corrects the estimate.
    if step > 1 {
        let n_full = count_voxels(points, v)? as f64;
        v = (v * (n_full / target as f64).powf(1.0 / dim)).max(min_voxel);
    }
    Ok(v.max(min_voxel))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    #[test]
    fn spacing_and_voxel_on_a_grid() {
        // A 200 x 200 grid of spacing 0.01 on a plane: spacing 0.01; 2500 voxels ≈ 0.04 edge.
        let mut pts = Vec::new();
        for i in 0..200 {
            for j in 0..200 {
                pts.push([i as f32 * 0.01, j as f32 * 0.01, 0.0]);
            }
        }
        let s = estimate_spacing(&pts).unwrap();
        // A large cloud takes the local-box path: same answer.
        let mut big = Vec::new();
        for i in 0..300 {
            for j in 0..300 {
                big.push([i as f32 * 0.01, j as f32 * 0.01, 0.0]);
            }
        }
        let sb = estimate_spacing(&big).unwrap();
        assert!((sb - 0.01).abs() < 1e-4, "{sb}");
        assert!((s - 0.01).abs() < 1e-4, "{s}");
        let v = voxel_for_target(&pts, 2500, 0.015).unwrap();
        let n = count_voxels(&pts, v).unwrap();
        assert!((2000..3100).contains(&n), "voxel {v} leaves {n}");
        // The same cloud in millimetres gives a 1000x voxel.
        let mm: Vec<[f32; 3]> = pts.iter().map(|p| p.map(|c| c * 1000.0)).collect();
        let vmm = voxel_for_target(&mm, 2500, 15.0).unwrap();
        assert!((vmm / v / 1000.0 - 1.0).abs() < 0.02, "{vmm} {v}");
        let mut rng = Rng::new(0);
        let one = vec![[rng.uniform(0.0, 1.0) as f32; 3]];
        assert!(estimate_spacing(&one).is_err());
    }

    /// A hollow cloud: 100 000 points on a unit sphere. Its per-axis median is the centre, where a box
    /// around the median holds no point; the estimate must still find the spacing on the surface.
    #[test]
    fn spacing_of_a_hollow_cloud() {
        // A Fibonacci sphere: near-uniform spacing sqrt(4π / n) ≈ 0.0112 (nearest neighbour ≈ 0.011).
        let n = 100_000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let pts: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = golden * i as f64;
                [(r * a.cos()) as f32, (r * a.sin()) as f32, z as f32]
            })
            .collect();
        let m = median_point(&pts);
        assert!(m.iter().all(|c| c.abs() < 0.05), "{m:?}");
        let s = estimate_spacing(&pts).unwrap();
        let want = (4.0 * std::f64::consts::PI / n as f64).sqrt();
        assert!(s > 0.7 * want && s < 1.3 * want, "{s} vs {want}");
    }
}
