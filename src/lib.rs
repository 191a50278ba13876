//! # depthcal
//!
//! A point-cloud registration engine for depth-only calibration of multi-robot cells.
//!
//! The pipeline is a chain of plain functions over plain data (see `docs/architecture.md`):
//! [`io`] reads clouds, [`preprocess`] downsamples and estimates normals, [`features`] computes FPFH,
//! [`registration`] matches features, runs RANSAC and refines with trimmed robust ICP.
//!
//! Conventions: `T_a_b` maps coordinates in frame b to frame a (`p_a = T_a_b · p_b`); SI units inside
//! (metres, radians); point coordinates are `f32`, transforms and sums `f64`; every randomised step takes a
//! seed and gives bit-identical output at any thread count.
//!
//! Cargo features: `cli` (the `depthcal` binary), `sim` (the ray-casting simulator, parry3d) and `rosbag`
//! (ROS1 `.bag` import) are on by default; `vision` (OpenCV) and `realsense` (librealsense) are opt-in.
//! `--no-default-features` builds the library alone.

#![warn(missing_docs)]
#![warn(rustdoc::broken_intra_doc_links)]

pub mod calibration;
pub mod camera;
pub mod capture;
pub mod cell;
pub mod config_json;
pub mod error;
pub mod features;
pub mod fusion;
pub mod geometry;
pub mod index;
pub mod io;
pub mod methods;
pub mod preprocess;
pub mod profile;
pub mod registration;
pub mod report;
pub mod sim;
mod simd;
pub mod stats;
pub mod tempfiles;
pub mod timing;
#[cfg(feature = "vision")]
pub mod vision;
pub mod viz;

pub use error::{Error, Result};
pub use geometry::PointCloud;
