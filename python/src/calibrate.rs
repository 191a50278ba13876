//! `calibrate`: robot-to-robot calibration of a cell dataset, the way `depthcal calibrate` does it.

use crate::convert;
use crate::errors::{input_err, lib_err, untrusted_err};
use crate::pool;
use crate::register::to_json;
use depthcal::calibration::initializer::UserGuess;
use depthcal::calibration::multi_robot::calibrate_robots;
use depthcal::calibration::robot_to_robot::{
    calibrate_request, CalibrateConfig, CalibrateRequest, Calibration,
};
use depthcal::cell::Cell;
use depthcal::geometry::robot_formats::{
    robot_transform_files, ros2_static_tf_command, transform_files, Frames, RobotOutput,
};
use depthcal::methods::{calibrate_with_method, Method, MethodInputs};
use depthcal::report::CalibrationReport;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::time::Instant;

/// The result of :func:`calibrate`: ``T_base1_base2``, the pose of the other robot's base in the
/// reference robot's base (``p_base1 = transform @ [p_base2, 1]``, metres), its uncertainty, quality and
/// verdict. ``to_dict()`` equals the JSON of ``depthcal calibrate --json``.
#[pyclass(module = "depthcal", name = "Calibration", frozen)]
pub struct PyCalibration {
    c: Calibration,
    frames: Frames,
    report: serde_json::Value,
    /// A cell of three or more robots: every robot but the reference.
    robots: Option<Vec<OtherRobot>>,
}

/// A robot of a cell of three or more robots, as the joint solution gives it.
struct OtherRobot {
    name: String,
    /// `T_reference_robot`; `None` when it is not calibrated.
    transform: Option<nalgebra::Isometry3<f64>>,
    frames: Frames,
}

#[pymethods]
impl PyCalibration {
    /// 4x4 float64 ``T_base1_base2`` (metres): maps the other robot's base coordinates into the reference
    /// robot's base.
    #[getter]
    fn transform<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix4(py, &self.c.transform)
    }
    /// The reference robot's name (base1).
    #[getter]
    fn reference(&self) -> String {
        self.c.reference.clone()
    }
    /// The other robot's name (base2).
    #[getter]
    fn other(&self) -> String {
        self.c.other.clone()
    }
    /// The initialiser used (``depth``, ``guess``, ...).
    #[getter]
    fn method(&self) -> String {
        self.c.method.clone()
    }
    /// 6x6 covariance of ``[rx, ry, rz (rad), tx, ty, tz (m)]``, a left increment in the reference base
    /// frame, including what the hand-eyes, pose repeatability and depth scale add.
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix6(py, &self.c.covariance)
    }
    /// 1-sigma per rotation axis, degrees (3 values).
    #[getter]
    fn sigma_deg<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v = (0..3)
            .map(|k| self.c.covariance[(k, k)].max(0.0).sqrt().to_degrees())
            .collect();
        PyArray1::from_vec(py, v)
    }
    /// 1-sigma per translation axis, millimetres (3 values).
    #[getter]
    fn sigma_mm<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let v = (3..6)
            .map(|k| self.c.covariance[(k, k)].max(0.0).sqrt() * 1e3)
            .collect();
        PyArray1::from_vec(py, v)
    }
    /// Fraction of the other robot's points with a reference point within the final correspondence
    /// distance (None when not refined).
    #[getter]
    fn fitness(&self) -> Option<f64> {
        self.c.fitness
    }
    /// RMS distance of those pairs, metres (None when not refined).
    #[getter]
    fn inlier_rmse(&self) -> Option<f64> {
        self.c.inlier_rmse
    }
    /// Overlap estimated by the trimmed ICP (None when not refined).
    #[getter]
    fn overlap(&self) -> Option<f64> {
        self.c.overlap
    }
    /// ICP met its tolerances.
    #[getter]
    fn converged(&self) -> bool {
        self.c.converged
    }
    /// Whether ICP refined the initial estimate.
    #[getter]
    fn refined(&self) -> bool {
        self.c.refined
    }
    /// Whether the result passed the quality gate (see ``reasons``).
    #[getter]
    fn trusted(&self) -> bool {
        self.c.trust.trusted
    }
    /// Why it is not trusted, one sentence each.
    #[getter]
    fn reasons(&self) -> Vec<String> {
        self.c.trust.reasons.clone()
    }
    /// What to try when it is not trusted.
    #[getter]
    fn suggestions(&self) -> Vec<String> {
        self.c.trust.suggestions.clone()
    }
    /// Things to know.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.c.warnings.clone()
    }
    /// Error against the cell's ``ground_truth.json`` as ``(degrees, millimetres)``, or None.
    #[getter]
    fn error_vs_truth(&self) -> Option<(f64, f64)> {
        self.c.error_vs_truth.map(|(r, t)| (r, t * 1e3))
    }
    /// The ROS 2 ``static_transform_publisher`` command line for the result.
    #[getter]
    fn ros2(&self) -> String {
        ros2_static_tf_command(&self.c.transform, &self.frames)
    }
    /// ``(parent, child)`` frame ids of the ROS outputs.
    #[getter]
    fn frame_ids(&self) -> (String, String) {
        (self.frames.parent.clone(), self.frames.child.clone())
    }
    /// Every robot but the reference: ``{name: 4x4 float64 T_<reference>_<robot>}`` (metres), ``None`` for a
    /// robot that is not calibrated. Two robots: the other robot's ``transform``. Three or more: the joint
    /// solution of every pair (docs/calibrate.md, "Cells of three or more robots"); ``to_dict()["robots"]`` and
    /// ``["pairs"]`` hold each robot's 1-sigma, verdict and reasons and each pair's own result.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        match &self.robots {
            None => d.set_item(&self.c.other, convert::matrix4(py, &self.c.transform))?,
            Some(rs) => {
                for r in rs {
                    d.set_item(
                        &r.name,
                        r.transform.as_ref().map(|t| convert::matrix4(py, t)),
                    )?;
                }
            }
        }
        Ok(d)
    }
    /// Wall time of each stage, milliseconds (a dict).
    #[getter]
    fn timings_ms<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report["timings_ms"])
    }
    /// The files of ``depthcal calibrate --output DIR`` for robots and ROS (see :func:`transform_files`):
    /// a dict of file name to text.
    fn transform_files<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        match &self.robots {
            None => {
                for (name, text) in transform_files(&self.c.transform, &self.frames) {
                    d.set_item(name, text)?;
                }
            }
            Some(rs) => {
                let outs: Vec<RobotOutput> = rs
                    .iter()
                    .filter_map(|r| {
                        Some(RobotOutput {
                            name: r.name.clone(),
                            transform: r.transform?,
                            frames: r.frames.clone(),
                        })
                    })
                    .collect();
                for (name, text) in robot_transform_files(&self.c.reference, &outs) {
                    d.set_item(name, text)?;
                }
            }
        }
        Ok(d)
    }
    /// Everything as plain Python objects (the JSON of ``depthcal calibrate --json``).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report)
    }
    /// Returns the result itself when it is trusted; raises ``UntrustedError`` with the reasons otherwise.
    fn check(slf: Bound<'_, Self>) -> PyResult<Bound<'_, Self>> {
        let c = slf.get();
        if c.c.trust.trusted {
            Ok(slf)
        } else {
            Err(untrusted_err(&c.c.trust.reasons))
        }
    }
    fn __repr__(&self) -> String {
        let v = self.c.transform.translation.vector;
        format!(
            "Calibration({} -> {}, method={:?}, trusted={}, xyz_m=[{:.4}, {:.4}, {:.4}], rotation_deg={:.3}{})",
            self.c.other,
            self.c.reference,
            self.c.method,
            if self.c.trust.trusted { "True" } else { "False" },
            v.x,
            v.y,
            v.z,
            self.c.transform.rotation.angle().to_degrees(),
            match self.c.error_vs_truth {
                Some((r, t)) => format!(", error_vs_truth=({r:.4} deg, {:.3} mm)", t * 1e3),
                None => String::new(),
            }
        )
    }
}

/// The frame ids: the arguments, else the robots' `frame` in cell.toml, else ROBOT_base.
fn frames(
    cell: &Cell,
    frame_id: Option<String>,
    child_frame_id: Option<String>,
) -> depthcal::Result<Frames> {
    let (r, o) = cell.robot_pair()?;
    let explicit = frame_id.is_some() || child_frame_id.is_some();
    let parent = frame_id.unwrap_or_else(|| cell.frame_id(&r.name));
    let child = child_frame_id.unwrap_or_else(|| cell.frame_id(&o.name));
    match Frames::new(&parent, &child) {
        Ok(f) => Ok(f),
        // As the command line: a robot name that makes no valid frame id is kept when only printed.
        Err(_) if !explicit => Ok(Frames { parent, child }),
        Err(e) => Err(e),
    }
}

/// Calibrates a cell: finds ``T_base1_base2``, the pose of the other robot's base in the reference
/// robot's base, as ``depthcal calibrate CELL_DIR`` does (fuse each robot's frames in its base frame,
/// initialise, refine with trimmed robust ICP, check and report).
///
/// Args:
///     cell_dir: the cell dataset directory (with ``cell.toml``).
///     method: the initialiser: ``depth`` (FPFH + RANSAC under the cell's priors), ``guess`` (from
///         ``init``), ``checkerboard`` (with ``board_poses``; finding boards in images, ``marker`` and
///         ``features`` need a depthcal built with OpenCV, which this package is not).
///     init: an initial ``T_base1_base2`` (4x4, metres, or the path of a matrix file or an earlier JSON
///         result); implies ``method="guess"``.
///     seed: seed of every randomised step; results are bit-identical for a seed at any thread count.
///     threads: worker threads for this call (default: all cores).
///     config: a dict of ``CalibrateConfig`` fields (e.g. ``{"max_range_factor": None}``) merged over the
///         defaults as ``depthcal calibrate --config`` merges its file.
///     priors: use the ``[priors]`` of cell.toml (False: ``--no-priors``).
///     refine: refine the initial estimate with ICP (False: ``--no-refine``).
///     frame_id, child_frame_id: base frame ids of the ROS outputs (default: the robots' ``frame`` in
///         cell.toml, else ``ROBOT_base``).
///     board_poses: with ``method="checkerboard"``: ``{robot: handeye_json_path}``.
///
/// Returns:
///     :class:`Calibration` with ``transform``, ``sigma_deg``, ``sigma_mm``, ``trusted``, ``reasons``,
///     ``ros2``, ``error_vs_truth``, ``transform_files()``, ``to_dict()``.
///
/// Raises:
///     FileError (OSError) / FormatError (ValueError): a missing or malformed cell; InputError: a bad
///     argument; ConfigError: a bad config. An untrusted result is returned, not raised (call ``check()``).
#[pyfunction]
#[pyo3(signature = (cell_dir, *, method="depth", init=None, seed=0, threads=None, config=None, priors=true, refine=true, frame_id=None, child_frame_id=None, board_poses=None))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate(
    py: Python<'_>,
    cell_dir: &Bound<'_, PyAny>,
    method: &str,
    init: Option<&Bound<'_, PyAny>>,
    seed: u64,
    threads: Option<usize>,
    config: Option<&Bound<'_, PyAny>>,
    priors: bool,
    refine: bool,
    frame_id: Option<String>,
    child_frame_id: Option<String>,
    board_poses: Option<std::collections::BTreeMap<String, PathBuf>>,
) -> PyResult<PyCalibration> {
    let start = Instant::now();
    let dir = convert::path(cell_dir, "cell_dir")?;
    let mut cfg: CalibrateConfig = convert::config(config, "calibrate configuration")?;
    cfg.seed = seed;
    cfg.use_priors = priors;
    cfg.validate().map_err(lib_err)?;
    // A path is the CLI's `--init FILE`; an array is a guess named "init".
    let (init_file, init_array) = match init.filter(|i| !i.is_none()) {
        None => (None, None),
        Some(i) => match convert::path_like(i) {
            Some(p) => (Some(p), None),
            None => (None, Some(convert::isometry(i, "init")?)),
        },
    };
    let method = if init_file.is_some() || init_array.is_some() {
        Method::Guess
    } else {
        Method::from_name(method).map_err(lib_err)?
    };
    if method == Method::Guess && init_file.is_none() && init_array.is_none() {
        return Err(input_err(
            "method=\"guess\" needs init= (a 4x4 matrix, or a matrix file or an earlier JSON result)",
        ));
    }
    let board_pose: Vec<(String, PathBuf)> = board_poses.unwrap_or_default().into_iter().collect();
    if !board_pose.is_empty() && method != Method::Checkerboard {
        return Err(input_err("board_poses is for method=\"checkerboard\""));
    }
    let cell_name = dir.display().to_string();
    let cell = py.detach(|| Cell::open(&dir)).map_err(lib_err)?;
    cell.ground_truth().map_err(lib_err)?;
    let frames = frames(&cell, frame_id, child_frame_id).map_err(lib_err)?;
    let inputs = MethodInputs {
        init: init_file,
        board_pose,
    };
    if cell.robots.len() > 2 {
        // Every base at once, as `depthcal calibrate` solves a cell of three or more robots.
        if method != Method::Depth || !refine {
            return Err(input_err(format!(
                "the cell names {} robots: cells of more than two robots are calibrated from depth (method=\"depth\", refine=True); init and the image methods give one pair",
                cell.robots.len()
            )));
        }
        let frame_ids = cell.other_frame_ids(&frames.child);
        let outcome = pool::run(py, threads, move || {
            let init = depthcal::methods::build(Method::Depth, &cell, &inputs, &cfg)?.0;
            calibrate_robots(&cell, init.as_ref(), &cfg, &mut |_| {})
        })?;
        let (cc, _fused) = outcome.map_err(lib_err)?;
        let total_ms = start.elapsed().as_secs_f64() * 1e3;
        let report = to_json(&CalibrationReport::with_robots(
            &cc, &cell_name, &frames, &frame_ids, total_ms,
        ))?;
        let robots = cc
            .robots
            .iter()
            .zip(&frame_ids)
            .map(|(r, id)| OtherRobot {
                name: r.name.clone(),
                transform: r.transform,
                frames: Frames {
                    parent: frames.parent.clone(),
                    child: id.clone(),
                },
            })
            .collect();
        return Ok(PyCalibration {
            c: cc.headline(),
            frames,
            report,
            robots: Some(robots),
        });
    }
    let outcome = pool::run(py, threads, move || match init_array {
        Some(transform) => {
            let guess = UserGuess {
                transform,
                source: "init".into(),
            };
            calibrate_request(CalibrateRequest {
                refine,
                ..CalibrateRequest::new(&cell, &guess, &cfg)
            })
        }
        None => calibrate_with_method(&cell, method, &inputs, &cfg, refine, &mut |_| {}),
    })?;
    let (c, _fused) = outcome.map_err(lib_err)?;
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let report = to_json(&CalibrationReport::new(&c, &cell_name, &frames, total_ms))?;
    Ok(PyCalibration {
        c,
        frames,
        report,
        robots: None,
    })
}
