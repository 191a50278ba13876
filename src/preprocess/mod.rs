//! Preprocessing.
pub mod normals;
pub mod outlier;
pub mod scale;
pub mod voxel;
