//! The exceptions of the package: `depthcal.Error` and one subclass per kind of library error, each also
//! deriving from the Python built-in exception a user would catch (`ValueError`, `OSError`,
//! `RuntimeError`). Every exception carries the library's message unchanged.

use pyo3::exceptions::{PyException, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

/// The kinds of exception the package raises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Bad input data: wrong array shape or dtype, NaN, too few points, a non-rigid matrix.
    Input,
    /// A file was read but its content is wrong, or its extension names no known format.
    Format,
    /// A configuration value is out of range or names an unknown key.
    Config,
    /// A file could not be opened, read or written.
    File,
    /// An algorithm could not produce a result.
    Failed,
    /// A result did not pass the quality gate (raised by `check()` of a result).
    Untrusted,
}

struct Types {
    base: Py<PyType>,
    input: Py<PyType>,
    format: Py<PyType>,
    config: Py<PyType>,
    file: Py<PyType>,
    failed: Py<PyType>,
    untrusted: Py<PyType>,
}

static TYPES: PyOnceLock<Types> = PyOnceLock::new();

fn make_type<'py>(
    py: Python<'py>,
    name: &str,
    bases: Bound<'py, PyTuple>,
    doc: &str,
) -> PyResult<Bound<'py, PyType>> {
    let dict = PyDict::new(py);
    dict.set_item("__doc__", doc)?;
    dict.set_item("__module__", "depthcal")?;
    let ty = py
        .import("builtins")?
        .getattr("type")?
        .call1((name, bases, dict))?;
    Ok(ty.cast_into::<PyType>()?)
}

fn types(py: Python<'_>) -> PyResult<&Types> {
    TYPES.get_or_try_init(py, || {
        let base = make_type(
            py,
            "Error",
            PyTuple::new(py, [py.get_type::<PyException>()])?,
            "Base class of every error depthcal raises; `str(e)` is the library's message.",
        )?;
        let sub = |name: &str, builtin: Bound<'_, PyType>, doc: &str| -> PyResult<Py<PyType>> {
            let bases = PyTuple::new(py, [base.clone(), builtin])?;
            Ok(make_type(py, name, bases, doc)?.unbind())
        };
        Ok::<_, PyErr>(Types {
            input: sub(
                "InputError",
                py.get_type::<PyValueError>(),
                "Bad input data (also a ValueError): a wrong array shape or dtype, NaN or infinite \
                 values, too few points, a non-rigid matrix, an unknown method name.",
            )?,
            format: sub(
                "FormatError",
                py.get_type::<PyValueError>(),
                "A file whose content is wrong (also a ValueError): a bad header, truncated data, a bad \
                 number, or an extension that names no known format. The message names the file.",
            )?,
            config: sub(
                "ConfigError",
                py.get_type::<PyValueError>(),
                "A configuration value out of range or an unknown configuration key (also a ValueError); \
                 the message names the field.",
            )?,
            file: sub(
                "FileError",
                py.get_type::<PyOSError>(),
                "A file that could not be opened, read or written (also an OSError, with `errno` and \
                 `filename` set when known).",
            )?,
            failed: sub(
                "FailedError",
                py.get_type::<PyRuntimeError>(),
                "The algorithm could not produce a result (also a RuntimeError), e.g. no registration \
                 hypothesis was found.",
            )?,
            untrusted: sub(
                "UntrustedError",
                py.get_type::<PyRuntimeError>(),
                "Raised by `check()` of a result that did not pass the quality gate (also a \
                 RuntimeError); `reasons` lists why.",
            )?,
            base: base.unbind(),
        })
    })
}

/// Adds the exception classes to the module.
pub fn add_to_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    let t = types(py)?;
    m.add("Error", t.base.bind(py))?;
    m.add("InputError", t.input.bind(py))?;
    m.add("FormatError", t.format.bind(py))?;
    m.add("ConfigError", t.config.bind(py))?;
    m.add("FileError", t.file.bind(py))?;
    m.add("FailedError", t.failed.bind(py))?;
    m.add("UntrustedError", t.untrusted.bind(py))?;
    Ok(())
}

/// A Python exception of `kind` carrying `msg`.
pub fn new_err(kind: Kind, msg: impl Into<String>) -> PyErr {
    let msg = msg.into();
    Python::attach(|py| match types(py) {
        Ok(t) => {
            let ty = match kind {
                Kind::Input => &t.input,
                Kind::Format => &t.format,
                Kind::Config => &t.config,
                Kind::File => &t.file,
                Kind::Failed => &t.failed,
                Kind::Untrusted => &t.untrusted,
            };
            PyErr::from_type(ty.bind(py).clone(), (msg,))
        }
        Err(e) => e,
    })
}

/// An [`Kind::Input`] error.
pub fn input_err(msg: impl Into<String>) -> PyErr {
    new_err(Kind::Input, msg)
}

/// The Python exception of a library error, with the library's message.
pub fn lib_err(e: depthcal::Error) -> PyErr {
    use depthcal::Error as E;
    let msg = e.to_string();
    match &e {
        E::Io { path, err } => {
            let py_err = new_err(Kind::File, msg);
            Python::attach(|py| {
                let v = py_err.value(py);
                // Best effort: the message is what matters.
                let _ = v.setattr("filename", path.display().to_string());
                if let Some(code) = err.raw_os_error() {
                    let _ = v.setattr("errno", code);
                    let _ = v.setattr("strerror", err.to_string());
                }
            });
            py_err
        }
        E::Format { .. } | E::UnknownFormat { .. } => new_err(Kind::Format, msg),
        E::Config { .. } => new_err(Kind::Config, msg),
        E::InvalidInput(_) => new_err(Kind::Input, msg),
        E::Failed(_) => new_err(Kind::Failed, msg),
    }
}

/// `UntrustedError` with the result's reasons (as the exception's `reasons` attribute too).
pub fn untrusted_err(reasons: &[String]) -> PyErr {
    let mut msg = String::from("untrusted result:");
    for r in reasons {
        msg.push_str("\n  - ");
        msg.push_str(r);
    }
    let e = new_err(Kind::Untrusted, msg);
    Python::attach(|py| {
        let _ = e.value(py).setattr("reasons", reasons.to_vec());
    });
    e
}

/// Issues a Python `UserWarning` with `msg` (what the command line prints as `warning: ...` on stderr).
pub fn warn(py: Python<'_>, msg: &str) -> PyResult<()> {
    let w = py.import("warnings")?;
    w.getattr("warn")?
        .call1((msg, py.get_type::<pyo3::exceptions::PyUserWarning>(), 2))?;
    Ok(())
}
