//! `fuse`: one robot's depth frames of a cell dataset fused into a cloud in its base frame.

use crate::cloud::PyPointCloud;
use crate::convert;
use crate::errors::{input_err, lib_err, new_err, Kind};
use crate::pool;
use depthcal::cell::Cell;
use depthcal::fusion::{fuse_robot, CropBox, FuseConfig};
use pyo3::prelude::*;
use std::time::Instant;

/// The fewest points a fused cloud must have (fewer cannot be registered), as `depthcal fuse`.
const MIN_FUSED_POINTS: usize = 20;
/// Below this a warning says the cloud is very sparse.
const FEW_FUSED_POINTS: usize = 1000;

/// Fuses one robot's depth frames of a cell dataset into one cloud in the robot's base frame (metres),
/// as ``depthcal fuse`` does: each frame deprojected through its intrinsics and placed by
/// ``T_base_cam = T_base_ee @ T_ee_cam``, voxel-fused, outliers removed, normals estimated.
///
/// Args:
///     cell_dir: the cell dataset directory (with ``cell.toml``).
///     robot: the robot's name in cell.toml (default: the reference robot).
///     voxel: voxel edge in metres (default: 2x the median pixel footprint of the first frame).
///     min_depth, max_depth: depth range kept, metres.
///     crop: workspace box in the base frame ``(x0, y0, z0, x1, y1, z1)``, metres (corners in any order).
///     outlier_removal: statistical outlier removal. normals: estimate normals.
///     threads: worker threads for this call (default: all cores).
///
/// Returns:
///     ``(cloud, stats)``: a :class:`PointCloud` (float32 points in the base frame, metres; normals) and
///     a dict (``robot``, ``frames``, ``points_in``, ``points_cropped``, ``voxel_size_m``, ``voxels``,
///     ``sparse_removed``, ``outliers_removed``, ``points``, ``normals``, ``seconds``: the JSON of
///     ``depthcal fuse --json``, with ``output`` None).
#[pyfunction]
#[pyo3(signature = (cell_dir, robot=None, *, voxel=None, min_depth=0.1, max_depth=10.0, crop=None, outlier_removal=true, normals=true, threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn fuse<'py>(
    py: Python<'py>,
    cell_dir: &Bound<'py, PyAny>,
    robot: Option<String>,
    voxel: Option<f64>,
    min_depth: f64,
    max_depth: f64,
    crop: Option<Vec<f64>>,
    outlier_removal: bool,
    normals: bool,
    threads: Option<usize>,
) -> PyResult<(PyPointCloud, Bound<'py, PyAny>)> {
    let dir = convert::path(cell_dir, "cell_dir")?;
    if let Some(v) = voxel {
        if !(v.is_finite() && v > 0.0) {
            return Err(new_err(
                Kind::Config,
                format!("voxel {v}: the voxel edge must be a positive number of metres"),
            ));
        }
    }
    if !(min_depth.is_finite() && max_depth.is_finite() && min_depth < max_depth) {
        return Err(input_err(format!(
            "min_depth {min_depth} / max_depth {max_depth}: need finite depths with min < max"
        )));
    }
    let crop = crop.map(|v| crop_box(&v)).transpose()?;
    let mut cfg = FuseConfig {
        voxel_size_m: voxel,
        ..Default::default()
    };
    cfg.deproject.min_depth_m = min_depth;
    cfg.deproject.max_depth_m = max_depth;
    cfg.crop = crop;
    if !outlier_removal {
        cfg.outlier = None;
    }
    if !normals {
        cfg.normals = None;
    }
    let start = Instant::now();
    let outcome = pool::run(py, threads, move || -> depthcal::Result<_> {
        let cell = Cell::open(&dir)?;
        let name = robot.unwrap_or_else(|| cell.manifest.reference.clone());
        let r = cell.robot(&name)?;
        let fused = fuse_robot(r, &cfg, &|_| {})?;
        Ok((name, fused))
    })?;
    let (name, fused) = outcome.map_err(lib_err)?;
    let s = &fused.stats;
    if s.points_out < MIN_FUSED_POINTS {
        return Err(input_err(format!(
            "fusing robot {name:?}: the fused cloud has only {} points (voxel {} m, {} frames, {} samples): \
             too few to register (at least {MIN_FUSED_POINTS}). Choose a smaller voxel",
            s.points_out, s.voxel_size_m, s.frames, s.points_in
        )));
    }
    if s.points_out < FEW_FUSED_POINTS {
        crate::errors::warn(
            py,
            &format!(
                "the fused cloud has only {} points (voxel {} m): too sparse for a reliable \
                 registration; choose a smaller voxel",
                s.points_out, s.voxel_size_m
            ),
        )?;
    }
    let report =
        depthcal::report::FusionReport::new(&fused, &name, None, start.elapsed().as_secs_f64());
    let stats = crate::register::to_json(&report)?;
    Ok((
        PyPointCloud::from_cloud(py, &fused.cloud),
        convert::json_to_py(py, &stats)?,
    ))
}

/// A crop box from six numbers x0, y0, z0, x1, y1, z1 (metres, corners in any order).
fn crop_box(v: &[f64]) -> PyResult<CropBox> {
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(input_err(format!(
            "crop: expected 6 finite numbers (x0, y0, z0, x1, y1, z1), metres; got {v:?}"
        )));
    }
    let lo = [v[0].min(v[3]), v[1].min(v[4]), v[2].min(v[5])];
    let hi = [v[0].max(v[3]), v[1].max(v[4]), v[2].max(v[5])];
    if (0..3).any(|k| lo[k] == hi[k]) {
        return Err(input_err(
            "crop: the crop box is empty (two corners share a coordinate)",
        ));
    }
    Ok(CropBox { min: lo, max: hi })
}
