//! Simulation of test data with exact ground truth.
//!
//! * [`analytic`]: an analytic indoor-like point sampler ([`demo_scene`]) and a partial-overlap splitter
//!   ([`split_overlapping`]), used by the registration tests, the benches and the sample clouds in `clouds/`.
//! * The depth-camera simulator: a [`Scene`] of fiducial objects on a table (parry3d shapes and triangle
//!   meshes), ray-cast depth and colour images of a RealSense-like camera ([`render_frame`], [`SimCamera`]),
//!   a realistic noise model ([`NoiseConfig`]), and complete two-robot cells with ground truth
//!   ([`SimCell`], [`simulate_cell`]) written as `depthcal-cell/1` datasets.
//!
//! The ray-casting simulator ([`scene`], [`render`], [`overlap`], [`cell`]) needs the cargo feature `sim`
//! (on by default; it pulls parry3d). Without it this module keeps the analytic sampler, the images
//! ([`RgbImage`]) and the plain descriptions of boards, markers, meshes, cameras and noise.
//!
//! parry3d is built on glam; glam types stay inside this module. Its public API takes and returns
//! `nalgebra::Isometry3<f64>` (metres) like the rest of the crate.
//!
//! In memory, without files:
//!
//! ```no_run
//! # #[cfg(feature = "sim")] {
//! use depthcal::sim::{SimCell, SimConfig};
//! let cell = SimCell::generate(&SimConfig { seed: 7, ..Default::default() }).unwrap();
//! let truth = cell.t_base1_base2();
//! let frames = cell.render_robot(0).unwrap(); // depth (and colour) of every view of the reference robot
//! let t_base_cam = cell.robots[0].t_base_cam(0);
//! # let _ = (truth, frames, t_base_cam);
//! # }
//! ```

pub mod analytic;
pub mod board;
pub mod camera;
#[cfg(feature = "sim")]
pub mod cell;
#[cfg(feature = "sim")]
mod convert;
pub mod marker;
mod marker_codes;
pub mod mesh;
pub mod noise;
#[cfg(feature = "sim")]
pub mod overlap;
#[cfg(feature = "sim")]
pub mod render;
#[cfg(feature = "sim")]
pub mod scene;

pub use crate::camera::{write_rgb_png, RgbImage};
pub use analytic::{demo_scene, split_overlapping};
pub use board::{SimBoard, SimBoardConfig, TablePrint};
pub use camera::{Resolution, SimCamera};
#[cfg(feature = "sim")]
pub use cell::{simulate_cell, SimCell, SimConfig, SimRobot, WriteStats};
pub use marker::{marker_code, SimMarker, SimMarkers, SimMarkersConfig};
pub use mesh::{builtin_mesh, read_ply_mesh, MeshData, BUILTIN_MESHES};
pub use noise::{NoiseConfig, NoiseLevel};
#[cfg(feature = "sim")]
pub use render::{render_frame, RenderedFrame};
#[cfg(feature = "sim")]
pub use scene::{
    Appearance, Hit, ObjectKind, ObjectShape, Scene, SceneConfig, SceneObject, Surface,
};
