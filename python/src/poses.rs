//! Pose conversions (KUKA XYZ-ABC, UR, ABB, Fanuc, x,y,z + quaternion, 4x4 matrices), pose files, and
//! the calibrated transform in the formats robot controllers and ROS read.

use crate::convert;
use crate::errors::{input_err, lib_err};
use depthcal::geometry::pose::{
    isometry_to_abb, isometry_to_fanuc, isometry_to_ur, isometry_to_xyzquat, KukaPose,
};
use depthcal::geometry::robot_formats::{
    ros2_static_tf_command, transform_files as lib_transform_files, Frames,
};
use depthcal::geometry::transform::isometry_to_rows;
use depthcal::io::poses::{PoseFormat, PoseRecord};
use nalgebra::Isometry3;
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A pose format by name (`kuka`, `matrix`, `xyzquat`, `ur`, `abb`, `fanuc` and their aliases).
pub fn format(name: &str) -> PyResult<PoseFormat> {
    name.parse::<PoseFormat>().map_err(input_err)
}

/// The numbers of `t` in `f` (the same values the pose files hold, before rounding to text).
fn values(f: PoseFormat, t: &Isometry3<f64>) -> Vec<f64> {
    match f {
        PoseFormat::Kuka => {
            let k = KukaPose::from_isometry(t);
            vec![k.x_mm, k.y_mm, k.z_mm, k.a_deg, k.b_deg, k.c_deg]
        }
        PoseFormat::Matrix => isometry_to_rows(t).to_vec(),
        PoseFormat::Xyzquat => isometry_to_xyzquat(t).to_vec(),
        PoseFormat::Ur => isometry_to_ur(t).to_vec(),
        PoseFormat::Abb => isometry_to_abb(t).to_vec(),
        PoseFormat::Fanuc => isometry_to_fanuc(t).to_vec(),
    }
}

/// Converts pose values to 4x4 matrices (metres).
///
/// ``values`` is one pose (a vector) or an (N, k) array of poses in ``format``: ``kuka``
/// (x_mm, y_mm, z_mm, a_deg, b_deg, c_deg; ``R = Rz(A) Ry(B) Rx(C)``), ``ur`` (x, y, z in metres, rx, ry,
/// rz rotation vector in radians), ``abb`` (x_mm, y_mm, z_mm, q1..q4 = w, x, y, z), ``fanuc`` (x_mm, y_mm,
/// z_mm, w_deg, p_deg, r_deg; ``R = Rz(r) Ry(p) Rx(w)``), ``xyzquat`` (x, y, z in metres, qx, qy, qz, qw)
/// or ``matrix`` (16 numbers row-major). Returns a (4, 4) float64 array for one pose, (N, 4, 4) for N.
/// Quaternions must have unit norm within 1e-3; matrices must be rigid.
#[pyfunction]
#[pyo3(signature = (values, format))]
pub fn pose_to_matrix<'py>(
    py: Python<'py>,
    values: &Bound<'py, PyAny>,
    format: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let f = self::format(format)?;
    let (rows, single) = convert::value_rows(values, "values", f.value_count())?;
    let mut out = Vec::with_capacity(rows.len());
    for (i, r) in rows.iter().enumerate() {
        let t = f.parse_values(r).map_err(|m| {
            input_err(if single {
                format!("{f} pose: {m}")
            } else {
                format!("{f} pose {i}: {m}")
            })
        })?;
        out.push(t);
    }
    Ok(if single {
        convert::matrix4(py, &out[0]).into_any()
    } else {
        convert::matrix4_stack(py, &out).into_any()
    })
}

/// Converts 4x4 rigid matrices (metres) to pose values in ``format`` (see :func:`pose_to_matrix`).
///
/// ``matrix`` is (4, 4) or (N, 4, 4); returns a vector or an (N, k) array. KUKA / Fanuc angles come back
/// in (-180, 180] (B / P in [-90, 90], C / W = 0 at gimbal lock); quaternions with ``w >= 0``; the UR
/// rotation vector with its angle in [0, pi].
#[pyfunction]
#[pyo3(signature = (matrix, format))]
pub fn matrix_to_pose<'py>(
    py: Python<'py>,
    matrix: &Bound<'py, PyAny>,
    format: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let f = self::format(format)?;
    let a = convert::as_ndarray(matrix, "matrix")?;
    use numpy::PyUntypedArrayMethods;
    if a.ndim() == 2 {
        let t = convert::isometry(matrix, "matrix")?;
        return Ok(PyArray1::from_vec(py, values(f, &t)).into_any());
    }
    let ts = convert::isometries(matrix, "matrix")?;
    let rows: Vec<Vec<f64>> = ts.iter().map(|t| values(f, t)).collect();
    if rows.is_empty() {
        return Ok(PyArray2::<f64>::zeros(py, [0, f.value_count()], false).into_any());
    }
    Ok(PyArray2::from_vec2(py, &rows)
        .map_err(|e| input_err(e.to_string()))?
        .into_any())
}

/// Reads a pose CSV file (a header, then ``frame,values...`` rows; blank lines and ``#`` comments
/// skipped). ``format`` is taken from the header when None.
///
/// Returns ``(frame_ids, poses)``: a list of str and an (N, 4, 4) float64 array (metres).
#[pyfunction]
#[pyo3(signature = (path, format=None))]
pub fn read_poses<'py>(
    py: Python<'py>,
    path: &Bound<'py, PyAny>,
    format: Option<&str>,
) -> PyResult<(Vec<String>, Bound<'py, PyAny>)> {
    let p = convert::path(path, "path")?;
    let f = format.map(self::format).transpose()?;
    let (_, records) = depthcal::io::poses::read_poses(&p, f).map_err(lib_err)?;
    let ids = records.iter().map(|r| r.frame.clone()).collect();
    let poses: Vec<Isometry3<f64>> = records.iter().map(|r| r.pose).collect();
    Ok((ids, convert::matrix4_stack(py, &poses).into_any()))
}

/// Writes a pose CSV file atomically: ``poses`` (N, 4, 4) rigid matrices in metres, written in ``format``
/// (fixed decimals: KUKA 6, ABB 6 and 12, the others 9). ``frame_ids`` default to "0", "1", ...
#[pyfunction]
#[pyo3(signature = (path, poses, format="kuka", frame_ids=None))]
pub fn write_poses(
    path: &Bound<'_, PyAny>,
    poses: &Bound<'_, PyAny>,
    format: &str,
    frame_ids: Option<Vec<String>>,
) -> PyResult<()> {
    let p = convert::path(path, "path")?;
    let f = self::format(format)?;
    let ts = convert::isometries(poses, "poses")?;
    let ids = frame_ids_or_default(frame_ids, ts.len(), "poses")?;
    let records: Vec<PoseRecord> = ts
        .into_iter()
        .zip(ids)
        .map(|(pose, frame)| PoseRecord {
            frame,
            pose,
            line: 0,
        })
        .collect();
    depthcal::io::poses::write_poses(&p, &records, f).map_err(lib_err)
}

/// The frame ids given (one per pose, non-empty, unique) or "0", "1", ...
pub fn frame_ids_or_default(
    ids: Option<Vec<String>>,
    n: usize,
    what: &str,
) -> PyResult<Vec<String>> {
    let Some(ids) = ids else {
        return Ok((0..n).map(|i| i.to_string()).collect());
    };
    if ids.len() != n {
        return Err(input_err(format!(
            "frame_ids: {} ids for {n} {what}; give one per pose",
            ids.len()
        )));
    }
    let mut seen = std::collections::HashSet::new();
    for id in &ids {
        if id.trim().is_empty() {
            return Err(input_err("frame_ids: an id is empty"));
        }
        if !seen.insert(id.as_str()) {
            return Err(input_err(format!("frame_ids: {id:?} appears twice")));
        }
    }
    Ok(ids)
}

/// The ROS 2 command line that publishes ``T_parent_child`` (4x4, metres) as a static transform:
/// ``ros2 run tf2_ros static_transform_publisher --x .. --qw .. --frame-id PARENT --child-frame-id CHILD``
/// (6 decimals of metres, 8 of the unit quaternion), as ``depthcal calibrate`` prints it.
#[pyfunction]
#[pyo3(signature = (transform, parent, child))]
pub fn ros2_static_transform(
    transform: &Bound<'_, PyAny>,
    parent: &str,
    child: &str,
) -> PyResult<String> {
    let t = convert::isometry(transform, "transform")?;
    let f = Frames::new(parent, child).map_err(lib_err)?;
    Ok(ros2_static_tf_command(&t, &f))
}

/// The files ``depthcal calibrate --output DIR`` writes for robots and ROS, as a dict of file name to
/// text: ``T_base1_base2.txt`` (4x4), ``static_tf.launch.py`` (ROS 2 launch file), ``base_joint.urdf.xacro``
/// (URDF fixed joint), ``tf.yaml``, ``kuka_base.txt`` (KUKA FRAME, mm and degrees), ``ur_pose.txt``
/// (URScript pose), ``abb_wobj.txt`` (RAPID wobjdata). ``transform`` is ``T_parent_child`` (metres);
/// ``parent`` and ``child`` are frame ids (1-256 of letters, digits and ``_ - . /``).
#[pyfunction]
#[pyo3(signature = (transform, parent, child))]
pub fn transform_files<'py>(
    py: Python<'py>,
    transform: &Bound<'py, PyAny>,
    parent: &str,
    child: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let t = convert::isometry(transform, "transform")?;
    let f = Frames::new(parent, child).map_err(lib_err)?;
    let d = PyDict::new(py);
    for (name, text) in lib_transform_files(&t, &f) {
        d.set_item(name, text)?;
    }
    Ok(d)
}
