//! Calibration: robot-to-robot (initialisers, priors, the pipeline), hand-eye (AX=XB and the robot-world
//! form AX=ZB, pure Rust), rotation and pose averaging.
//!
//! Frames follow the crate convention: `T_a_b` maps coordinates in frame b to frame a.

pub mod average;
pub mod board_init;
pub mod config;
pub mod consistency;
pub mod feature_init;
pub mod fused;
pub mod handeye;
pub mod hypotheses;
pub mod initializer;
pub mod marker_init;
pub mod multi_robot;
pub mod plan;
pub mod plan_robots;
pub mod pose_graph;
pub mod pose_scatter;
pub mod precision;
pub mod priors;
pub mod robot_to_robot;
pub mod routes;
pub mod uncertainty;
pub mod visibility;
