//! Reading and writing point clouds, transforms and pose files.
//!
//! Formats are chosen by extension: `.ply` (ascii, binary little/big endian), `.pcd` (ascii, binary,
//! binary_compressed), `.xyz`/`.txt`/`.pts` (whitespace or comma separated x y z per line, extra columns
//! ignored), `.npy` (an N×3 float32/float64 array). Every error names the file.

mod atomic;
pub mod matrix;
mod npy;
mod pcd;
mod ply;
pub mod poses;
mod xyz;

pub use atomic::write_atomically;
pub use matrix::{parse_matrix, read_matrix_file, write_matrix_file};

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::path::Path;

const READ_FORMATS: &str = ".ply, .pcd, .xyz, .txt, .pts, .npy";

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Reads a point cloud, choosing the format by the file extension.
///
/// Points with NaN or infinite coordinates are kept here; call [`PointCloud::drop_non_finite`] to remove them.
pub fn read_cloud(path: impl AsRef<Path>) -> Result<PointCloud> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_cloud(&bytes, path)
}

/// Parses the bytes of a point-cloud file; `name` chooses the format by its extension (as [`read_cloud`]) and
/// names the file in errors. Never panics: any input is a cloud or an error.
pub fn parse_cloud(bytes: &[u8], name: impl AsRef<Path>) -> Result<PointCloud> {
    let path = name.as_ref();
    if bytes.is_empty() {
        return Err(Error::format(path, "the file is empty"));
    }
    match extension(path).as_str() {
        "ply" => ply::read(path, bytes),
        "pcd" => pcd::read(path, bytes),
        "xyz" | "txt" | "pts" => xyz::read(path, bytes),
        "npy" => npy::read(path, bytes),
        _ => Err(Error::UnknownFormat {
            path: path.to_path_buf(),
            expected: READ_FORMATS,
        }),
    }
}

/// Writes a point cloud (binary little-endian PLY for `.ply`, `x y z` text for `.xyz`/`.txt`), atomically:
/// a temporary file in the same directory is written and then renamed over `path`.
pub fn write_cloud(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    let path = path.as_ref();
    match extension(path).as_str() {
        "ply" => write_atomically(path, |w| ply::write(w, cloud)),
        "xyz" | "txt" => write_atomically(path, |w| xyz::write(w, cloud)),
        _ => Err(Error::UnknownFormat {
            path: path.to_path_buf(),
            expected: ".ply, .xyz, .txt (for writing)",
        }),
    }
}

/// Writes a PLY file in ASCII (for tests and interoperability checks).
pub fn write_ply_ascii(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    write_atomically(path.as_ref(), |w| {
        ply::write_with(w, cloud, ply::Encoding::Ascii)
    })
}

/// Writes a PLY file in big-endian binary (for tests and interoperability checks).
pub fn write_ply_big_endian(path: impl AsRef<Path>, cloud: &PointCloud) -> Result<()> {
    write_atomically(path.as_ref(), |w| {
        ply::write_with(w, cloud, ply::Encoding::BinaryBigEndian)
    })
}
