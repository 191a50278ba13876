//! Registration: correspondences, RANSAC, trimmed robust ICP, and the `register` pipeline.

pub mod anderson;
pub mod consensus;
pub mod correspondence;
pub mod extent;
pub mod icp;
pub mod kernel;
pub mod ransac;
pub mod rigid_fit;
pub mod verify;

pub use icp::{
    icp, icp_lazy_normals, IcpCloud, IcpConfig, IcpFactor, IcpIteration, IcpResult, Trim,
};
pub use kernel::RobustKernel;
pub use ransac::{ransac, PoseConstraint, RansacConfig, RansacResult};
pub use rigid_fit::rigid_fit;
pub mod pipeline;
pub mod quality;
pub mod trust;

pub use pipeline::{
    register, register_request, register_with_prior, register_with_progress, IcpLevelTrace,
    PreparedLevels, RegisterConfig, RegisterRequest, Registration,
};
pub use trust::{assess_registration, Trust, TrustConfig};
pub use verify::HypothesisPrior;
