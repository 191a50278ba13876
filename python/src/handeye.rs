//! `handeye`: `T_ee_cam` and `T_base_board` from robot poses and board poses seen by the camera.

use crate::convert;
use crate::errors::{input_err, lib_err};
use crate::pool;
use crate::poses::{format, frame_ids_or_default};
use crate::register::to_json;
use depthcal::calibration::handeye::{
    calibrate_hand_eye, frames_from_records, HandEyeConfig, HandEyeFrame, HandEyeMethod,
    HandEyeResult,
};
use numpy::PyArray2;
use pyo3::prelude::*;

/// The result of :func:`handeye`.
///
/// Eye-in-hand (the default): ``t_ee_cam`` is the camera in the flange frame, ``t_base_board`` the board
/// in the robot base. Eye-to-hand: they are ``T_ee_board`` and ``T_base_cam``. Metres; ``to_dict()``
/// equals the JSON of ``depthcal handeye --json``.
#[pyclass(module = "depthcal", name = "HandEye", frozen)]
pub struct PyHandEye {
    r: HandEyeResult,
    report: serde_json::Value,
}

#[pymethods]
impl PyHandEye {
    /// 4x4 float64 ``T_ee_cam`` (eye-to-hand: ``T_ee_board``), metres.
    #[getter]
    fn t_ee_cam<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix4(py, &self.r.t_ee_cam)
    }
    /// 4x4 float64 ``T_base_board`` (eye-to-hand: ``T_base_cam``), metres.
    #[getter]
    fn t_base_board<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix4(py, &self.r.t_base_board)
    }
    /// 1-sigma of ``t_ee_cam`` per axis, degrees (statistical; None without refinement).
    #[getter]
    fn sigma_deg(&self) -> Option<f64> {
        self.r.t_ee_cam_sigma.map(|s| s.rotation_deg)
    }
    /// 1-sigma of ``t_ee_cam`` per axis, millimetres (statistical; None without refinement).
    #[getter]
    fn sigma_mm(&self) -> Option<f64> {
        self.r.t_ee_cam_sigma.map(|s| s.translation_mm)
    }
    /// ``refined``, or the closed form's name without refinement.
    #[getter]
    fn method(&self) -> String {
        if self.r.refined {
            "refined".into()
        } else {
            self.r.method.name().into()
        }
    }
    /// Per frame: ``frame``, ``rotation_deg``, ``translation_mm``, ``normalized``, ``rejected`` (dicts).
    #[getter]
    fn residuals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report["residuals"])
    }
    /// Ids of the frames rejected as outliers.
    #[getter]
    fn rejected(&self) -> Vec<String> {
        self.r.rejected.clone()
    }
    /// Excitation, rejected frames, poor fit, failed closed forms.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.r.warnings.clone()
    }
    /// The refinement met its tolerances.
    #[getter]
    fn converged(&self) -> bool {
        self.r.converged
    }
    /// Everything as plain Python objects (the JSON of ``depthcal handeye --json``).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        convert::json_to_py(py, &self.report)
    }
    fn __repr__(&self) -> String {
        let v = self.r.t_ee_cam.translation.vector * 1e3;
        let s = &self.report["residual_summary"];
        format!(
            "HandEye(method={:?}, frames={}, rejected={}, t_ee_cam xyz_mm=[{:.3}, {:.3}, {:.3}], \
             rotation_deg={:.3}, residual_rms_deg={:.4}, residual_rms_mm={:.3})",
            self.method(),
            self.r.residuals.len(),
            self.r.rejected.len(),
            v.x,
            v.y,
            v.z,
            self.r.t_ee_cam.rotation.angle().to_degrees(),
            s["rotation_rms_deg"].as_f64().unwrap_or(f64::NAN),
            s["translation_rms_mm"].as_f64().unwrap_or(f64::NAN)
        )
    }
}

/// Hand-eye calibration: finds ``T_ee_cam`` (the camera in the flange frame) and ``T_base_board`` (the
/// fixed board in the robot base) such that every frame i satisfies
/// ``T_base_ee[i] @ T_ee_cam @ T_cam_board[i] = T_base_board``.
///
/// Args:
///     robot_poses: (N, 4, 4) flange poses ``T_base_ee`` in metres (OpenCV's ``gripper2base``), or the
///         path of a pose CSV file (``robot_format``, default KUKA XYZ-ABC).
///     target_poses: (N, 4, 4) board poses in the camera ``T_cam_board`` in metres (OpenCV's
///         ``target2cam``), or the path of a pose CSV file (``target_format``, default matrix); files are
///         matched to the robot file's rows by frame id.
///     method: closed form to start from: ``auto`` (the best fit), ``tsai``, ``park``, ``daniilidis``,
///         ``shah``, ``li``.
///     refine: jointly refine both transforms (robust Levenberg-Marquardt) and reject outlier frames; with
///         False the closed form is returned as it is.
///     eye_to_hand: the camera is fixed and the board is on the flange: the answer is then ``T_ee_board``
///         and ``T_base_cam`` (target poses are still ``T_cam_board``).
///     seed: seed of the least-median-of-squares search.
///     config: a dict of ``HandEyeConfig`` fields merged over the defaults.
///     frame_ids: names of the frames (arrays only; default "0", "1", ...).
///     threads: worker threads for this call (default: all cores).
///
/// Returns:
///     :class:`HandEye` with ``t_ee_cam``, ``t_base_board`` (4x4 float64), ``sigma_deg``, ``sigma_mm``,
///     ``residuals``, ``rejected``, ``warnings``, ``to_dict()``.
///
/// Raises:
///     InputError (ValueError): wrong shapes, non-rigid matrices, fewer than 3 frames, too little rotation,
///     mismatched units. FileError / FormatError: unreadable pose files.
#[pyfunction]
#[pyo3(signature = (robot_poses, target_poses, *, method="auto", refine=true, eye_to_hand=false, seed=0, config=None, frame_ids=None, robot_format="kuka", target_format="matrix", threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn handeye(
    py: Python<'_>,
    robot_poses: &Bound<'_, PyAny>,
    target_poses: &Bound<'_, PyAny>,
    method: &str,
    refine: bool,
    eye_to_hand: bool,
    seed: u64,
    config: Option<&Bound<'_, PyAny>>,
    frame_ids: Option<Vec<String>>,
    robot_format: &str,
    target_format: &str,
    threads: Option<usize>,
) -> PyResult<PyHandEye> {
    let mut cfg: HandEyeConfig = convert::config(config, "hand-eye configuration")?;
    cfg.method = method.parse::<HandEyeMethod>().map_err(input_err)?;
    cfg.refine = refine;
    cfg.seed = seed;
    let (rp, tp) = (
        convert::path_like(robot_poses),
        convert::path_like(target_poses),
    );
    let mut frames = match (&rp, &tp) {
        (Some(r), Some(t)) => {
            if frame_ids.is_some() {
                return Err(input_err(
                    "frame_ids: only for arrays; pose files name their frames",
                ));
            }
            let rf = format(robot_format)?;
            let tf = format(target_format)?;
            let (_, robot) = depthcal::io::poses::read_poses(r, Some(rf)).map_err(lib_err)?;
            let (_, target) = depthcal::io::poses::read_poses(t, Some(tf)).map_err(lib_err)?;
            frames_from_records(&robot, r, &target, t).map_err(lib_err)?
        }
        (None, None) => {
            let robot = convert::isometries(robot_poses, "robot_poses")?;
            let target = convert::isometries(target_poses, "target_poses")?;
            if robot.len() != target.len() {
                return Err(input_err(format!(
                    "robot_poses has {} poses and target_poses {}; give one board pose per robot pose",
                    robot.len(),
                    target.len()
                )));
            }
            let ids = frame_ids_or_default(frame_ids, robot.len(), "poses")?;
            ids.into_iter()
                .zip(robot.into_iter().zip(target))
                .map(|(id, (t_base_ee, t_cam_board))| HandEyeFrame {
                    id,
                    t_base_ee,
                    t_cam_board,
                })
                .collect()
        }
        _ => {
            return Err(input_err(
                "robot_poses and target_poses: give two arrays or two pose file paths",
            ))
        }
    };
    if eye_to_hand {
        for f in &mut frames {
            f.t_cam_board = f.t_cam_board.inverse();
        }
    }
    let r = pool::run(py, threads, move || calibrate_hand_eye(&frames, &cfg))?.map_err(lib_err)?;
    let report = to_json(&depthcal::report::HandEyeReport::new(
        &r,
        &depthcal::report::HandEyeInputs {
            eye_to_hand,
            robot_poses: rp
                .map(|p| p.display().to_string())
                .unwrap_or_else(|| "<array>".into()),
            target_poses: Some(
                tp.map(|p| p.display().to_string())
                    .unwrap_or_else(|| "<array>".into()),
            ),
            images: None,
        },
    ))?;
    Ok(PyHandEye { r, report })
}
