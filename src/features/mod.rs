//! Local shape descriptors.

pub mod fpfh;

pub use fpfh::{compute_fpfh, Fpfh, FpfhConfig, FPFH_BINS};
