//! `register`: the registration pipeline on two clouds, and its result class.

use crate::cloud::cloud_from_py;
use crate::convert;
use crate::errors::{lib_err, untrusted_err, Kind};
use crate::pool;
use depthcal::registration::RegisterConfig;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use std::time::Instant;

/// The result of :func:`register`: the transform that maps SOURCE points into TARGET's frame, its quality
/// and uncertainty, and the verdict.
///
/// Attributes are read-only; ``to_dict()`` gives everything as plain Python objects, equal to the JSON
/// that ``depthcal register --json`` prints for the same inputs.
#[pyclass(module = "depthcal", name = "Registration", frozen)]
pub struct PyRegistration {
    reg: depthcal::registration::Registration,
    report: serde_json::Value,
}

#[pymethods]
impl PyRegistration {
    /// 4x4 float64 ``T_target_source``: ``p_target = transform @ [p_source, 1]`` (cloud units).
    #[getter]
    fn transform<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix4(py, &self.reg.transform)
    }
    /// Fraction of the (finest-level) source points with a target point within the final correspondence
    /// distance, 0-1.
    #[getter]
    fn fitness(&self) -> f64 {
        self.reg.fitness
    }
    /// RMS distance of those pairs, cloud units.
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.reg.inlier_rmse
    }
    /// Overlap ratio estimated by the trimmed ICP, 0-1.
    #[getter]
    fn overlap(&self) -> f64 {
        self.reg.overlap
    }
    /// True only when every ICP level met its step tolerances within its iteration budget.
    #[getter]
    fn converged(&self) -> bool {
        self.reg.converged
    }
    /// ICP iterations over all levels.
    #[getter]
    fn iterations(&self) -> usize {
        self.reg.iterations
    }
    /// Whether the result passed the quality gate (see ``reasons``).
    #[getter]
    fn trusted(&self) -> bool {
        self.reg.trust.trusted
    }
    /// Why the result is not trusted, one sentence each (empty when trusted).
    #[getter]
    fn reasons(&self) -> Vec<String> {
        self.reg.trust.reasons.clone()
    }
    /// What to try when it is not trusted.
    #[getter]
    fn suggestions(&self) -> Vec<String> {
        self.reg.trust.suggestions.clone()
    }
    /// Things to know: dropped points, degeneracy, non-convergence, mismatched units.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.reg.warnings.clone()
    }
    /// 6x6 float64 covariance of ``[rx, ry, rz (rad), tx, ty, tz (cloud units)]``, a left increment about
    /// the target origin: ``sigma^2 (J^T W J)^-1`` plus a systematic floor.
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix6(py, &self.reg.covariance)
    }
    /// 6x6 float64 information matrix ``J^T W J`` (same parameter order).
    #[getter]
    fn information<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix6(py, &self.reg.information)
    }
    /// 1-sigma per parameter, ``sqrt(diag(covariance))``: radians then cloud units.
    #[getter]
    fn sigma<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v: Vec<f64> = (0..6)
            .map(|k| self.reg.covariance[(k, k)].max(0.0).sqrt())
            .collect();
        PyArray1::from_vec(py, v)
    }
    /// True when some motion is unconstrained (a plane, a corridor); see ``to_dict()["degeneracy"]``.
    #[getter]
    fn degenerate(&self) -> bool {
        self.reg.degeneracy.is_degenerate()
    }
    /// Fraction of the finest level's source points that lie on a target surface after the transform.
    #[getter]
    fn surface_agreement(&self) -> f64 {
        self.reg.surface_agreement
    }
    /// Voxel size of the global stage, cloud units (chosen from the data unless given).
    #[getter]
    fn voxel(&self) -> f64 {
        self.reg.voxel
    }
    /// Wall time of each stage in milliseconds, in order (a dict).
    #[getter]
    fn timings_ms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report["timings_ms"])
    }
    /// Everything as plain Python objects (the JSON of ``depthcal register --json``).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report)
    }
    /// Returns the result itself when it is trusted; raises ``UntrustedError`` with the reasons otherwise.
    fn check(slf: Bound<'_, Self>) -> PyResult<Bound<'_, Self>> {
        let r = slf.get();
        if r.reg.trust.trusted {
            Ok(slf)
        } else {
            Err(untrusted_err(&r.reg.trust.reasons))
        }
    }
    fn __repr__(&self) -> String {
        let t = &self.reg.transform;
        let v = t.translation.vector;
        format!(
            "Registration(trusted={}, fitness={:.3}, inlier_rmse={:.6}, overlap={:.3}, converged={}, \
             rotation_deg={:.3}, translation=[{:.6}, {:.6}, {:.6}])",
            if self.reg.trust.trusted { "True" } else { "False" },
            self.reg.fitness,
            self.reg.inlier_rmse,
            self.reg.overlap,
            if self.reg.converged { "True" } else { "False" },
            t.rotation.angle().to_degrees(),
            v.x,
            v.y,
            v.z
        )
    }
}

/// A cloud argument: a path (read with `read_cloud`, NaN points then dropped by the pipeline with a
/// warning, as the command line does), or points.
pub enum CloudArg {
    File(std::path::PathBuf),
    Points(depthcal::PointCloud),
}

pub fn cloud_arg(obj: &Bound<'_, PyAny>, what: &str, drop_nonfinite: bool) -> PyResult<CloudArg> {
    if let Some(p) = convert::path_like(obj) {
        return Ok(CloudArg::File(p));
    }
    Ok(CloudArg::Points(cloud_from_py(obj, what, drop_nonfinite)?))
}

impl CloudArg {
    /// The cloud: read from its file, or a copy of the points.
    pub fn load(&self) -> depthcal::Result<depthcal::PointCloud> {
        match self {
            CloudArg::File(p) => depthcal::io::read_cloud(p),
            CloudArg::Points(c) => Ok(c.clone()),
        }
    }
}

/// Registers ``source`` onto ``target``: finds the rigid transform that moves SOURCE onto TARGET, with
/// no parameters to tune (FPFH + RANSAC, verification, then coarse-to-fine trimmed robust ICP).
///
/// Args:
///     source, target: (N, 3) float32 or float64 arrays (any memory layout; an Open3D cloud's
///         ``np.asarray(pcd.points)``, or the Open3D cloud itself), :class:`PointCloud` objects, or paths
///         of cloud files (read as ``depthcal register`` reads them). Any unit (metres, millimetres):
///         every scale is measured from the data.
///     init: optional 4x4 rigid transform SOURCE -> TARGET to start from; skips the global stage.
///     voxel: global-stage voxel size in the clouds' unit (default: chosen so that ~5000 points remain).
///     seed: seed of the randomised steps; results are bit-identical for a seed at any thread count.
///     threads: worker threads for this call (default: all cores).
///     config: a dict of ``RegisterConfig`` fields (e.g. ``{"icp": {"kernel": "tukey"}, "icp_levels": 3}``)
///         merged over the defaults as ``depthcal register --config`` merges its file.
///     drop_nonfinite: drop array rows with NaN/inf values (with a warning) instead of raising.
///
/// Returns:
///     :class:`Registration` with ``transform`` (4x4 float64, ``p_target = T @ p_source``), ``fitness``,
///     ``inlier_rmse`` (cloud units), ``overlap``, ``converged``, ``trusted``, ``reasons``, ``covariance``
///     (6x6, rad and cloud units), ``timings_ms``, ``to_dict()``.
///
/// Raises:
///     InputError (ValueError): bad arrays (shape, dtype, NaN), fewer than 10 points, a non-rigid init.
///     ConfigError (ValueError): a bad config value or key. FileError (OSError) / FormatError
///     (ValueError): an unreadable cloud file. FailedError (RuntimeError): no hypothesis found.
///
/// The GIL is released while it runs.
#[pyfunction]
#[pyo3(signature = (source, target, *, init=None, voxel=None, seed=0, threads=None, config=None, drop_nonfinite=false))]
#[allow(clippy::too_many_arguments)]
pub fn register(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    target: &Bound<'_, PyAny>,
    init: Option<&Bound<'_, PyAny>>,
    voxel: Option<f64>,
    seed: u64,
    threads: Option<usize>,
    config: Option<&Bound<'_, PyAny>>,
    drop_nonfinite: bool,
) -> PyResult<PyRegistration> {
    let start = Instant::now();
    let mut cfg: RegisterConfig = convert::config(config, "registration configuration")?;
    cfg.seed = seed;
    if voxel.is_some() {
        cfg.voxel = voxel;
    }
    cfg.validate().map_err(lib_err)?;
    let init = init
        .filter(|i| !i.is_none())
        .map(|i| convert::isometry(i, "init"))
        .transpose()?;
    let src_arg = cloud_arg(source, "source", drop_nonfinite)?;
    let tgt_arg = cloud_arg(target, "target", drop_nonfinite)?;
    let name = |a: &CloudArg| match a {
        CloudArg::File(p) => Some(p.display().to_string()),
        CloudArg::Points(_) => None,
    };
    let (src_name, tgt_name) = (name(&src_arg), name(&tgt_arg));
    let read_from_files =
        matches!(src_arg, CloudArg::File(_)) || matches!(tgt_arg, CloudArg::File(_));
    let outcome = pool::run(py, threads, move || -> depthcal::Result<_> {
        let t_read = Instant::now();
        let load = |a: CloudArg| match a {
            CloudArg::File(p) => depthcal::io::read_cloud(&p),
            CloudArg::Points(c) => Ok(c),
        };
        let source = load(src_arg)?;
        let target = load(tgt_arg)?;
        let read_ms = t_read.elapsed().as_secs_f64() * 1e3;
        let mut reg = depthcal::registration::register(&source, &target, init.as_ref(), &cfg)?;
        if read_from_files {
            reg.timings_ms.insert(0, ("read".into(), read_ms));
        }
        Ok((reg, [source.len(), target.len()]))
    })?;
    let (reg, points) = outcome.map_err(lib_err)?;
    let report = to_json(&depthcal::report::RegistrationReport::new(
        &reg,
        &depthcal::report::RegistrationInputs {
            source: src_name,
            target: tgt_name,
            points,
            seed,
            truth: None,
            total_ms: start.elapsed().as_secs_f64() * 1e3,
        },
    ))?;
    Ok(PyRegistration { reg, report })
}

/// A report as a JSON value (what the command line prints with `--json`).
pub fn to_json<T: serde::Serialize>(report: &T) -> PyResult<serde_json::Value> {
    serde_json::to_value(report)
        .map_err(|e| crate::errors::new_err(Kind::Failed, format!("the report: {e}")))
}
