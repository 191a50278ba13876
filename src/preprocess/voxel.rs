//! Voxel-grid downsampling: one point per occupied voxel, the centroid of the points inside it.
//!
//! Output points are in Morton (Z-order) order of their voxels, so that points close in space are close
//! in memory; nearest-neighbour queries issued in that order are markedly faster.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use rayon::prelude::*;

/// Interleaves the low 21 bits of x, y, z into a 63-bit Morton code.
#[inline]
pub fn morton3(x: u32, y: u32, z: u32) -> u64 {
    #[inline]
    fn split(v: u32) -> u64 {
        let mut x = (v as u64) & 0x1f_ffff;
        x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
        x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
        x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
        x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
        x = (x | (x << 2)) & 0x1249_2492_4924_9249;
        x
    }
    split(x) | (split(y) << 1) | (split(z) << 2)
}

/// Largest number of voxels along one axis (21 bits of Morton code per axis).
const MAX_CELLS: f64 = (1u64 << 21) as f64 - 1.0;

/// Morton keys of each point for voxel size `voxel`, with the grid anchored at the cloud's minimum corner.
pub(crate) fn voxel_keys(points: &[[f32; 3]], voxel: f64) -> Result<Vec<u64>> {
    if !(voxel > 0.0 && voxel.is_finite()) {
        return Err(Error::Config {
            field: "voxel".into(),
            msg: format!("must be a positive length, got {voxel}"),
        });
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    for k in 0..3 {
        if (hi[k] - lo[k]) / voxel > MAX_CELLS {
            return Err(Error::Config {
                field: "voxel".into(),
                msg: format!(
                    "{voxel} is too small for a cloud {:.3} wide (more than 2^21 voxels per axis)",
                    hi[k] - lo[k]
                ),
            });
        }
    }
    let inv = 1.0 / voxel;
    Ok(points
        .par_iter()
        .map(|p| {
            let c = |k: usize| ((p[k] as f64 - lo[k]) * inv).floor() as u32;
            morton3(c(0), c(1), c(2))
        })
        .collect())
}

/// Downsamples to one point per occupied voxel of edge `voxel` (cloud units): the centroid of its points,
/// the normalised mean of their normals, the mean of their colours. Non-finite points must be removed first.
pub fn voxel_downsample(cloud: &PointCloud, voxel: f64) -> Result<PointCloud> {
    Ok(voxel_downsample_with_counts(cloud, voxel)?.0)
}

/// As [`voxel_downsample`], also returning how many input points each output point averages.
pub fn voxel_downsample_with_counts(
    cloud: &PointCloud,
    voxel: f64,
) -> Result<(PointCloud, Vec<u32>)> {
    if cloud.is_empty() {
        return Ok((PointCloud::default(), Vec::new()));
    }
    let keys = voxel_keys(&cloud.points, voxel)?;
    // Sort (key, index) pairs: contiguous memory, ties broken by index (deterministic).
    let mut pairs: Vec<(u64, u32)> = keys
        .iter()
        .enumerate()
        .map(|(i, &k)| (k, i as u32))
        .collect();
    pairs.par_sort_unstable();
    let order: Vec<u32> = pairs.iter().map(|p| p.1).collect();
    // Run boundaries.
    let mut starts = Vec::with_capacity(cloud.len() / 4 + 1);
    for (j, w) in pairs.iter().enumerate() {
        if j == 0 || w.0 != pairs[j - 1].0 {
            starts.push(j);
        }
    }
    starts.push(order.len());
    let runs: Vec<(usize, usize)> = starts.windows(2).map(|w| (w[0], w[1])).collect();
    let points: Vec<[f32; 3]> = runs
        .par_iter()
        .map(|&(a, b)| {
            let mut s = [0f64; 3];
            for &i in &order[a..b] {
                let p = cloud.points[i as usize];
                for k in 0..3 {
                    s[k] += p[k] as f64;
                }
            }
            let n = (b - a) as f64;
            [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
        })
        .collect();
    let normals = cloud.normals.as_ref().map(|ns| {
        runs.par_iter()
            .map(|&(a, b)| {
                let mut s = [0f64; 3];
                for &i in &order[a..b] {
                    let p = ns[i as usize];
                    for k in 0..3 {
                        s[k] += p[k] as f64;
                    }
                }
                let n = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt().max(1e-30);
                [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
            })
            .collect()
    });
    let colors = cloud.colors.as_ref().map(|cs| {
        runs.par_iter()
            .map(|&(a, b)| {
                let mut s = [0u64; 3];
                for &i in &order[a..b] {
                    for k in 0..3 {
                        s[k] += cs[i as usize][k] as u64;
                    }
                }
                let n = (b - a) as u64;
                [
                    ((s[0] + n / 2) / n) as u8,
                    ((s[1] + n / 2) / n) as u8,
                    ((s[2] + n / 2) / n) as u8,
                ]
            })
            .collect()
    });
    let counts = runs.iter().map(|&(a, b)| (b - a) as u32).collect();
    Ok((
        PointCloud {
            points,
            normals,
            colors,
        },
        counts,
    ))
}

/// Number of occupied voxels of edge `voxel` among `points` (for choosing a voxel size).
pub fn count_voxels(points: &[[f32; 3]], voxel: f64) -> Result<usize> {
    let mut keys = voxel_keys(points, voxel)?;
    keys.par_sort_unstable();
    keys.dedup();
    Ok(keys.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;
    use std::collections::HashMap;

    #[test]
    fn morton_interleaves() {
        assert_eq!(morton3(1, 0, 0), 1);
        assert_eq!(morton3(0, 1, 0), 2);
        assert_eq!(morton3(0, 0, 1), 4);
        assert_eq!(morton3(3, 0, 0), 0b1001);
    }

    /// Against a HashMap oracle: same voxels, same centroids.
    #[test]
    fn centroids_match_oracle() {
        let mut rng = Rng::new(1);
        let pts: Vec<[f32; 3]> = (0..20_000)
            .map(|_| {
                [
                    rng.uniform(-2.0, 2.0) as f32,
                    rng.uniform(0.0, 1.0) as f32,
                    rng.uniform(5.0, 6.0) as f32,
                ]
            })
            .collect();
        let cloud = PointCloud::from_points(pts.clone());
        let v = 0.1;
        let (out, counts) = voxel_downsample_with_counts(&cloud, v).unwrap();
        let lo = cloud.bounds().unwrap().0;
        let mut map: HashMap<[i64; 3], ([f64; 3], u32)> = HashMap::new();
        for p in &pts {
            let k = [0, 1, 2].map(|a| ((p[a] as f64 - lo[a] as f64) / v).floor() as i64);
            let e = map.entry(k).or_insert(([0.0; 3], 0));
            for (acc, c) in e.0.iter_mut().zip(p) {
                *acc += *c as f64;
            }
            e.1 += 1;
        }
        assert_eq!(out.len(), map.len());
        assert_eq!(counts.iter().sum::<u32>() as usize, pts.len());
        for (p, c) in out.points.iter().zip(&counts) {
            let k = [0, 1, 2].map(|a| {
                // A centroid lies inside its voxel.
                ((p[a] as f64 - lo[a] as f64) / v).floor() as i64
            });
            let (s, n) = map[&k];
            assert_eq!(n, *c);
            for a in 0..3 {
                assert!((s[a] / n as f64 - p[a] as f64).abs() < 1e-5);
            }
        }
        assert!(voxel_downsample(&cloud, 0.0).is_err());
        assert!(voxel_downsample(&cloud, 1e-9).is_err());
    }
}
