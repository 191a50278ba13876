//! Geometry: the point cloud type, rigid transforms, pose errors, random numbers.

pub mod cloud;
pub mod plane;
pub mod pose;
pub mod rng;
pub mod transform;

pub use cloud::PointCloud;
pub use rng::Rng;
