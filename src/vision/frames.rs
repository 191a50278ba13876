//! A cell frame's colour image (as grey) with its depth, checked to be aligned: the marker and the
//! 2D-feature methods read a pixel's depth at the pixel's position in the colour image, so both images
//! must have the robot's intrinsics' size (RealSense's aligned streams, the simulator).

use super::image::{read_grey_image, GreyImage};
use crate::camera::DepthImage;
use crate::cell::CellRobot;
use crate::error::{Error, Result};

/// Frame `i` of `robot`: its colour image as grey and its depth image. Errors name the robot, the frame
/// and the file: no colour image pattern, unreadable images, a colour image of another size than the
/// depth image, a depth image of another size than the intrinsics.
pub fn load_aligned_frame(
    robot: &CellRobot,
    i: usize,
    method: &str,
) -> Result<(GreyImage, DepthImage)> {
    let f = &robot.frames[i];
    let Some(color) = &f.color_path else {
        return Err(Error::InvalidInput(format!(
            "robot {:?} has no colour images (no `color` pattern in cell.toml; frame {} at line {} of {}): \
             the {method} method needs colour images aligned to depth",
            robot.name,
            f.id,
            f.pose_line,
            robot.poses_path.display()
        )));
    };
    let grey = read_grey_image(color)?;
    let depth = robot.load_depth(i)?;
    if (grey.width, grey.height) != (depth.width, depth.height) {
        return Err(Error::format(
            color,
            format!(
                "robot {:?} frame {}: the colour image is {}x{} but the depth image {} is {}x{}; the {method} \
                 method needs colour aligned to depth (same size and camera, e.g. RealSense's aligned streams)",
                robot.name,
                f.id,
                grey.width,
                grey.height,
                f.depth_path.display(),
                depth.width,
                depth.height
            ),
        ));
    }
    Ok((grey, depth))
}
