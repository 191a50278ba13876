//! The board seen by a set of images: per frame `T_cam_board` (detection + PnP), the images matched to
//! frame ids, and the board pose in a cell robot's base from its colour images.

use super::board_view::detect_board;
use super::charuco::CharucoConfig;
use super::corners::CornerConfig;
use super::image::read_grey_image;
use super::pnp::pose_of_points;
use crate::calibration::average::{average_poses, AverageConfig, PoseAverage};
use crate::camera::Intrinsics;
use crate::cell::{Board, CellRobot};
use crate::error::{check, Error, Result};
use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Settings of [`observe_board`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObserveConfig {
    /// Checkerboard corner detection.
    pub corners: CornerConfig,
    /// ChArUco corner detection.
    pub charuco: CharucoConfig,
    /// A view whose PnP RMS reprojection error exceeds this is rejected (a wrong detection or a bad
    /// intrinsics file), pixels. Default 2.0.
    pub max_rms_px: f64,
}

impl ObserveConfig {
    /// Checks the values and the nested detection settings; the error names the field.
    pub fn validate(&self) -> Result<()> {
        check::positive("max_rms_px", self.max_rms_px)?;
        self.corners.validate()?;
        self.charuco.validate()
    }
}

impl Default for ObserveConfig {
    fn default() -> Self {
        ObserveConfig {
            corners: CornerConfig::default(),
            charuco: CharucoConfig::default(),
            max_rms_px: 2.0,
        }
    }
}

/// The board found in one frame's image.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardObservation {
    /// The frame id.
    pub frame: String,
    /// The image file.
    pub image: PathBuf,
    /// `T_cam_board`, metres.
    pub t_cam_board: Isometry3<f64>,
    /// PnP RMS reprojection error, pixels.
    pub rms_px: f64,
    /// Which detector found the corners.
    pub detector: &'static str,
    /// Corners found (a ChArUco view may show part of the board).
    pub corners: usize,
    /// The corners found, pixels (`(0, 0)` = centre of the top-left pixel).
    pub image_points: Vec<nalgebra::Point2<f64>>,
    /// The same corners in the board frame, metres.
    pub object_points: Vec<nalgebra::Point3<f64>>,
}

/// The result of [`observe_board`].
#[derive(Clone, Debug, PartialEq, Default)]
pub struct BoardObservations {
    /// Frames where the board was found, in input order.
    pub found: Vec<BoardObservation>,
    /// Frames where it was not: `(frame, image, reason)`, in input order.
    pub rejected: Vec<(String, PathBuf, String)>,
}

impl BoardObservations {
    /// The rejected frames as one line per frame (`frame (image): reason`).
    pub fn rejected_lines(&self) -> Vec<String> {
        self.rejected
            .iter()
            .map(|(f, p, r)| format!("frame {f} ({}): {r}", p.display()))
            .collect()
    }
}

/// Finds the board in each frame's image (in parallel) and solves its pose in the camera from the corners
/// found (a ChArUco board may be partly in view). `images` are `(frame id, image file)`. Images of another
/// size than `intr` are an error naming the file; frames whose image has no board, or whose PnP error
/// exceeds `cfg.max_rms_px`, are rejected; it is an error when the board is found in no image (the message
/// names them all).
pub fn observe_board(
    images: &[(String, PathBuf)],
    board: &Board,
    intr: &Intrinsics,
    cfg: &ObserveConfig,
) -> Result<BoardObservations> {
    cfg.validate()?;
    if images.is_empty() {
        return Err(Error::InvalidInput(
            "no images to look for the board in".into(),
        ));
    }
    type One = std::result::Result<BoardObservation, String>;
    let per: Vec<Result<One>> = images
        .par_iter()
        .map(|(frame, path)| -> Result<One> {
            let img = read_grey_image(path)?;
            if (img.width, img.height) != (intr.width, intr.height) {
                return Err(Error::format(
                    path,
                    format!(
                        "image is {}x{} pixels but the intrinsics are for {}x{}",
                        img.width, img.height, intr.width, intr.height
                    ),
                ));
            }
            let Some(c) = detect_board(&img, board, &cfg.corners, &cfg.charuco)? else {
                return Ok(Err(format!("board ({board}) not found")));
            };
            let pose = match pose_of_points(&c.image_points, &c.object_points, intr) {
                Ok(p) => p,
                Err(e) => return Ok(Err(format!("PnP failed: {e}"))),
            };
            if pose.rms_px.is_nan() || pose.rms_px > cfg.max_rms_px {
                return Ok(Err(format!(
                    "PnP reprojection RMS {:.2} px exceeds {:.2} px (wrong detection or intrinsics)",
                    pose.rms_px, cfg.max_rms_px
                )));
            }
            Ok(Ok(BoardObservation {
                frame: frame.clone(),
                image: path.clone(),
                t_cam_board: pose.t_cam_board,
                rms_px: pose.rms_px,
                detector: c.detector,
                corners: c.len(),
                image_points: c.image_points,
                object_points: c.object_points,
            }))
        })
        .collect();
    let mut out = BoardObservations::default();
    for ((frame, path), r) in images.iter().zip(per) {
        match r? {
            Ok(o) => out.found.push(o),
            Err(reason) => out.rejected.push((frame.clone(), path.clone(), reason)),
        }
    }
    if out.found.is_empty() {
        return Err(Error::InvalidInput(format!(
            "the board ({board}) was found in none of the {} images:\n  {}",
            images.len(),
            out.rejected_lines().join("\n  ")
        )));
    }
    Ok(out)
}

/// Image file extensions tried for a frame id (lower and upper case).
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "bmp", "tif", "tiff"];

/// `(frame id, image)` per frame, and the images of no frame.
pub type FrameImages = (Vec<(String, PathBuf)>, Vec<PathBuf>);

/// Matches each frame id to an image `DIR/<frame>.<ext>` ([`IMAGE_EXTENSIONS`]). Errors naming the frames
/// that have no image; images in `dir` that belong to no frame are returned (to warn about).
pub fn find_frame_images(dir: &Path, frames: &[String]) -> Result<FrameImages> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut files: Vec<PathBuf> = Vec::new();
    for e in entries {
        let p = e.map_err(|e| Error::io(dir, e))?.path();
        let ext = p
            .extension()
            .and_then(|x| x.to_str())
            .map(|x| x.to_ascii_lowercase());
        // Hidden files (e.g. `.NAME.tmp-PID` of an interrupted write) are never frames.
        let hidden = p
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with('.'));
        if !hidden && p.is_file() && ext.is_some_and(|x| IMAGE_EXTENSIONS.contains(&x.as_str())) {
            files.push(p);
        }
    }
    files.sort();
    let stem = |p: &Path| p.file_stem().and_then(|s| s.to_str()).map(String::from);
    let mut out = Vec::with_capacity(frames.len());
    let mut missing = Vec::new();
    for f in frames {
        let hits: Vec<&PathBuf> = files
            .iter()
            .filter(|p| stem(p).as_deref() == Some(f.as_str()))
            .collect();
        match hits.as_slice() {
            [one] => out.push((f.clone(), (*one).clone())),
            [] => missing.push(f.clone()),
            many => {
                return Err(Error::InvalidInput(format!(
                    "{}: frame {f} has {} images ({}); keep one",
                    dir.display(),
                    many.len(),
                    many.iter()
                        .map(|p| p.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                )))
            }
        }
    }
    if !missing.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: {} of {} frames have no image <frame>.{{png,jpg,...}}: frames {} ({} images in the directory)",
            dir.display(),
            missing.len(),
            frames.len(),
            missing.join(", "),
            files.len()
        )));
    }
    let extra = files
        .into_iter()
        .filter(|p| stem(p).is_none_or(|s| !frames.contains(&s)))
        .collect();
    Ok((out, extra))
}

/// The board pose in one robot's base, from its colour images.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotBoardPose {
    /// The robot's name.
    pub robot: String,
    /// The average `T_base_board` over the frames (robust rotation average) with its spread.
    pub average: PoseAverage,
    /// The frames used (same order as `average.rotation_deg`).
    pub frames: Vec<String>,
    /// What was seen in each frame.
    pub observations: BoardObservations,
}

/// `T_base_board` of a cell robot: its colour images (assumed aligned to the depth stream, i.e. taken with
/// the robot's intrinsics and `T_ee_cam`, as the simulator and RealSense's aligned streams give them), the
/// board in each (PnP), then `T_base_ee · T_ee_cam · T_cam_board` averaged over the frames.
///
/// Errors when the robot has no colour images, or the board is found in no frame (naming the frames).
pub fn board_in_robot_base(
    robot: &CellRobot,
    board: &Board,
    cfg: &ObserveConfig,
) -> Result<RobotBoardPose> {
    let mut images = Vec::with_capacity(robot.frames.len());
    for f in &robot.frames {
        let Some(p) = &f.color_path else {
            return Err(Error::InvalidInput(format!(
                "robot {:?} has no colour images (no `color` pattern in cell.toml; frame {} at line {} of {}): \
                 the checkerboard method needs colour images of the board",
                robot.name,
                f.id,
                f.pose_line,
                robot.poses_path.display()
            )));
        };
        images.push((f.id.clone(), p.clone()));
    }
    let obs = observe_board(&images, board, &robot.intrinsics, cfg).map_err(|e| match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("robot {:?}: {m}", robot.name)),
        e => e,
    })?;
    let mut poses = Vec::with_capacity(obs.found.len());
    let mut frames = Vec::with_capacity(obs.found.len());
    for o in &obs.found {
        let f = robot
            .frames
            .iter()
            .find(|f| f.id == o.frame)
            .expect("observed frames come from the robot");
        poses.push(f.t_base_ee * robot.t_ee_cam * o.t_cam_board);
        frames.push(o.frame.clone());
    }
    let average = average_poses(
        &poses,
        None,
        &AverageConfig {
            l1_iterations: 50,
            ..AverageConfig::default()
        },
    )?;
    Ok(RobotBoardPose {
        robot: robot.name.clone(),
        average,
        frames,
        observations: obs,
    })
}
