//! Preprocessing.
pub mod normals;
pub mod outlier;
pub mod scale;
pub mod surface;
pub mod voxel;
