//! `profile`: where registration spends its time, as `depthcal profile --json` reports it.

use crate::convert;
use crate::errors::{input_err, lib_err};
use crate::pool;
use depthcal::profile::{nearby_guess, profile as run_profile, synthetic_pair, ProfileConfig};
use depthcal::registration::RegisterConfig;
use pyo3::prelude::*;

/// Profiles the registration pipeline: each stage's wall and CPU time, items in and out and throughput,
/// each ICP iteration's time, pairs and residual, and the peak memory, over ``repeat`` runs.
///
/// Args:
///     source, target: cloud file paths or (N, 3) arrays (as for :func:`register`); or leave both out and
///         give ``synthetic``.
///     synthetic: profile a generated pair of about this many points a side (planes, boxes, cylinders,
///         1 mm noise, partial overlap, a known transform; metres).
///     init: optional 4x4 SOURCE -> TARGET guess; needed when ``stages`` has no global stage (a synthetic
///         pair then starts 3 degrees / 5 cm off its truth).
///     truth: optional 4x4 true transform, for the error (synthetic pairs know theirs).
///     voxel: global-stage voxel size (cloud units). stages: the stages to report (``read``, ``scale``,
///         ``downsample_normals``, ``fpfh``, ``match``, ``ransac``, ``verify``, ``icp``, ``quality``,
///         ``total``). repeat: runs (default 3). seed, threads, config: as for :func:`register`.
///
/// Returns:
///     A dict, the JSON of ``depthcal profile --json`` (schema ``depthcal.profile/1``): ``stages``,
///     ``icp_levels``, ``peak_memory_bytes``, ``transform``, ``error_vs_truth``, ``deterministic``...
///     Times are milliseconds.
///
/// The GIL is released while it runs.
#[pyfunction]
#[pyo3(signature = (source=None, target=None, *, synthetic=None, init=None, truth=None, voxel=None, stages=None, repeat=3, seed=0, threads=None, config=None))]
#[allow(clippy::too_many_arguments)]
pub fn profile<'py>(
    py: Python<'py>,
    source: Option<&Bound<'py, PyAny>>,
    target: Option<&Bound<'py, PyAny>>,
    synthetic: Option<usize>,
    init: Option<&Bound<'py, PyAny>>,
    truth: Option<&Bound<'py, PyAny>>,
    voxel: Option<f64>,
    stages: Option<Vec<String>>,
    repeat: usize,
    seed: u64,
    threads: Option<usize>,
    config: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let mut cfg: RegisterConfig = convert::config(config, "registration configuration")?;
    cfg.seed = seed;
    if voxel.is_some() {
        cfg.voxel = voxel;
    }
    cfg.validate().map_err(lib_err)?;
    let pcfg = ProfileConfig {
        repeat,
        stages: stages.unwrap_or_default(),
    };
    pcfg.validate().map_err(lib_err)?;
    let iso = |o: Option<&Bound<'py, PyAny>>, what: &str| {
        o.filter(|i| !i.is_none())
            .map(|i| convert::isometry(i, what))
            .transpose()
    };
    let init = iso(init, "init")?;
    let truth = iso(truth, "truth")?;
    let source = source.filter(|x| !x.is_none());
    let target = target.filter(|x| !x.is_none());
    let clouds = match (synthetic, source, target) {
        (Some(_), None, None) => None,
        (None, Some(s), Some(t)) => Some((
            crate::register::cloud_arg(s, "source", false)?,
            crate::register::cloud_arg(t, "target", false)?,
        )),
        (Some(_), _, _) => {
            return Err(input_err(
                "synthetic replaces source and target: give one or the other",
            ))
        }
        _ => return Err(input_err("give source and target, or synthetic=N")),
    };
    let report = pool::run(py, threads, move || -> depthcal::Result<_> {
        match clouds {
            None => {
                let n = synthetic.expect("checked");
                let (s, t, pose) = synthetic_pair(n, seed)?;
                let init = init.or_else(|| pcfg.fine_only().then(|| nearby_guess(&pose)));
                run_profile(
                    &format!("synthetic {n} (seed {seed})"),
                    &mut || Ok((s.clone(), t.clone())),
                    init.as_ref(),
                    Some(&truth.unwrap_or(pose)),
                    &cfg,
                    &pcfg,
                )
            }
            Some((s, t)) => run_profile(
                "arrays or files",
                &mut || Ok((s.load()?, t.load()?)),
                init.as_ref(),
                truth.as_ref(),
                &cfg,
                &pcfg,
            ),
        }
    })?
    .map_err(lib_err)?;
    let v = crate::register::to_json(&report)?;
    convert::json_to_py(py, &v)
}
