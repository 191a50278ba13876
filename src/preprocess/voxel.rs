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
    // The box, in parallel (min and max are exact: the same at any thread count).
    let (lo, hi) = points
        .par_iter()
        .fold(
            || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(mut lo, mut hi), p| {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k] as f64);
                    hi[k] = hi[k].max(p[k] as f64);
                }
                (lo, hi)
            },
        )
        .reduce(
            || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |a, b| {
                (
                    std::array::from_fn(|k| a.0[k].min(b.0[k])),
                    std::array::from_fn(|k| a.1[k].max(b.1[k])),
                )
            },
        );
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
            // `p[k] - lo[k]` is never negative (`lo` is the minimum of the same values), so truncation
            // is the floor: no `floor` call (a libm call on the baseline x86-64 target, without SSE4.1).
            let c = |k: usize| ((p[k] as f64 - lo[k]) * inv) as u32;
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
///
/// The points are aggregated by hashing their voxel keys, in [`PARTS`] partitions of the voxels (by the
/// high bits of the key's hash) processed in parallel, each reading its points contiguously (chunks of
/// points are first split into per-partition buckets); within a voxel the points are summed in increasing
/// index order, in `f64`, so the centroids do not depend on the thread count. Only the occupied voxels'
/// keys are then sorted (Morton order), not every point's: 2-3x faster than sorting all `(key, index)`
/// pairs, with the same output bit for bit.
pub fn voxel_downsample_with_counts(
    cloud: &PointCloud,
    voxel: f64,
) -> Result<(PointCloud, Vec<u32>)> {
    if cloud.is_empty() {
        return Ok((PointCloud::default(), Vec::new()));
    }
    let keys = voxel_keys(&cloud.points, voxel)?;
    // Each chunk of consecutive points is split into per-partition buckets (points in index order), so
    // that each partition then reads its points contiguously, chunk after chunk: in index order.
    let (normals, colors) = (cloud.normals.as_deref(), cloud.colors.as_deref());
    let buckets: Vec<Vec<Bucket>> = keys
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(c, ks)| {
            let mut sizes = [0usize; PARTS];
            for &k in ks {
                sizes[key_part(k)] += 1;
            }
            let mut out: Vec<Bucket> = sizes
                .iter()
                .map(|&n| Bucket {
                    keys: Vec::with_capacity(n),
                    points: Vec::with_capacity(n),
                    normals: Vec::with_capacity(if normals.is_some() { n } else { 0 }),
                    colors: Vec::with_capacity(if colors.is_some() { n } else { 0 }),
                })
                .collect();
            let base = c * CHUNK;
            for (j, &k) in ks.iter().enumerate() {
                let (i, b) = (base + j, &mut out[key_part(k)]);
                b.keys.push(k);
                b.points.push(cloud.points[i]);
                if let Some(ns) = normals {
                    b.normals.push(ns[i]);
                }
                if let Some(cs) = colors {
                    b.colors.push(cs[i]);
                }
            }
            out
        })
        .collect();
    drop(keys);
    let parts: Vec<PartSums> = (0..PARTS)
        .into_par_iter()
        .map(|p| {
            let n: usize = buckets.iter().map(|b| b[p].keys.len()).sum();
            let mut map = KeySlots::with_capacity(n / 4);
            let mut s = PartSums::default();
            for b in buckets.iter().map(|b| &b[p]) {
                for (j, &key) in b.keys.iter().enumerate() {
                    let (slot, new) = map.slot(key);
                    if new {
                        s.keys.push(key);
                        s.counts.push(0);
                        s.points.push([0.0; 3]);
                        if normals.is_some() {
                            s.normals.push([0.0; 3]);
                        }
                        if colors.is_some() {
                            s.colors.push([0; 3]);
                        }
                    }
                    s.counts[slot] += 1;
                    let (q, acc) = (b.points[j], &mut s.points[slot]);
                    for k in 0..3 {
                        acc[k] += q[k] as f64;
                    }
                    if normals.is_some() {
                        let (q, acc) = (b.normals[j], &mut s.normals[slot]);
                        for k in 0..3 {
                            acc[k] += q[k] as f64;
                        }
                    }
                    if colors.is_some() {
                        let (q, acc) = (b.colors[j], &mut s.colors[slot]);
                        for k in 0..3 {
                            acc[k] += q[k] as u64;
                        }
                    }
                }
            }
            s
        })
        .collect();
    drop(buckets);
    // The occupied voxels in Morton order: (key, partition, slot); keys are unique.
    let mut order: Vec<(u64, u32, u32)> =
        Vec::with_capacity(parts.iter().map(|s| s.keys.len()).sum());
    for (p, s) in parts.iter().enumerate() {
        order.extend(
            s.keys
                .iter()
                .enumerate()
                .map(|(j, &k)| (k, p as u32, j as u32)),
        );
    }
    order.par_sort_unstable_by_key(|o| o.0);
    let counts: Vec<u32> = order
        .iter()
        .map(|&(_, p, j)| parts[p as usize].counts[j as usize])
        .collect();
    let points: Vec<[f32; 3]> = order
        .par_iter()
        .map(|&(_, p, j)| {
            let (s, n) = (&parts[p as usize], j as usize);
            let (v, c) = (s.points[n], s.counts[n] as f64);
            [(v[0] / c) as f32, (v[1] / c) as f32, (v[2] / c) as f32]
        })
        .collect();
    let normals = normals.map(|_| {
        order
            .par_iter()
            .map(|&(_, p, j)| {
                let s = parts[p as usize].normals[j as usize];
                let n = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt().max(1e-30);
                [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
            })
            .collect()
    });
    let colors = colors.map(|_| {
        order
            .par_iter()
            .map(|&(_, p, j)| {
                let (s, n) = (&parts[p as usize], j as usize);
                let (v, c) = (s.colors[n], s.counts[n] as u64);
                [
                    ((v[0] + c / 2) / c) as u8,
                    ((v[1] + c / 2) / c) as u8,
                    ((v[2] + c / 2) / c) as u8,
                ]
            })
            .collect()
    });
    Ok((
        PointCloud {
            points,
            normals,
            colors,
        },
        counts,
    ))
}

/// Partitions of the hashed voxel grid (a power of two): each voxel belongs to one, chosen by the high
/// bits of its key's hash, and the partitions are aggregated in parallel. Fixed, so that the result does
/// not depend on the thread count.
const PARTS: usize = 64;

/// Points per chunk of the bucketing pass (fixed, so the result does not depend on the thread count).
const CHUNK: usize = 1 << 16;

/// One chunk's points of one partition, in index order.
struct Bucket {
    keys: Vec<u64>,
    points: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    colors: Vec<[u8; 3]>,
}

/// Multiplicative hash of a Morton key (Fibonacci hashing).
#[inline]
fn key_hash(key: u64) -> u64 {
    key.wrapping_mul(0x9E37_79B9_7F4A_7C15)
}

/// The partition of a key: the top 6 bits of its hash.
#[inline]
fn key_part(key: u64) -> usize {
    (key_hash(key) >> 58) as usize
}

/// An open-addressing map from voxel keys to slots `0..len`, in order of first insertion.
struct KeySlots {
    keys: Vec<u64>,
    slots: Vec<u32>,
    len: usize,
}

/// The empty marker of [`KeySlots`] (Morton keys use 63 bits, so no key equals it).
const NO_KEY: u64 = u64::MAX;

impl KeySlots {
    fn with_capacity(n: usize) -> Self {
        let cap = (2 * n).next_power_of_two().max(64);
        KeySlots {
            keys: vec![NO_KEY; cap],
            slots: vec![0; cap],
            len: 0,
        }
    }

    /// The slot of `key`, inserting it (with the next slot number) when new: `(slot, inserted)`.
    #[inline]
    fn slot(&mut self, key: u64) -> (usize, bool) {
        if 2 * (self.len + 1) > self.keys.len() {
            self.grow();
        }
        let mask = self.keys.len() - 1;
        // The low bits of the hash (the high ones chose the partition).
        let mut h = (key_hash(key) as usize) & mask;
        loop {
            let k = self.keys[h];
            if k == key {
                return (self.slots[h] as usize, false);
            }
            if k == NO_KEY {
                self.keys[h] = key;
                self.slots[h] = self.len as u32;
                self.len += 1;
                return (self.len - 1, true);
            }
            h = (h + 1) & mask;
        }
    }

    fn grow(&mut self) {
        let old_keys = std::mem::take(&mut self.keys);
        let old_slots = std::mem::take(&mut self.slots);
        let cap = 2 * old_keys.len();
        self.keys = vec![NO_KEY; cap];
        self.slots = vec![0; cap];
        let mask = cap - 1;
        for (k, s) in old_keys.into_iter().zip(old_slots) {
            if k != NO_KEY {
                let mut h = (key_hash(k) as usize) & mask;
                while self.keys[h] != NO_KEY {
                    h = (h + 1) & mask;
                }
                self.keys[h] = k;
                self.slots[h] = s;
            }
        }
    }
}

/// One partition's voxels: their keys, point counts and the f64 sums of their points (normals, colours),
/// each sum taken over the voxel's points in increasing index order.
#[derive(Default)]
struct PartSums {
    keys: Vec<u64>,
    counts: Vec<u32>,
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    colors: Vec<[u64; 3]>,
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

    /// The sort-based downsampling this module used before the hashed partitions, kept as an oracle.
    fn sorted_downsample(cloud: &PointCloud, voxel: f64) -> Result<(PointCloud, Vec<u32>)> {
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

    /// The hashed partitions give the sort-based result bit for bit: points, normals, colours, counts,
    /// order, on a cloud with many voxels of many points and many of one.
    #[test]
    fn hashed_partitions_equal_the_sorted_pairs() {
        let mut rng = Rng::new(3);
        let n = 60_000;
        let pts: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let s = if i % 3 == 0 { 10.0 } else { 1.0 };
                [
                    (s * rng.uniform(-1.0, 1.0)) as f32,
                    rng.uniform(0.0, 0.5) as f32,
                    rng.uniform(2.0, 2.2) as f32,
                ]
            })
            .collect();
        let normals: Vec<[f32; 3]> = (0..n)
            .map(|_| [rng.normal() as f32, rng.normal() as f32, 1.0])
            .collect();
        let colors: Vec<[u8; 3]> = (0..n)
            .map(|i| [(i % 251) as u8, (i % 13) as u8, 200])
            .collect();
        let cloud = PointCloud {
            points: pts,
            normals: Some(normals),
            colors: Some(colors),
        };
        for v in [0.004, 0.03, 0.2, 5.0] {
            let (a, ca) = voxel_downsample_with_counts(&cloud, v).unwrap();
            let (b, cb) = sorted_downsample(&cloud, v).unwrap();
            assert!(a.len() > 1 || v == 5.0, "voxel {v}: {} points", a.len());
            assert_eq!(ca, cb, "voxel {v}");
            assert_eq!(a.points, b.points, "voxel {v}");
            assert_eq!(a.normals, b.normals, "voxel {v}");
            assert_eq!(a.colors, b.colors, "voxel {v}");
        }
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
