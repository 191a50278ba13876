//! Statistical outlier removal (as PCL's `StatisticalOutlierRemoval` and Open3D's
//! `remove_statistical_outlier`).
//!
//! For every point the mean distance to its `k` nearest neighbours is computed; points whose mean distance
//! exceeds `μ + std_ratio·σ` (mean and standard deviation over the whole cloud) are outliers. Deterministic:
//! the statistics are summed in point order whatever the thread count.

use crate::error::{Error, Result};
use crate::index::KdIndex;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Statistical outlier removal settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutlierConfig {
    /// Number of neighbours whose mean distance is measured (default 20).
    pub k: usize,
    /// Threshold in standard deviations above the mean of the mean distances (default 2.0). Smaller removes
    /// more.
    pub std_ratio: f64,
}

impl Default for OutlierConfig {
    fn default() -> Self {
        OutlierConfig {
            k: 20,
            std_ratio: 2.0,
        }
    }
}

impl OutlierConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        if self.k == 0 {
            return Err(Error::Config {
                field: "outlier.k".into(),
                msg: "must be at least 1".into(),
            });
        }
        if !(self.std_ratio.is_finite() && self.std_ratio > 0.0) {
            return Err(Error::Config {
                field: "outlier.std_ratio".into(),
                msg: format!("must be a positive number, found {}", self.std_ratio),
            });
        }
        Ok(())
    }
}

/// The indices (ascending) of the points that are *not* statistical outliers.
///
/// `index` must be built over `points`. Clouds with at most `k` points are returned unchanged.
pub fn statistical_inliers(
    points: &[[f32; 3]],
    index: &KdIndex,
    cfg: &OutlierConfig,
) -> Result<Vec<usize>> {
    cfg.validate()?;
    let n = points.len();
    if n <= cfg.k {
        return Ok((0..n).collect());
    }
    // k + 1 because the query point itself is among its nearest neighbours.
    let mean_dist: Vec<f64> = points
        .par_iter()
        .map_init(Vec::new, |nn, p| {
            index.knn_into(p, cfg.k + 1, nn);
            let s: f64 = nn.iter().skip(1).map(|&(_, d2)| (d2 as f64).sqrt()).sum();
            s / (nn.len().saturating_sub(1)).max(1) as f64
        })
        .collect();
    let mean = mean_dist.iter().sum::<f64>() / n as f64;
    let var = mean_dist
        .iter()
        .map(|d| (d - mean) * (d - mean))
        .sum::<f64>()
        / (n - 1) as f64;
    let limit = mean + cfg.std_ratio * var.sqrt();
    Ok((0..n).filter(|&i| mean_dist[i] <= limit).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    #[test]
    fn removes_isolated_points_and_keeps_the_surface() {
        let mut rng = Rng::new(1);
        let mut pts: Vec<[f32; 3]> = Vec::new();
        for i in 0..60 {
            for j in 0..60 {
                pts.push([
                    i as f32 * 0.01,
                    j as f32 * 0.01,
                    (rng.normal() * 0.0005) as f32,
                ]);
            }
        }
        let n_surface = pts.len();
        for _ in 0..30 {
            pts.push([
                rng.uniform(0.0, 0.6) as f32,
                rng.uniform(0.0, 0.6) as f32,
                rng.uniform(0.1, 0.5) as f32,
            ]);
        }
        let idx = KdIndex::new(&pts);
        let keep = statistical_inliers(&pts, &idx, &OutlierConfig::default()).unwrap();
        let removed_outliers = (n_surface..pts.len())
            .filter(|i| keep.binary_search(i).is_err())
            .count();
        let removed_surface = (0..n_surface)
            .filter(|i| keep.binary_search(i).is_err())
            .count();
        assert_eq!(removed_outliers, 30);
        assert!(removed_surface < n_surface / 50, "{removed_surface}");
        assert!(statistical_inliers(
            &pts,
            &idx,
            &OutlierConfig {
                k: 0,
                std_ratio: 1.0
            }
        )
        .is_err());
    }
}
