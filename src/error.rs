//! The library's typed error.

use std::path::PathBuf;

/// Every way a depthcal library call can fail.
///
/// Errors that come from a file name the file (and, where known, the line or field) and say what to do.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be opened, read or written.
    #[error("{path}: {err}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The operating system's error (already part of the message, so not repeated as a cause).
        err: std::io::Error,
    },
    /// The file was read but its content is wrong (bad header, truncated data, bad number, ...).
    #[error("{path}: {msg}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, naming the line or field.
        msg: String,
    },
    /// The file extension does not name a format depthcal knows.
    #[error("{path}: unknown file format (expected one of {expected})")]
    UnknownFormat {
        /// The file concerned.
        path: PathBuf,
        /// The extensions that are understood.
        expected: &'static str,
    },
    /// The input data cannot be processed (empty cloud, too few points, NaN, degenerate geometry, ...).
    #[error("{0}")]
    InvalidInput(String),
    /// A configuration value is out of range.
    #[error("invalid configuration: {field}: {msg}")]
    Config {
        /// The configuration field, e.g. `icp.max_iterations`.
        field: String,
        /// Why it is invalid.
        msg: String,
    },
    /// An algorithm could not produce a result (e.g. RANSAC found no hypothesis).
    #[error("{0}")]
    Failed(String),
}

/// Shorthand for `Result<T, depthcal::Error>`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A format error for `path` with message `msg`.
    pub fn format(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            msg: msg.into(),
        }
    }
    /// An I/O error for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            err: source,
        }
    }
}
