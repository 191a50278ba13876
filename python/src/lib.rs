//! Python bindings of depthcal: `import depthcal`, NumPy arrays in and out.
//!
//! The compiled module `depthcal._depthcal`; the pure-Python package `depthcal` (python/depthcal)
//! re-exports it and adds the named pose conversions. Every long call releases the GIL and runs on a
//! thread pool of the size asked for (`threads=`); results are bit-identical to the command line's for the
//! same inputs and seed.

use pyo3::prelude::*;

mod calibrate;
mod cloud;
mod convert;
mod errors;
mod fuse;
mod handeye;
mod pool;
mod poses;
mod profile;
mod register;
mod simulate;

/// depthcal's compiled core (use the package ``depthcal``, which re-exports it).
#[pymodule]
fn _depthcal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    errors::add_to_module(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<cloud::PyPointCloud>()?;
    m.add_class::<register::PyRegistration>()?;
    m.add_class::<calibrate::PyCalibration>()?;
    m.add_class::<handeye::PyHandEye>()?;
    m.add_function(wrap_pyfunction!(cloud::read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(cloud::write_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(register::register, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(handeye::handeye, m)?)?;
    m.add_function(wrap_pyfunction!(fuse::fuse, m)?)?;
    m.add_function(wrap_pyfunction!(simulate::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(profile::profile, m)?)?;
    m.add_function(wrap_pyfunction!(poses::pose_to_matrix, m)?)?;
    m.add_function(wrap_pyfunction!(poses::matrix_to_pose, m)?)?;
    m.add_function(wrap_pyfunction!(poses::read_poses, m)?)?;
    m.add_function(wrap_pyfunction!(poses::write_poses, m)?)?;
    m.add_function(wrap_pyfunction!(poses::ros2_static_transform, m)?)?;
    m.add_function(wrap_pyfunction!(poses::transform_files, m)?)?;
    Ok(())
}
