//! Geometry: the point cloud type, rigid transforms, pose errors and formats, random numbers.

pub mod cloud;
pub mod plane;
pub mod pose;
pub mod rng;
pub mod robot_formats;
pub mod transform;

pub use cloud::PointCloud;
pub use rng::Rng;
