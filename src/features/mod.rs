//! Local shape descriptors.

pub mod fpfh;
pub mod nearest;

pub use fpfh::{compute_fpfh, Fpfh, FpfhConfig, FPFH_BINS};
