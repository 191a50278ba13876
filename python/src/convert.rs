//! Conversions between NumPy arrays / Python objects and the library's types, with the checks that turn
//! bad input into [`crate::errors::Kind::Input`] exceptions: shapes, dtypes, NaN and infinite values.
//! Arrays of any memory layout (C, Fortran, strided views) are accepted; they are copied once into the
//! library's layout.

use crate::errors::{input_err, lib_err};
use depthcal::geometry::transform::{isometry_from_rows, isometry_to_rows};
use nalgebra::{Isometry3, Matrix6};
use numpy::ndarray::{ArrayView2, Axis};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};
use std::path::PathBuf;

/// `obj` as a NumPy array: arrays as they are, anything else through `numpy.asarray` (lists, Open3D's
/// `Vector3dVector`, ...).
pub fn as_ndarray<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
) -> PyResult<Bound<'py, PyUntypedArray>> {
    if let Ok(a) = obj.cast::<PyUntypedArray>() {
        return Ok(a.clone());
    }
    let np = obj.py().import("numpy")?;
    let a = np.getattr("asarray")?.call1((obj,)).map_err(|e| {
        input_err(format!(
            "{what}: expected a NumPy array, got {} ({e})",
            type_name(obj)
        ))
    })?;
    a.cast_into::<PyUntypedArray>().map_err(|_| {
        input_err(format!(
            "{what}: expected a NumPy array, got {}",
            type_name(obj)
        ))
    })
}

/// The Python type name of `obj`.
pub fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// `(3, 100)`-style text of a shape.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The dtype name of an array (`float32`, `int64`, ...).
pub fn dtype_name(a: &Bound<'_, PyUntypedArray>) -> String {
    a.dtype()
        .getattr("name")
        .and_then(|n| n.extract::<String>())
        .unwrap_or_else(|_| "?".into())
}

/// Checks that `a` is `(N, 3)`; the error names `what`, the shape found, and a hint for a transposed array.
fn check_n3(a: &Bound<'_, PyUntypedArray>, what: &str) -> PyResult<usize> {
    let shape = a.shape();
    if shape.len() == 2 && shape[1] == 3 {
        return Ok(shape[0]);
    }
    let hint = match shape {
        [3, n] if *n != 3 => " (it looks transposed: pass arr.T)",
        [3] => " (a single point: pass arr.reshape(1, 3))",
        [n] if n % 3 == 0 && *n > 0 => " (a flat array: pass arr.reshape(-1, 3))",
        _ => "",
    };
    Err(input_err(format!(
        "{what}: expected an (N, 3) array, got shape {}{hint}",
        shape_text(shape)
    )))
}

fn rows_f32<T: Copy + Into<f64>>(v: ArrayView2<'_, T>) -> Vec<[f32; 3]> {
    if let Some(s) = v.as_slice() {
        return s
            .chunks_exact(3)
            .map(|c| [c[0].into() as f32, c[1].into() as f32, c[2].into() as f32])
            .collect();
    }
    v.axis_iter(Axis(0))
        .map(|r| [r[0].into() as f32, r[1].into() as f32, r[2].into() as f32])
        .collect()
}

/// Copies an `(N, 3)` float32/float64 array into `f32` rows (float64 is rounded to float32, as the file
/// readers do).
fn float_rows(a: &Bound<'_, PyUntypedArray>, what: &str) -> PyResult<Vec<[f32; 3]>> {
    check_n3(a, what)?;
    if let Ok(x) = a.cast::<PyArray2<f32>>() {
        return Ok(rows_f32(x.readonly().as_array()));
    }
    if let Ok(x) = a.cast::<PyArray2<f64>>() {
        return Ok(rows_f32(x.readonly().as_array()));
    }
    Err(input_err(format!(
        "{what}: expected a float32 or float64 array, got dtype {}; convert it with \
         arr.astype(np.float64)",
        dtype_name(a)
    )))
}

/// Fails when a row has a NaN or infinite value (after rounding to float32: 1e300 is infinite there).
fn check_finite(rows: &[[f32; 3]], what: &str) -> PyResult<()> {
    let bad = |p: &[f32; 3]| p.iter().any(|v| !v.is_finite());
    if let Some(first) = rows.iter().position(bad) {
        let n = rows.iter().filter(|p| bad(p)).count();
        return Err(input_err(format!(
            "{what}: {n} of {} rows have NaN or infinite values (the first is row {first}); drop them \
             first, e.g. arr[np.isfinite(arr).all(axis=1)], or pass drop_nonfinite=True where offered",
            rows.len()
        )));
    }
    Ok(())
}

/// The points of an `(N, 3)` float32/float64 array-like, checked finite unless `allow_nonfinite`.
pub fn points(
    obj: &Bound<'_, PyAny>,
    what: &str,
    allow_nonfinite: bool,
) -> PyResult<Vec<[f32; 3]>> {
    let a = as_ndarray(obj, what)?;
    let rows = float_rows(&a, what)?;
    if !allow_nonfinite {
        check_finite(&rows, what)?;
    }
    Ok(rows)
}

/// Unit normals, `(N, 3)` float32/float64, finite, `n` rows.
pub fn normals(obj: &Bound<'_, PyAny>, what: &str, n: usize) -> PyResult<Vec<[f32; 3]>> {
    let rows = points(obj, what, false)?;
    if rows.len() != n {
        return Err(input_err(format!(
            "{what}: {} rows for {n} points; give one normal per point",
            rows.len()
        )));
    }
    Ok(rows)
}

/// RGB colours, `(N, 3)`: uint8 (0-255), integers in 0-255, or floats in [0, 1] (Open3D's convention,
/// scaled by 255 and rounded).
pub fn colors(obj: &Bound<'_, PyAny>, what: &str, n: usize) -> PyResult<Vec<[u8; 3]>> {
    let a = as_ndarray(obj, what)?;
    let rows = check_n3(&a, what)?;
    if rows != n {
        return Err(input_err(format!(
            "{what}: {rows} rows for {n} points; give one colour per point"
        )));
    }
    if let Ok(x) = a.cast::<PyArray2<u8>>() {
        let v = x.readonly();
        return Ok(v
            .as_array()
            .axis_iter(Axis(0))
            .map(|r| [r[0], r[1], r[2]])
            .collect());
    }
    let kind: String = a.dtype().getattr("kind")?.extract()?;
    match kind.as_str() {
        "f" => {
            let np = a.py().import("numpy")?;
            let f = np
                .getattr("asarray")?
                .call1((a, "float64"))?
                .cast_into::<PyArray2<f64>>()?;
            let v = f.readonly();
            let mut out = Vec::with_capacity(n);
            for r in v.as_array().axis_iter(Axis(0)) {
                let mut c = [0u8; 3];
                for k in 0..3 {
                    let x = r[k];
                    if !(0.0..=1.0).contains(&x) {
                        return Err(input_err(format!(
                            "{what}: float colours must be in [0, 1] (found {x}); give uint8 values \
                             0-255 or floats 0-1"
                        )));
                    }
                    c[k] = (x * 255.0).round() as u8;
                }
                out.push(c);
            }
            Ok(out)
        }
        "i" | "u" => {
            let np = a.py().import("numpy")?;
            let f = np
                .getattr("asarray")?
                .call1((a, "int64"))?
                .cast_into::<PyArray2<i64>>()?;
            let v = f.readonly();
            let mut out = Vec::with_capacity(n);
            for r in v.as_array().axis_iter(Axis(0)) {
                let mut c = [0u8; 3];
                for k in 0..3 {
                    c[k] = u8::try_from(r[k]).map_err(|_| {
                        input_err(format!(
                            "{what}: integer colours must be in 0-255 (found {})",
                            r[k]
                        ))
                    })?;
                }
                out.push(c);
            }
            Ok(out)
        }
        _ => Err(input_err(format!(
            "{what}: expected uint8 (0-255) or float (0-1) colours, got dtype {}",
            dtype_name(&a)
        ))),
    }
}

/// A real-valued array-like as float64 (integers accepted); other dtypes are errors naming `what`.
fn float64_array<'py>(obj: &Bound<'py, PyAny>, what: &str) -> PyResult<Bound<'py, PyUntypedArray>> {
    let a = as_ndarray(obj, what)?;
    let kind: String = a.dtype().getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(input_err(format!(
            "{what}: expected a real-valued (float) array, got dtype {}",
            dtype_name(&a)
        )));
    }
    let np = obj.py().import("numpy")?;
    let f = np.getattr("asarray")?.call1((a, "float64"))?;
    Ok(f.cast_into::<PyUntypedArray>()?)
}

/// A rigid 4x4 matrix (array-like, row-major as NumPy shows it), checked by the library's validator
/// (`isometry_from_rows`: finite, bottom row 0 0 0 1, a proper rotation).
pub fn isometry(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Isometry3<f64>> {
    let a = float64_array(obj, what)?;
    if a.shape() != [4, 4] {
        return Err(input_err(format!(
            "{what}: expected a 4x4 matrix, got shape {}",
            shape_text(a.shape())
        )));
    }
    let x = a.cast::<PyArray2<f64>>()?.readonly();
    let v = x.as_array();
    let mut m = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            m[r * 4 + c] = v[[r, c]];
        }
    }
    isometry_from_rows(&m, what).map_err(lib_err)
}

/// A stack of rigid 4x4 matrices, `(N, 4, 4)` (a single `(4, 4)` is a stack of one); each is checked and
/// named `what[i]` in errors.
pub fn isometries(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Isometry3<f64>>> {
    let a = float64_array(obj, what)?;
    let shape = a.shape().to_vec();
    if shape.len() != 3 || shape[1] != 4 || shape[2] != 4 {
        return Err(input_err(format!(
            "{what}: expected an (N, 4, 4) array of 4x4 matrices, got shape {}",
            shape_text(&shape)
        )));
    }
    let x = a.cast::<numpy::PyArray3<f64>>()?.readonly();
    let v = x.as_array();
    let mut out = Vec::with_capacity(shape[0]);
    for i in 0..shape[0] {
        let mut m = [0.0; 16];
        for r in 0..4 {
            for c in 0..4 {
                m[r * 4 + c] = v[[i, r, c]];
            }
        }
        out.push(isometry_from_rows(&m, &format!("{what}[{i}]")).map_err(lib_err)?);
    }
    Ok(out)
}

/// Rows of `k` numbers: a `(k,)` vector (returned as one row, `single` true) or an `(N, k)` array.
pub fn value_rows(obj: &Bound<'_, PyAny>, what: &str, k: usize) -> PyResult<(Vec<Vec<f64>>, bool)> {
    let a = float64_array(obj, what)?;
    let shape = a.shape().to_vec();
    match shape.as_slice() {
        [n] if *n == k => {
            let x = a.cast::<PyArray1<f64>>()?.readonly();
            Ok((vec![x.as_array().to_vec()], true))
        }
        [_, n] if *n == k => {
            let x = a.cast::<PyArray2<f64>>()?.readonly();
            Ok((
                x.as_array()
                    .axis_iter(Axis(0))
                    .map(|r| r.to_vec())
                    .collect(),
                false,
            ))
        }
        _ => Err(input_err(format!(
            "{what}: expected {k} numbers or an (N, {k}) array, got shape {}",
            shape_text(&shape)
        ))),
    }
}

/// A 4x4 float64 array of an isometry.
pub fn matrix4<'py>(py: Python<'py>, t: &Isometry3<f64>) -> Bound<'py, PyArray2<f64>> {
    let m = isometry_to_rows(t);
    let v: Vec<Vec<f64>> = m.chunks(4).map(|r| r.to_vec()).collect();
    // Four rows of four: from_vec2 cannot fail.
    PyArray2::from_vec2(py, &v).unwrap_or_else(|_| PyArray2::zeros(py, [4, 4], false))
}

/// An `(N, 4, 4)` float64 array of isometries.
pub fn matrix4_stack<'py>(py: Python<'py>, ts: &[Isometry3<f64>]) -> Bound<'py, PyArray3<f64>> {
    let mut flat = Vec::with_capacity(ts.len() * 16);
    for t in ts {
        flat.extend_from_slice(&isometry_to_rows(t));
    }
    let arr = numpy::ndarray::Array3::from_shape_vec((ts.len(), 4, 4), flat)
        .unwrap_or_else(|_| numpy::ndarray::Array3::zeros((0, 4, 4)));
    PyArray3::from_owned_array(py, arr)
}

/// A 6x6 float64 array.
pub fn matrix6<'py>(py: Python<'py>, m: &Matrix6<f64>) -> Bound<'py, PyArray2<f64>> {
    let arr = numpy::ndarray::Array2::from_shape_fn((6, 6), |(r, c)| m[(r, c)]);
    PyArray2::from_owned_array(py, arr)
}

/// An `(N, 3)` array of `f32` rows (float32) without an intermediate copy beyond the one into NumPy.
pub fn rows_f32_array<'py>(py: Python<'py>, rows: &[[f32; 3]]) -> Bound<'py, PyArray2<f32>> {
    let flat: Vec<f32> = rows.iter().flatten().copied().collect();
    let arr = numpy::ndarray::Array2::from_shape_vec((rows.len(), 3), flat)
        .unwrap_or_else(|_| numpy::ndarray::Array2::zeros((0, 3)));
    PyArray2::from_owned_array(py, arr)
}

/// An `(N, 3)` uint8 array of colours.
pub fn rows_u8_array<'py>(py: Python<'py>, rows: &[[u8; 3]]) -> Bound<'py, PyArray2<u8>> {
    let flat: Vec<u8> = rows.iter().flatten().copied().collect();
    let arr = numpy::ndarray::Array2::from_shape_vec((rows.len(), 3), flat)
        .unwrap_or_else(|_| numpy::ndarray::Array2::zeros((0, 3)));
    PyArray2::from_owned_array(py, arr)
}

/// A JSON value as plain Python objects (dict, list, str, int, float, bool, None).
pub fn json_to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => PyBool::new(py, *b).to_owned().into_any(),
        Value::Number(n) => {
            if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any()
            } else if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any()
            } else {
                n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any()
            }
        }
        Value::String(s) => PyString::new(py, s).into_any(),
        Value::Array(a) => {
            let items = a
                .iter()
                .map(|x| json_to_py(py, x))
                .collect::<PyResult<Vec<_>>>()?;
            PyList::new(py, items)?.into_any()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, json_to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}

/// Plain Python objects (dict, list, tuple, str, int, float, bool, None, NumPy scalars and arrays) as a
/// JSON value; `path` names the position in errors (`config["icp"]["kernel"]`).
pub fn py_to_json(obj: &Bound<'_, PyAny>, path: &str) -> PyResult<serde_json::Value> {
    use serde_json::Value;
    if obj.is_none() {
        return Ok(Value::Null);
    }
    if let Ok(b) = obj.cast::<PyBool>() {
        return Ok(Value::Bool(b.is_true()));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(Value::String(s.to_cow()?.to_string()));
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut m = serde_json::Map::new();
        for (k, v) in d.iter() {
            let key: String = k.extract().map_err(|_| {
                crate::errors::new_err(
                    crate::errors::Kind::Config,
                    format!("{path}: keys must be strings, got {}", type_name(&k)),
                )
            })?;
            let sub = format!("{path}[{key:?}]");
            m.insert(key, py_to_json(&v, &sub)?);
        }
        return Ok(Value::Object(m));
    }
    if obj.cast::<PyList>().is_ok() || obj.cast::<PyTuple>().is_ok() {
        let mut out = Vec::new();
        for (i, x) in obj.try_iter()?.enumerate() {
            out.push(py_to_json(&x?, &format!("{path}[{i}]"))?);
        }
        return Ok(Value::Array(out));
    }
    if obj.cast::<PyUntypedArray>().is_ok() {
        let list = obj.call_method0("tolist")?;
        return py_to_json(&list, path);
    }
    let is_int = obj.cast::<PyInt>().is_ok() || obj.hasattr("__index__")?;
    if is_int {
        if let Ok(u) = obj.extract::<u64>() {
            return Ok(Value::from(u));
        }
        if let Ok(i) = obj.extract::<i64>() {
            return Ok(Value::from(i));
        }
    }
    if obj.cast::<PyFloat>().is_ok() || obj.hasattr("__float__")? {
        let f: f64 = obj.extract()?;
        return serde_json::Number::from_f64(f)
            .map(Value::Number)
            .ok_or_else(|| {
                crate::errors::new_err(
                    crate::errors::Kind::Config,
                    format!("{path}: {f} is not a valid configuration value (NaN or infinite)"),
                )
            });
    }
    Err(crate::errors::new_err(
        crate::errors::Kind::Config,
        format!(
            "{path}: a {} cannot be a configuration value (use dict, list, str, int, float, bool or None)",
            type_name(obj)
        ),
    ))
}

/// A configuration `T`: the defaults, with `config` (a dict, or a JSON object as text) merged over them
/// the way the command line merges `--config FILE` ([`depthcal::config_json`]).
pub fn config<T>(config: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<T>
where
    T: serde::de::DeserializeOwned + serde::Serialize + Default,
{
    let Some(c) = config.filter(|c| !c.is_none()) else {
        return Ok(T::default());
    };
    let value = if let Ok(s) = c.cast::<PyString>() {
        serde_json::from_str(&s.to_cow()?).map_err(|e| {
            crate::errors::new_err(
                crate::errors::Kind::Config,
                format!("config: not a valid {what}: {e}"),
            )
        })?
    } else if c.cast::<PyDict>().is_ok() {
        py_to_json(c, "config")?
    } else {
        return Err(crate::errors::new_err(
            crate::errors::Kind::Config,
            format!(
                "config: expected a dict (or a JSON object as a str) of {what} fields, got {}",
                type_name(c)
            ),
        ));
    };
    depthcal::config_json::config_from_value(value).map_err(|e| {
        crate::errors::new_err(
            crate::errors::Kind::Config,
            format!("config: not a valid {what}: {e}"),
        )
    })
}

/// A path from a `str` or an `os.PathLike`, or `None` when `obj` is neither.
pub fn path_like(obj: &Bound<'_, PyAny>) -> Option<PathBuf> {
    if obj.cast::<PyString>().is_ok() || obj.hasattr("__fspath__").unwrap_or(false) {
        obj.extract::<PathBuf>().ok()
    } else {
        None
    }
}

/// A required path argument.
pub fn path(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<PathBuf> {
    path_like(obj).ok_or_else(|| {
        input_err(format!(
            "{what}: expected a path (str or os.PathLike), got {}",
            type_name(obj)
        ))
    })
}
