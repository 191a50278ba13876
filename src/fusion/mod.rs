//! Fusion of a robot's depth frames into one cloud in the robot's base frame.
//!
//! For each frame, `T_base_cam = T_base_ee · T_ee_cam`; the depth image is deprojected (see
//! [`crate::camera::deproject`]), moved into the base frame, cropped to an optional workspace box and
//! accumulated in a voxel grid: each occupied voxel becomes one point, the mean of the samples that fell in
//! it, with its sample count and the mean centre of the cameras (frames) that saw it. Then sparse voxels and
//! statistical outliers are removed and normals are estimated and oriented toward those cameras.
//!
//! Speed and determinism: frames are processed in parallel; each frame's samples are reduced through a
//! small voxel cache keyed by integer voxel coordinates and appended to hash-partitioned shards, which are
//! sorted and summed at the end. Sums are kept in fixed point (integer micrometres), so the result does not
//! depend on the order frames are merged in, and the output is sorted by voxel key: bit-identical at any
//! thread count.

use crate::camera::depth::{check_size, deproject_row};
use crate::camera::{DeprojectConfig, DepthImage, DepthView, Intrinsics, RayTable};
use crate::error::{Error, Result};
use crate::geometry::{floor_i64, PointCloud};
use crate::index::KdIndex;
use crate::preprocess::normals::{estimate_normals, NormalConfig};
use crate::preprocess::outlier::{statistical_inliers, OutlierConfig};
use crate::preprocess::surface::{project_to_weighted_planes, SurfaceConfig};
use nalgebra::{Isometry3, Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// An axis-aligned workspace box in the robot's base frame, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CropBox {
    /// Lower corner `[x, y, z]`, metres.
    pub min: [f64; 3],
    /// Upper corner `[x, y, z]`, metres.
    pub max: [f64; 3],
}

impl CropBox {
    /// The box of two corners `[x0, y0, z0, x1, y1, z1]` (metres, in any order); the error says what is
    /// wrong (not six finite numbers, or two corners sharing a coordinate).
    pub fn from_corners(v: &[f64]) -> std::result::Result<Self, String> {
        if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
            return Err(format!(
                "expected 6 finite numbers (x0, y0, z0, x1, y1, z1), metres; got {v:?}"
            ));
        }
        let lo = [v[0].min(v[3]), v[1].min(v[4]), v[2].min(v[5])];
        let hi = [v[0].max(v[3]), v[1].max(v[4]), v[2].max(v[5])];
        if (0..3).any(|k| lo[k] == hi[k]) {
            return Err("the crop box is empty (two corners share a coordinate)".into());
        }
        Ok(CropBox { min: lo, max: hi })
    }

    /// True when `p` (metres, base frame) is inside the box (bounds included).
    #[inline]
    pub fn contains(&self, p: &[f64; 3]) -> bool {
        (0..3).all(|k| p[k] >= self.min[k] && p[k] <= self.max[k])
    }
}

/// Settings of [`fuse_frames`] and [`fuse_robot`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FuseConfig {
    /// Voxel edge, metres. `None` (default): `auto_voxel_factor` × the median pixel footprint of the first
    /// frame (median depth / focal length), e.g. ~9.6 mm for a 585 px camera at 1.9 m.
    pub voxel_size_m: Option<f64>,
    /// Multiple of the median pixel footprint used when `voxel_size_m` is `None` (default 3.0: measured on
    /// 25 Kinect frames, 2.0 gives 1.7 M points and 5.5 s with outlier removal and normals, 3.0 gives
    /// 0.72 M points and 2.7 s, of which fusion itself is 0.34 s).
    pub auto_voxel_factor: f64,
    /// The automatic voxel's largest edge, metres (a voxel given in `voxel_size_m` is not bounded);
    /// `None` (default): no bound. `calibrate` sets 11 mm.
    pub max_auto_voxel_m: Option<f64>,
    /// Voxels with fewer samples than this are dropped (default 1: keep all).
    pub min_points_per_voxel: u32,
    /// Depth range and flying-pixel filter.
    pub deproject: DeprojectConfig,
    /// Optional workspace box in the base frame; samples outside are dropped before fusion. Default none.
    pub crop: Option<CropBox>,
    /// Statistical outlier removal on the fused points; `None` disables it. Default `k = 20`, `std_ratio = 2`.
    pub outlier: Option<OutlierConfig>,
    /// Normal estimation (oriented toward the cameras that saw each voxel); `None` disables it. Default 30
    /// nearest neighbours.
    pub normals: Option<NormalConfig>,
    /// Count-weighted surface projection of the voxel means, then a merge of the voxels it brought
    /// together (see [`crate::preprocess::surface`]): removes the doubled sheets that noisy depth leaves
    /// where a surface runs along a voxel layer. `None` disables it. Default on.
    pub surface: Option<SurfaceConfig>,
    /// Keep a low-resolution depth map of every frame with its pose ([`DepthView`], blocks of this many
    /// pixels) in [`FusedCloud::views`], for visibility tests; `None` (default) keeps none.
    pub depth_views: Option<u32>,
    /// Keep only the voxels within this multiple of the median range (see [`within_median_range`]),
    /// before the surface projection and everything after it; `None` (default) keeps every voxel.
    /// `calibrate` sets it from its own `max_range_factor`.
    pub max_range_factor: Option<f64>,
}

impl Default for FuseConfig {
    fn default() -> Self {
        FuseConfig {
            voxel_size_m: None,
            auto_voxel_factor: 3.0,
            max_auto_voxel_m: None,
            min_points_per_voxel: 1,
            deproject: DeprojectConfig::default(),
            crop: None,
            outlier: Some(OutlierConfig::default()),
            normals: Some(NormalConfig::default()),
            surface: Some(SurfaceConfig::default()),
            depth_views: None,
            max_range_factor: None,
        }
    }
}

impl FuseConfig {
    /// The automatic voxel edge of `depth` ([`auto_voxel_size`] at `auto_voxel_factor`, at most
    /// `max_auto_voxel_m`), metres; `None` when the image has no valid depth in range.
    pub fn auto_voxel(&self, depth: &DepthImage, intr: &Intrinsics) -> Option<f64> {
        auto_voxel_size(depth, intr, &self.deproject, self.auto_voxel_factor)
            .map(|v| self.max_auto_voxel_m.map_or(v, |m| v.min(m)))
    }

    /// Fusion only: no outlier removal, no normals (the fast path the speed figures refer to).
    pub fn voxels_only() -> Self {
        FuseConfig {
            outlier: None,
            normals: None,
            ..Default::default()
        }
    }

    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("fuse.{field}"),
                msg,
            })
        };
        if let Some(v) = self.voxel_size_m {
            if !(v.is_finite() && v > 0.0) {
                return bad(
                    "voxel_size_m",
                    format!("must be a positive number of metres, found {v}"),
                );
            }
        }
        if let Some(v) = self.max_auto_voxel_m {
            if !(v.is_finite() && v > 0.0) {
                return bad(
                    "max_auto_voxel_m",
                    format!("must be a positive number of metres, found {v}"),
                );
            }
        }
        if let Some(f) = self.max_range_factor {
            if !(f.is_finite() && f > 0.0) {
                return bad(
                    "max_range_factor",
                    format!("must be a positive number, found {f}"),
                );
            }
        }
        if !(self.auto_voxel_factor.is_finite() && self.auto_voxel_factor > 0.0) {
            return bad(
                "auto_voxel_factor",
                format!("must be positive, found {}", self.auto_voxel_factor),
            );
        }
        if let Some(c) = &self.crop {
            if (0..3)
                .any(|k| !(c.min[k].is_finite() && c.max[k].is_finite() && c.min[k] < c.max[k]))
            {
                return bad(
                    "crop",
                    format!(
                        "min {:?} must be below max {:?} on every axis",
                        c.min, c.max
                    ),
                );
            }
        }
        if let Some(o) = &self.outlier {
            o.validate()?;
        }
        self.deproject.validate()
    }
}

/// The fewest points a fused cloud must have (fewer cannot be registered).
pub const MIN_FUSED_POINTS: usize = 20;
/// Below this many points a fused cloud is too sparse for a reliable registration (a warning).
pub const FEW_FUSED_POINTS: usize = 1000;

/// What `depthcal fuse` and `depthcal.fuse` take, one settings layer for both: [`FuseOptions::config`]
/// makes the checked [`FuseConfig`].
#[derive(Clone, Debug, PartialEq)]
pub struct FuseOptions {
    /// Voxel edge, metres (`None`: automatic).
    pub voxel_m: Option<f64>,
    /// Depths kept, metres.
    pub min_depth_m: f64,
    /// See `min_depth_m`.
    pub max_depth_m: f64,
    /// Workspace crop box in the base frame.
    pub crop: Option<CropBox>,
    /// Remove statistical outliers.
    pub outlier_removal: bool,
    /// Estimate normals.
    pub normals: bool,
}

impl FuseOptions {
    /// The fusion settings of these options over the defaults, checked ([`FuseConfig::validate`]: the
    /// error names the field).
    pub fn config(&self) -> Result<FuseConfig> {
        let mut cfg = FuseConfig {
            voxel_size_m: self.voxel_m,
            crop: self.crop,
            ..Default::default()
        };
        cfg.deproject.min_depth_m = self.min_depth_m;
        cfg.deproject.max_depth_m = self.max_depth_m;
        if !self.outlier_removal {
            cfg.outlier = None;
        }
        if !self.normals {
            cfg.normals = None;
        }
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Whether robot `robot`'s fused cloud can be registered: an error below [`MIN_FUSED_POINTS`] points, a
/// warning to show below [`FEW_FUSED_POINTS`].
pub fn check_fused_size(robot: &str, s: &FuseStats) -> Result<Option<String>> {
    if s.points_out < MIN_FUSED_POINTS {
        return Err(Error::InvalidInput(format!(
            "fusing robot {robot:?}: the fused cloud has only {} points (voxel {} m, {} frames, {} samples): \
             too few to register (at least {MIN_FUSED_POINTS}). Choose a smaller voxel",
            s.points_out, s.voxel_size_m, s.frames, s.points_in
        )));
    }
    Ok((s.points_out < FEW_FUSED_POINTS).then(|| {
        format!(
            "the fused cloud has only {} points (voxel {} m): too sparse for a reliable registration; choose a smaller voxel",
            s.points_out, s.voxel_size_m
        )
    }))
}

/// Counters of a fusion run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FuseStats {
    /// Frames fused.
    pub frames: usize,
    /// Points deprojected from all frames (after depth range and flying-pixel filtering).
    pub points_in: usize,
    /// Of those, samples outside the crop box.
    pub points_cropped: usize,
    /// Voxel edge used, metres.
    pub voxel_size_m: f64,
    /// Occupied voxels.
    pub voxels: usize,
    /// Voxels dropped for having fewer than `min_points_per_voxel` samples.
    pub sparse_removed: usize,
    /// Voxels dropped for lying beyond `max_range_factor` × the median range.
    pub range_cut: usize,
    /// Points moved by the surface projection (before the merge of the voxels it brought together).
    pub surface_moved: usize,
    /// Points removed by the statistical outlier filter.
    pub outliers_removed: usize,
    /// Points in the result.
    pub points_out: usize,
}

/// A fused cloud with per-point provenance.
#[derive(Clone, Debug, Default)]
pub struct FusedCloud {
    /// The points (voxel means, metres, base frame) sorted by voxel key, with normals if computed.
    pub cloud: PointCloud,
    /// Number of samples averaged into each point.
    pub counts: Vec<u32>,
    /// Mean camera centre (base frame, metres, ~1 cm resolution) of the samples averaged into each point,
    /// i.e. of the frames that saw it weighted by their sample counts; normals face it.
    pub viewpoints: Vec<[f32; 3]>,
    /// Counters.
    pub stats: FuseStats,
    /// Each frame's low-resolution depth and pose, in frame order, when [`FuseConfig::depth_views`] asks
    /// for them (else empty).
    pub views: Vec<DepthView>,
}

impl FusedCloud {
    /// Unit direction from each point toward its mean camera centre ([`FusedCloud::viewpoints`]): the side
    /// each surface was seen from. A point whose viewpoint coincides with it (never for real frames) gets
    /// a zero vector. Empty when the cloud has no viewpoints.
    pub fn sight_directions(&self) -> Vec<[f32; 3]> {
        self.to_viewpoints()
            .map(|d| {
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                if n > 0.0 && n.is_finite() {
                    [d[0] / n, d[1] / n, d[2] / n]
                } else {
                    [0.0; 3]
                }
            })
            .collect()
    }

    /// The vector from each point to its mean camera centre; nothing when the cloud has no viewpoints.
    fn to_viewpoints(&self) -> impl Iterator<Item = [f32; 3]> + '_ {
        let n = if self.viewpoints.len() == self.cloud.points.len() {
            self.viewpoints.len()
        } else {
            0
        };
        self.cloud.points[..n]
            .iter()
            .zip(&self.viewpoints[..n])
            .map(|(p, v)| [v[0] - p[0], v[1] - p[1], v[2] - p[2]])
    }

    /// Gives the cloud normals that carry the side each surface was seen from, unless it has normals
    /// already (fusion's own normals face the cameras too): its sight directions. Returns whether the
    /// cloud now has sided normals.
    pub fn make_sided(&mut self) -> bool {
        if self.cloud.normals.is_none() {
            let s = self.sight_directions();
            if s.len() == self.cloud.points.len() && !s.is_empty() {
                self.cloud.normals = Some(s);
            }
        }
        self.cloud.normals.is_some()
    }

    /// Distance from each point to its mean camera centre ([`FusedCloud::viewpoints`]), metres. Empty
    /// when the cloud has no viewpoints.
    pub fn ranges(&self) -> Vec<f32> {
        ranges_of(&self.cloud.points, &self.viewpoints)
    }
}

/// One frame to fuse: its depth image and `T_base_cam`.
#[derive(Clone, Copy, Debug)]
pub struct FrameInput<'a> {
    /// The depth image (size must match the ray table).
    pub depth: &'a DepthImage,
    /// Camera pose in the base frame, metres.
    pub t_base_cam: Isometry3<f64>,
}

// ---------------------------------------------------------------------------------------------------------
// Voxel accumulation.

/// Fixed-point resolution of the point sums: units per metre (1 µm).
const FIXED: f64 = 1e6;
/// Fixed-point resolution of the camera-centre sums: units per metre (1 cm; only used to orient normals).
const CAM_FIXED: f64 = 1e2;
const KEY_BITS: u32 = 21;
const KEY_OFFSET: i64 = 1 << (KEY_BITS - 1);
const SHARD_BITS: u32 = 6;
const CACHE_BITS: u32 = 13;
const EMPTY: u64 = u64::MAX;

/// `round(x)` (half away from zero) as an integer without a libm call.
#[inline(always)]
fn round_i64(x: f64) -> i64 {
    (x + 0.5f64.copysign(x)) as i64
}

#[inline]
fn shard_of(key: u64) -> usize {
    (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - SHARD_BITS)) as usize
}

#[inline]
fn cache_slot(key: u64) -> usize {
    let mut z = key ^ (key >> 31);
    z = z.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    (z >> (64 - CACHE_BITS)) as usize
}

/// Packs integer voxel coordinates (each in `[-2^20, 2^20)`) into a key whose order is `(x, y, z)`
/// lexicographic; `None` when out of range.
#[inline]
fn pack_key(ix: i64, iy: i64, iz: i64) -> Option<u64> {
    let r = -KEY_OFFSET..KEY_OFFSET;
    if r.contains(&ix) && r.contains(&iy) && r.contains(&iz) {
        let u = |v: i64| (v + KEY_OFFSET) as u64;
        Some(u(ix) << (2 * KEY_BITS) | u(iy) << KEY_BITS | u(iz))
    } else {
        None
    }
}

/// A partial sum for one voxel: fixed-point sums of the samples and of their cameras' centres.
#[derive(Clone, Copy)]
struct Partial {
    key: u64,
    sum: [i64; 3],
    cam: [i32; 3],
    count: u32,
}

/// A streaming voxel accumulator: add frames from any number of threads, then [`VoxelFusion::finish`].
///
/// Each frame is reduced through a small direct-mapped cache of voxels (image coherence makes most
/// samples hit), and the partial sums are appended to one of 64 shards. [`VoxelFusion::finish`] sorts each
/// shard by voxel key and adds up equal keys; all sums are integers, so the result does not depend on the
/// order of frames or the thread count.
pub struct VoxelFusion {
    voxel: f64,
    inv: f64,
    deproject: DeprojectConfig,
    crop: Option<CropBox>,
    shards: Vec<Mutex<Vec<Partial>>>,
    points_in: AtomicUsize,
    cropped: AtomicUsize,
    out_of_range: AtomicUsize,
    frames: AtomicUsize,
}

/// The raw result of voxel fusion, sorted by voxel key.
#[derive(Clone, Debug, Default)]
pub struct VoxelCloud {
    /// Voxel means, metres.
    pub points: Vec<[f32; 3]>,
    /// Samples per voxel.
    pub counts: Vec<u32>,
    /// Mean camera centre of the samples of each voxel (metres, ~1 cm resolution).
    pub viewpoints: Vec<[f32; 3]>,
    /// Counters (voxel size, frames, points in, cropped, voxels).
    pub stats: FuseStats,
}

impl VoxelFusion {
    /// An empty accumulator with voxel edge `voxel_size_m` (metres).
    pub fn new(
        voxel_size_m: f64,
        deproject: DeprojectConfig,
        crop: Option<CropBox>,
    ) -> Result<Self> {
        if !(voxel_size_m.is_finite() && voxel_size_m > 0.0) {
            return Err(Error::Config {
                field: "fuse.voxel_size_m".into(),
                msg: format!("must be a positive number of metres, found {voxel_size_m}"),
            });
        }
        deproject.validate()?;
        Ok(VoxelFusion {
            voxel: voxel_size_m,
            inv: 1.0 / voxel_size_m,
            deproject,
            crop,
            shards: (0..1 << SHARD_BITS)
                .map(|_| Mutex::new(Vec::new()))
                .collect(),
            points_in: AtomicUsize::new(0),
            cropped: AtomicUsize::new(0),
            out_of_range: AtomicUsize::new(0),
            frames: AtomicUsize::new(0),
        })
    }

    /// Deprojects one frame, moves it to the base frame and accumulates it. Safe to call from many threads;
    /// the final result does not depend on the order of calls. `what` names the image in errors.
    pub fn add_frame(
        &self,
        depth: &DepthImage,
        rays: &RayTable,
        t_base_cam: &Isometry3<f64>,
        what: &Path,
    ) -> Result<()> {
        check_size(depth, rays, what)?;
        let r: Matrix3<f64> = *t_base_cam.rotation.to_rotation_matrix().matrix();
        let t: Vector3<f64> = t_base_cam.translation.vector;
        let cam = [
            (t.x * CAM_FIXED).round() as i32,
            (t.y * CAM_FIXED).round() as i32,
            (t.z * CAM_FIXED).round() as i32,
        ];
        let mut cache: Vec<Partial> = vec![
            Partial {
                key: EMPTY,
                sum: [0; 3],
                cam: [0; 3],
                count: 0,
            };
            1 << CACHE_BITS
        ];
        let mut buckets: Vec<Vec<Partial>> = vec![Vec::new(); 1 << SHARD_BITS];
        let mut emit = |p: Partial| buckets[shard_of(p.key)].push(p);
        let mut row_pts = Vec::with_capacity(depth.width as usize);
        let (mut n_in, mut n_crop, mut n_range) = (0usize, 0usize, 0usize);
        for v in 0..depth.height as usize {
            row_pts.clear();
            deproject_row(depth, rays, &self.deproject, v, &mut row_pts);
            n_in += row_pts.len();
            for p in &row_pts {
                let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
                let q = [
                    r[(0, 0)] * x + r[(0, 1)] * y + r[(0, 2)] * z + t.x,
                    r[(1, 0)] * x + r[(1, 1)] * y + r[(1, 2)] * z + t.y,
                    r[(2, 0)] * x + r[(2, 1)] * y + r[(2, 2)] * z + t.z,
                ];
                if let Some(c) = &self.crop {
                    if !c.contains(&q) {
                        n_crop += 1;
                        continue;
                    }
                }
                let Some(key) = pack_key(
                    floor_i64(q[0] * self.inv),
                    floor_i64(q[1] * self.inv),
                    floor_i64(q[2] * self.inv),
                ) else {
                    n_range += 1;
                    continue;
                };
                let fixed = [
                    round_i64(q[0] * FIXED),
                    round_i64(q[1] * FIXED),
                    round_i64(q[2] * FIXED),
                ];
                let slot = &mut cache[cache_slot(key)];
                if slot.key != key {
                    if slot.key != EMPTY {
                        emit(*slot);
                    }
                    *slot = Partial {
                        key,
                        sum: [0; 3],
                        cam,
                        count: 0,
                    };
                }
                slot.sum[0] += fixed[0];
                slot.sum[1] += fixed[1];
                slot.sum[2] += fixed[2];
                slot.count += 1;
            }
        }
        for p in cache.into_iter().filter(|p| p.key != EMPTY) {
            emit(p);
        }
        for (s, mut bucket) in buckets.into_iter().enumerate() {
            if !bucket.is_empty() {
                self.shards[s]
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .append(&mut bucket);
            }
        }
        self.points_in.fetch_add(n_in, Ordering::Relaxed);
        self.cropped.fetch_add(n_crop, Ordering::Relaxed);
        self.out_of_range.fetch_add(n_range, Ordering::Relaxed);
        self.frames.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    /// The fused voxels, sorted by voxel key.
    pub fn finish(self) -> VoxelCloud {
        struct Voxel {
            key: u64,
            point: [f32; 3],
            view: [f32; 3],
            count: u32,
        }
        let shards: Vec<Vec<Partial>> = self
            .shards
            .into_iter()
            .map(|m| m.into_inner().unwrap_or_else(|e| e.into_inner()))
            .collect();
        let reduced: Vec<Vec<Voxel>> = shards
            .into_par_iter()
            .map(|parts| {
                // Sort compact (key, index) pairs rather than the 48-byte partial sums.
                let mut order: Vec<(u64, u32)> = parts
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (p.key, i as u32))
                    .collect();
                order.sort_unstable();
                let mut out: Vec<Voxel> = Vec::with_capacity(parts.len() / 2 + 1);
                let mut i = 0;
                while i < order.len() {
                    let key = order[i].0;
                    let (mut sum, mut cam, mut count) = ([0i64; 3], [0i64; 3], 0u64);
                    while i < order.len() && order[i].0 == key {
                        let p = &parts[order[i].1 as usize];
                        for k in 0..3 {
                            sum[k] += p.sum[k];
                            cam[k] += p.cam[k] as i64 * p.count as i64;
                        }
                        count += p.count as u64;
                        i += 1;
                    }
                    let c = count as f64;
                    out.push(Voxel {
                        key,
                        point: std::array::from_fn(|k| (sum[k] as f64 / (c * FIXED)) as f32),
                        view: std::array::from_fn(|k| (cam[k] as f64 / (c * CAM_FIXED)) as f32),
                        count: count.min(u32::MAX as u64) as u32,
                    });
                }
                out
            })
            .collect();
        // Global order by voxel key: sort (key, shard, index) triples, then gather.
        let mut order: Vec<(u64, u32)> = Vec::with_capacity(reduced.iter().map(|r| r.len()).sum());
        for (s, r) in reduced.iter().enumerate() {
            order.extend(
                r.iter()
                    .enumerate()
                    .map(|(i, v)| (v.key, (s as u32) << 26 | i as u32)),
            );
        }
        order.par_sort_unstable();
        let at = |code: u32| &reduced[(code >> 26) as usize][(code & ((1 << 26) - 1)) as usize];
        let all: Vec<&Voxel> = order.iter().map(|&(_, code)| at(code)).collect();
        let n = all.len();
        let out_of_range = self.out_of_range.into_inner();
        if out_of_range > 0 {
            log::warn!(
                "{out_of_range} samples lie more than {:.0} m from the base origin and were dropped",
                KEY_OFFSET as f64 * self.voxel
            );
        }
        VoxelCloud {
            points: all.iter().map(|v| v.point).collect(),
            counts: all.iter().map(|v| v.count).collect(),
            viewpoints: all.iter().map(|v| v.view).collect(),
            stats: FuseStats {
                frames: self.frames.into_inner(),
                points_in: self.points_in.into_inner(),
                points_cropped: self.cropped.into_inner(),
                voxel_size_m: self.voxel,
                voxels: n,
                ..Default::default()
            },
        }
    }
}

/// The automatic voxel edge: `factor` × median depth / mean focal length over the valid pixels of `depth`
/// (metres); `None` when the image has no valid depth in range.
pub fn auto_voxel_size(
    depth: &DepthImage,
    intr: &Intrinsics,
    cfg: &DeprojectConfig,
    factor: f64,
) -> Option<f64> {
    let mut d: Vec<u16> = depth
        .data
        .iter()
        .step_by(7)
        .copied()
        .filter(|&v| {
            let m = v as f64 * intr.depth_scale;
            v != 0 && m >= cfg.min_depth_m && m <= cfg.max_depth_m
        })
        .collect();
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable(mid);
    let median_m = *m as f64 * intr.depth_scale;
    Some(factor * median_m * 2.0 / (intr.fx + intr.fy))
}

/// Merges the points of `v` that fall into one voxel of edge `voxel` (sample-count weighted means of the
/// points and viewpoints, counts added); the result is sorted by voxel key. Deterministic.
fn merge_voxels(v: VoxelCloud, voxel: f64) -> VoxelCloud {
    let inv = 1.0 / voxel;
    let key = |p: &[f32; 3]| {
        pack_key(
            floor_i64(p[0] as f64 * inv),
            floor_i64(p[1] as f64 * inv),
            floor_i64(p[2] as f64 * inv),
        )
        .unwrap_or(EMPTY)
    };
    let mut order: Vec<(u64, u32)> = v
        .points
        .par_iter()
        .enumerate()
        .map(|(i, p)| (key(p), i as u32))
        .collect();
    order.par_sort_unstable();
    let mut out = VoxelCloud {
        stats: v.stats.clone(),
        ..Default::default()
    };
    let mut i = 0;
    while i < order.len() {
        let k = order[i].0;
        let (mut sp, mut sv, mut sw) = ([0f64; 3], [0f64; 3], 0u64);
        while i < order.len() && order[i].0 == k {
            let j = order[i].1 as usize;
            let w = v.counts[j].max(1) as u64;
            for d in 0..3 {
                sp[d] += v.points[j][d] as f64 * w as f64;
                sv[d] += v.viewpoints[j][d] as f64 * w as f64;
            }
            sw += w;
            i += 1;
        }
        let w = sw as f64;
        out.points.push(sp.map(|x| (x / w) as f32));
        out.viewpoints.push(sv.map(|x| (x / w) as f32));
        out.counts.push(sw.min(u32::MAX as u64) as u32);
    }
    out.stats.voxels = out.points.len();
    out
}

/// Distance from each point to its viewpoint, metres; empty unless there is one viewpoint per point.
fn ranges_of(points: &[[f32; 3]], viewpoints: &[[f32; 3]]) -> Vec<f32> {
    if viewpoints.len() != points.len() {
        return Vec::new();
    }
    points
        .iter()
        .zip(viewpoints)
        .map(|(p, v)| {
            let d = [v[0] - p[0], v[1] - p[1], v[2] - p[2]];
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .collect()
}

/// The indices (ascending) of the points no farther than `factor` times the median range from their
/// viewpoints (the mean camera centre of the samples fused into each, [`FusedCloud::viewpoints`]). The
/// median is over the depth samples: each point weighs as many samples as were fused into it (`counts`),
/// so it is about the median depth of the frames, whereas per point a wide far floor fills most voxels
/// while the cameras look at the workspace. Every point is kept when the slices differ in length.
pub fn within_median_range(
    points: &[[f32; 3]],
    viewpoints: &[[f32; 3]],
    counts: &[u32],
    factor: f64,
) -> Vec<usize> {
    if viewpoints.len() != points.len() || counts.len() != points.len() {
        return (0..points.len()).collect();
    }
    let ranges = ranges_of(points, viewpoints);
    let mut order: Vec<(f32, u32)> = ranges.iter().copied().zip(counts.iter().copied()).collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: u64 = order.iter().map(|&(_, c)| c as u64).sum();
    let mut acc = 0u64;
    let median = order
        .iter()
        .find(|&&(_, c)| {
            acc += c as u64;
            2 * acc >= total
        })
        .map_or(f32::INFINITY, |&(r, _)| r);
    let limit = (factor * median as f64) as f32;
    (0..points.len()).filter(|&i| ranges[i] <= limit).collect()
}

/// Removes sparse voxels, far voxels ([`FuseConfig::max_range_factor`]) and outliers and estimates oriented
/// normals (the steps after voxel fusion).
pub fn finish_fusion(v: VoxelCloud, cfg: &FuseConfig) -> Result<FusedCloud> {
    let mut stats = v.stats.clone();
    let mut keep: Vec<usize> = (0..v.points.len())
        .filter(|&i| v.counts[i] >= cfg.min_points_per_voxel)
        .collect();
    stats.sparse_removed = v.points.len() - keep.len();
    let pick = |keep: &[usize], v: &VoxelCloud| VoxelCloud {
        points: keep.iter().map(|&i| v.points[i]).collect(),
        counts: keep.iter().map(|&i| v.counts[i]).collect(),
        viewpoints: keep.iter().map(|&i| v.viewpoints[i]).collect(),
        stats: FuseStats::default(),
    };
    let mut v = if stats.sparse_removed > 0 {
        pick(&keep, &v)
    } else {
        v
    };
    // Before the surface projection: it is the costly step, and its fits far out would be cut anyway.
    if let Some(f) = cfg.max_range_factor {
        keep = within_median_range(&v.points, &v.viewpoints, &v.counts, f);
        stats.range_cut = v.points.len() - keep.len();
        if stats.range_cut > 0 {
            v = pick(&keep, &v);
        }
    }
    if let Some(sc) = cfg.surface.as_ref().filter(|_| v.points.len() >= 3) {
        let index = KdIndex::new(&v.points);
        let voxel = stats.voxel_size_m;
        let (points, moved) = project_to_weighted_planes(&v.points, &v.counts, &index, voxel, sc);
        v.points = points;
        v = merge_voxels(v, voxel);
        stats.surface_moved = moved;
    }
    if let Some(o) = &cfg.outlier {
        let index = KdIndex::new(&v.points);
        keep = statistical_inliers(&v.points, &index, o)?;
        stats.outliers_removed = v.points.len() - keep.len();
        if stats.outliers_removed > 0 {
            v = pick(&keep, &v);
        }
    }
    let normals = cfg
        .normals
        .as_ref()
        .filter(|_| v.points.len() >= 3)
        .map(|nc| {
            let index = KdIndex::new(&v.points);
            let mut n = estimate_normals(&v.points, &index, nc);
            n.par_iter_mut()
                .zip(v.points.par_iter().zip(v.viewpoints.par_iter()))
                .for_each(|(n, (p, c))| {
                    let dot = (0..3)
                        .map(|k| n[k] as f64 * (c[k] as f64 - p[k] as f64))
                        .sum::<f64>();
                    if dot < 0.0 {
                        *n = [-n[0], -n[1], -n[2]];
                    }
                });
            n
        });
    stats.points_out = v.points.len();
    Ok(FusedCloud {
        cloud: PointCloud {
            points: v.points,
            normals,
            colors: None,
        },
        counts: v.counts,
        viewpoints: v.viewpoints,
        stats,
        views: Vec::new(),
    })
}

/// Fuses in-memory frames of one camera (all frames share `intr`) into a base-frame cloud.
pub fn fuse_frames(
    frames: &[FrameInput<'_>],
    intr: &Intrinsics,
    cfg: &FuseConfig,
) -> Result<FusedCloud> {
    cfg.validate()?;
    if frames.is_empty() {
        return Err(Error::InvalidInput("no frames to fuse".into()));
    }
    let rays = RayTable::new(intr);
    let voxel = resolve_voxel(cfg, frames.iter().map(|f| f.depth), intr)?;
    let acc = VoxelFusion::new(voxel, cfg.deproject.clone(), cfg.crop)?;
    let views = frames
        .par_iter()
        .enumerate()
        .map(|(i, f)| {
            acc.add_frame(
                f.depth,
                &rays,
                &f.t_base_cam,
                Path::new(&format!("frame {i}")),
            )?;
            Ok(cfg
                .depth_views
                .map(|b| DepthView::new(f.depth, intr, &f.t_base_cam, b)))
        })
        .collect::<Result<Vec<Option<DepthView>>>>()?;
    let mut fused = finish_fusion(acc.finish(), cfg)?;
    fused.views = views.into_iter().flatten().collect();
    check_not_empty(&fused, "the frames")?;
    Ok(fused)
}

fn resolve_voxel<'a>(
    cfg: &FuseConfig,
    mut images: impl Iterator<Item = &'a DepthImage>,
    intr: &Intrinsics,
) -> Result<f64> {
    if let Some(v) = cfg.voxel_size_m {
        return Ok(v);
    }
    images
        .find_map(|img| cfg.auto_voxel(img, intr))
        .ok_or_else(|| {
            Error::InvalidInput(
                "no frame has valid depth in the depth range; cannot choose a voxel size".into(),
            )
        })
}

fn check_not_empty(f: &FusedCloud, what: &str) -> Result<()> {
    if f.cloud.is_empty() {
        return Err(Error::InvalidInput(format!(
            "fusing {what} gave no points ({} deprojected, {} outside the crop box); check the depth range, \
             the crop box and the depth scale",
            f.stats.points_in, f.stats.points_cropped
        )));
    }
    Ok(())
}

/// The depth frames of one robot as fusion needs them (a cell's robot, `depthcal::cell::CellRobot`,
/// is one).
pub trait DepthFrames: Sync {
    /// The robot's name, for messages.
    fn robot_name(&self) -> &str;
    /// The depth camera's intrinsics.
    fn depth_intrinsics(&self) -> &Intrinsics;
    /// The number of frames.
    fn frame_count(&self) -> usize;
    /// Frame `i`'s depth image.
    fn load_depth(&self, i: usize) -> Result<DepthImage>;
    /// Frame `i`'s camera pose in the robot base, `T_base_ee · T_ee_cam` (metres).
    fn t_base_cam(&self, i: usize) -> Isometry3<f64>;
    /// Frame `i`'s depth file, for messages.
    fn depth_path(&self, i: usize) -> &std::path::Path;
}

/// Fuses all frames of a robot, reading the depth images in parallel. `progress` is called once per
/// finished frame with the number of frames done so far.
pub fn fuse_robot(
    robot: &dyn DepthFrames,
    cfg: &FuseConfig,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<FusedCloud> {
    cfg.validate()?;
    if robot.frame_count() == 0 {
        return Err(Error::InvalidInput(format!(
            "robot {:?} has no frames",
            robot.robot_name()
        )));
    }
    let rays = RayTable::new(robot.depth_intrinsics());
    let first = robot.load_depth(0)?;
    let voxel = match cfg.voxel_size_m {
        Some(v) => v,
        None => {
            let auto = |img: &DepthImage| cfg.auto_voxel(img, robot.depth_intrinsics());
            let mut found = auto(&first);
            let mut i = 1;
            while found.is_none() && i < robot.frame_count() {
                found = auto(&robot.load_depth(i)?);
                i += 1;
            }
            found.ok_or_else(|| {
                Error::InvalidInput(format!(
                    "robot {:?}: no frame has valid depth in the depth range; cannot choose a voxel size",
                    robot.robot_name()
                ))
            })?
        }
    };
    let acc = VoxelFusion::new(voxel, cfg.deproject.clone(), cfg.crop)?;
    let done = AtomicUsize::new(0);
    let first = Mutex::new(Some(first));
    let views = (0..robot.frame_count())
        .into_par_iter()
        .map(|i| -> Result<Option<DepthView>> {
            let img = match if i == 0 {
                first.lock().unwrap().take()
            } else {
                None
            } {
                Some(img) => img,
                None => robot.load_depth(i)?,
            };
            acc.add_frame(&img, &rays, &robot.t_base_cam(i), robot.depth_path(i))?;
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            Ok(cfg
                .depth_views
                .map(|b| DepthView::new(&img, robot.depth_intrinsics(), &robot.t_base_cam(i), b)))
        })
        .collect::<Result<Vec<Option<DepthView>>>>()?;
    let mut fused = finish_fusion(acc.finish(), cfg)?;
    fused.views = views.into_iter().flatten().collect();
    check_not_empty(&fused, &format!("robot {:?}", robot.robot_name()))?;
    Ok(fused)
}

/// Deprojects one frame and moves it into the base frame (no fusion): metres, row-major pixel order.
pub fn frame_points_in_base(
    depth: &DepthImage,
    rays: &RayTable,
    cfg: &DeprojectConfig,
    t_base_cam: &Isometry3<f64>,
) -> Result<Vec<[f32; 3]>> {
    let mut pts = crate::camera::deproject(depth, rays, cfg)?;
    pts.par_iter_mut()
        .for_each(|p| *p = crate::geometry::cloud::transform_point(t_base_cam, p));
    Ok(pts)
}

#[cfg(test)]
pub(crate) mod tests;
