//! Point clouds: `read_cloud`, `write_cloud` and the `PointCloud` class they return.

use crate::convert;
use crate::errors::lib_err;
use numpy::{PyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// A point cloud read from a file: `points` `(N, 3) float32` in the file's unit (metres by convention),
/// `normals` `(N, 3) float32` or None, `colors` `(N, 3) uint8` or None.
///
/// Wherever depthcal takes points it also takes a `PointCloud` (and `np.asarray(cloud)` gives its points).
#[pyclass(module = "depthcal", name = "PointCloud", frozen)]
pub struct PyPointCloud {
    points: Py<PyArray2<f32>>,
    normals: Option<Py<PyArray2<f32>>>,
    colors: Option<Py<PyArray2<u8>>>,
}

impl PyPointCloud {
    /// The Python object of a library cloud (one copy into NumPy per attribute).
    pub fn from_cloud(py: Python<'_>, c: &depthcal::PointCloud) -> Self {
        PyPointCloud {
            points: convert::rows_f32_array(py, &c.points).unbind(),
            normals: c
                .normals
                .as_ref()
                .map(|n| convert::rows_f32_array(py, n).unbind()),
            colors: c
                .colors
                .as_ref()
                .map(|n| convert::rows_u8_array(py, n).unbind()),
        }
    }
}

#[pymethods]
impl PyPointCloud {
    /// Builds a cloud from arrays: `points` (N, 3) float32/float64, optional `normals` (N, 3) and `colors`
    /// (N, 3) uint8 0-255 or float 0-1. Values are checked (shape, dtype, finite) and copied.
    #[new]
    #[pyo3(signature = (points, normals=None, colors=None))]
    fn new(
        py: Python<'_>,
        points: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
        colors: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let c = cloud_from_args(points, normals, colors, "points")?;
        Ok(PyPointCloud::from_cloud(py, &c))
    }

    /// Point positions, (N, 3) float32.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f32>> {
        self.points.bind(py).clone()
    }

    /// Unit normals, (N, 3) float32, or None when the file had none.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f32>>> {
        self.normals.as_ref().map(|n| n.bind(py).clone())
    }

    /// RGB colours, (N, 3) uint8, or None when the file had none.
    #[getter]
    fn colors<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<u8>>> {
        self.colors.as_ref().map(|n| n.bind(py).clone())
    }

    fn __len__(&self, py: Python<'_>) -> usize {
        self.points.bind(py).shape()[0]
    }

    #[pyo3(signature = (dtype=None, copy=None))]
    fn __array__<'py>(
        &self,
        py: Python<'py>,
        dtype: Option<&Bound<'py, PyAny>>,
        copy: Option<bool>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let p = self.points.bind(py).clone().into_any();
        let np = py.import("numpy")?;
        match (dtype, copy) {
            (None, Some(true)) => p.call_method0("copy"),
            (None, _) => Ok(p),
            (Some(d), _) => np.getattr("asarray")?.call1((p, d)),
        }
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "PointCloud({} points{}{})",
            self.points.bind(py).shape()[0],
            if self.normals.is_some() {
                ", normals"
            } else {
                ""
            },
            if self.colors.is_some() {
                ", colors"
            } else {
                ""
            }
        )
    }
}

/// A library cloud from `points` (a `PointCloud`, an Open3D cloud, or an (N, 3) array-like) and optional
/// normals and colours.
pub fn cloud_from_args(
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    colors: Option<&Bound<'_, PyAny>>,
    what: &str,
) -> PyResult<depthcal::PointCloud> {
    let mut c = cloud_from_py(points, what, false)?;
    if let Some(n) = normals.filter(|n| !n.is_none()) {
        c.normals = Some(convert::normals(n, &format!("{what} normals"), c.len())?);
    }
    if let Some(k) = colors.filter(|k| !k.is_none()) {
        c.colors = Some(convert::colors(k, &format!("{what} colors"), c.len())?);
    }
    Ok(c)
}

/// A library cloud from a `PointCloud` (with its normals and colours), an object with a `points` attribute
/// (an Open3D `PointCloud`: its points only), or an (N, 3) float32/float64 array-like.
pub fn cloud_from_py(
    obj: &Bound<'_, PyAny>,
    what: &str,
    allow_nonfinite: bool,
) -> PyResult<depthcal::PointCloud> {
    if let Ok(c) = obj.cast::<PyPointCloud>() {
        let c = c.get();
        let py = obj.py();
        let mut out = depthcal::PointCloud::from_points(convert::points(
            c.points.bind(py).as_any(),
            what,
            allow_nonfinite,
        )?);
        if let Some(n) = &c.normals {
            out.normals = Some(convert::points(n.bind(py).as_any(), what, true)?);
        }
        if let Some(k) = &c.colors {
            out.colors = Some(convert::colors(k.bind(py).as_any(), what, out.len())?);
        }
        return Ok(out);
    }
    let is_array = obj.cast::<numpy::PyUntypedArray>().is_ok();
    if !is_array && obj.hasattr("points").unwrap_or(false) {
        let p = obj.getattr("points")?;
        return Ok(depthcal::PointCloud::from_points(convert::points(
            &p,
            what,
            allow_nonfinite,
        )?));
    }
    Ok(depthcal::PointCloud::from_points(convert::points(
        obj,
        what,
        allow_nonfinite,
    )?))
}

/// Reads a point cloud file, choosing the format by its extension: ``.ply`` (ASCII, binary little/big
/// endian; float or double x, y, z; optional nx, ny, nz and red, green, blue), ``.pcd`` (ascii, binary,
/// binary_compressed), ``.xyz``/``.txt``/``.pts`` (x y z per line) or ``.npy`` (an N x 3 float32/float64
/// array).
///
/// Returns a :class:`PointCloud`: ``points`` (N, 3) float32 in the file's unit, ``normals`` and ``colors``
/// when the file has them. Points with NaN or infinite coordinates are kept as they are in the file.
///
/// Raises ``FileError`` (an ``OSError``) when the file cannot be read and ``FormatError`` (a
/// ``ValueError``) when its content is wrong; the message names the file.
#[pyfunction]
pub fn read_cloud(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<PyPointCloud> {
    let p = convert::path(path, "path")?;
    let c = py
        .detach(|| depthcal::io::read_cloud(&p))
        .map_err(lib_err)?;
    Ok(PyPointCloud::from_cloud(py, &c))
}

/// Writes a point cloud: ``.ply`` (binary little endian, with normals and colours when given) or
/// ``.xyz``/``.txt`` (x y z text), atomically (a temporary file in the same directory, then a rename).
///
/// ``points`` is an (N, 3) float32/float64 array (stored as float32), a :class:`PointCloud` or an Open3D
/// cloud; ``normals`` (N, 3) float; ``colors`` (N, 3) uint8 0-255 or float 0-1. Non-finite values are
/// errors (``InputError``).
#[pyfunction]
#[pyo3(signature = (path, points, normals=None, colors=None))]
pub fn write_cloud(
    py: Python<'_>,
    path: &Bound<'_, PyAny>,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    colors: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let p = convert::path(path, "path")?;
    let c = cloud_from_args(points, normals, colors, "points")?;
    py.detach(|| depthcal::io::write_cloud(&p, &c))
        .map_err(lib_err)
}
