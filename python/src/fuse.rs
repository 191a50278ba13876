//! `fuse`: one robot's depth frames of a cell dataset fused into a cloud in its base frame.

use crate::cloud::PyPointCloud;
use crate::convert;
use crate::errors::{input_err, lib_err};
use crate::pool;
use depthcal::cell::Cell;
use depthcal::fusion::{check_fused_size, fuse_robot, CropBox, FuseOptions};
use pyo3::prelude::*;
use std::time::Instant;

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
    let crop = crop.map(|v| crop_box(&v)).transpose()?;
    let cfg = FuseOptions {
        voxel_m: voxel,
        min_depth_m: min_depth,
        max_depth_m: max_depth,
        crop,
        outlier_removal,
        normals,
    }
    .config()
    .map_err(lib_err)?;
    let start = Instant::now();
    let outcome = pool::run(py, threads, move || -> depthcal::Result<_> {
        let cell = Cell::open(&dir)?;
        let name = robot.unwrap_or_else(|| cell.manifest.reference.clone());
        let r = cell.robot(&name)?;
        let fused = fuse_robot(r, &cfg, &|_| {})?;
        Ok((name, fused))
    })?;
    let (name, fused) = outcome.map_err(lib_err)?;
    if let Some(w) = check_fused_size(&name, &fused.stats).map_err(lib_err)? {
        crate::errors::warn(py, &w)?;
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
    CropBox::from_corners(v).map_err(|e| input_err(format!("crop: {e}")))
}
