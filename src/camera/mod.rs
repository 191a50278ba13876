//! Camera models and depth frames: intrinsics with librealsense's distortion models, 16-bit depth PNG I/O,
//! and deprojection of depth images to camera-frame points.
//!
//! Pixel and camera conventions follow librealsense: pixel `(0, 0)` is the centre of the top-left pixel,
//! `x` right, `y` down, `z` forward along the optical axis; depth is the `z` coordinate in metres after
//! multiplying the raw 16-bit value by `depth_scale`.

pub mod depth;
pub mod distortion;
pub mod intrinsics;
pub mod rgb;
pub mod view;

pub use depth::{
    deproject, parse_depth_png, read_depth_png, write_depth_png, DeprojectConfig, DepthImage,
    RayTable,
};
pub use distortion::DistortionModel;
pub use intrinsics::{
    check_image_size, Intrinsics, DEFAULT_DEPTH_SCALE, MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE,
};
pub use rgb::{write_rgb_png, RgbImage};
pub use view::{DepthView, Seen};
