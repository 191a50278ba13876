//! `simulate`: a simulated two-robot cell dataset with ground truth, as `depthcal simulate` writes it.

use crate::convert;
use crate::errors::{input_err, lib_err};
use crate::pool;
use depthcal::sim::{NoiseLevel, Resolution, SimCell, SimConfig};
use pyo3::prelude::*;
use std::time::Instant;

/// Writes a simulated two-robot cell dataset (depth and colour frames, poses, intrinsics, ``cell.toml``
/// and ``ground_truth.json``) into ``out_dir``, as ``depthcal simulate`` does; the same seed and options
/// give the same bytes at any thread count.
///
/// Args:
///     out_dir: the directory to write (created; must be empty unless ``force``).
///     seed: seed of everything random (default 1).
///     frames: frames per robot (default 20).
///     noise: depth noise ``none``, ``low``, ``default``, ``high``, or a factor of the default (a number).
///     overlap: how much of the scene both robots see, 0-1 (default 0.7; with more robots, what two
///         robots share on average over the pairs).
///     resolution: ``640x480`` (default) or ``1280x720``.
///     objects: number of objects on the table.
///     tilted_bases: tilt the robot bases by up to 2 degrees.
///     robots: the number of robots, 2-8 (default 2): evenly round the table, named left, right,
///         robot3, ... (as ``depthcal simulate --robots N``).
///     color: render colour images (default True).
///     textured: give objects and table a distinctive texture.
///     config: a dict of ``SimConfig`` fields (e.g. ``{"scene": {"board": {"cols": 9, "rows": 6}}}``)
///         merged over the defaults; the arguments above override it.
///     force: write into a non-empty directory, replacing files of the same names.
///     threads: worker threads for this call (default: all cores).
///
/// Returns:
///     A dict (schema ``depthcal.simulation/1``, the JSON of ``depthcal simulate --json``): ``schema``,
///     ``out_dir``, ``seed``, ``robots``, ``frames_per_robot``, ``resolution``, ``objects``,
///     ``T_base1_base2`` (the truth, a pose dict: ``matrix``, ``xyz_m``, ``quaternion_xyzw``,
///     ``kuka_xyzabc``), ``base_distance_m``, ``shared_fraction``, ``view_spread``, ``files``, ``bytes``,
///     ``seconds``.
#[pyfunction]
#[pyo3(signature = (out_dir, *, seed=None, frames=None, noise=None, overlap=None, resolution=None, objects=None, tilted_bases=false, color=true, textured=false, config=None, force=false, threads=None, robots=None))]
#[allow(clippy::too_many_arguments)]
pub fn simulate<'py>(
    py: Python<'py>,
    out_dir: &Bound<'py, PyAny>,
    seed: Option<u64>,
    frames: Option<usize>,
    noise: Option<&Bound<'py, PyAny>>,
    overlap: Option<f64>,
    resolution: Option<&str>,
    objects: Option<usize>,
    tilted_bases: bool,
    color: bool,
    textured: bool,
    config: Option<&Bound<'py, PyAny>>,
    force: bool,
    threads: Option<usize>,
    robots: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let dir = convert::path(out_dir, "out_dir")?;
    let mut cfg: SimConfig = convert::config(config, "SimConfig")?;
    if let Some(n) = robots {
        cfg.set_robots(n).map_err(lib_err)?;
    }
    if let Some(s) = seed {
        cfg.seed = s;
    }
    if let Some(k) = frames {
        cfg.frames = k;
    }
    if let Some(n) = noise.filter(|n| !n.is_none()) {
        let text: String = match n.extract::<f64>() {
            Ok(f) if n.extract::<String>().is_err() => f.to_string(),
            _ => n.extract::<String>().map_err(|_| {
                input_err("noise: expected none, low, default, high, or a number (a factor)")
            })?,
        };
        cfg.noise_level = text
            .parse::<NoiseLevel>()
            .map_err(|e| input_err(format!("noise: {e}")))?;
        cfg.noise = None;
    }
    if let Some(o) = overlap {
        cfg.overlap = o;
    }
    if let Some(r) = resolution {
        cfg.resolution = r
            .parse::<Resolution>()
            .map_err(|e| input_err(format!("resolution: {e}")))?;
    }
    if let Some(n) = objects {
        cfg.scene.objects = n;
    }
    if tilted_bases {
        cfg.bases_level = false;
    }
    if !color {
        cfg.color = false;
    }
    if textured {
        cfg.scene.textured = true;
    }
    if dir.exists() {
        if !dir.is_dir() {
            return Err(input_err(format!(
                "{}: exists and is not a directory",
                dir.display()
            )));
        }
        let non_empty = std::fs::read_dir(&dir)
            .map_err(|e| lib_err(depthcal::Error::io(&dir, e)))?
            .next()
            .is_some();
        if non_empty && !force {
            return Err(input_err(format!(
                "{}: the directory is not empty; choose an empty or new directory, or pass force=True to \
                 replace the files of the same names",
                dir.display()
            )));
        }
    }
    let start = Instant::now();
    let out = dir.clone();
    let sim_cfg = cfg.clone();
    let outcome = pool::run(py, threads, move || -> depthcal::Result<_> {
        let cell = SimCell::generate(&sim_cfg)?;
        let stats = cell.write(&out, &|_| {})?;
        Ok((cell, stats))
    })?;
    let (cell, stats) = outcome.map_err(lib_err)?;
    let report = depthcal::report::SimulationReport::new(
        &cell,
        &cfg,
        &stats,
        &dir,
        start.elapsed().as_secs_f64(),
    );
    let v = crate::register::to_json(&report)?;
    convert::json_to_py(py, &v)
}
