//! The board pose in the camera, `T_cam_board`, from its inner corners in one image (PnP).
//!
//! The corners are first undistorted with the crate's own camera model ([`Intrinsics::pixel_ray`], so any
//! distortion model works) to ideal pinhole pixels; OpenCV's planar IPPE solver gives the pose, which
//! Levenberg-Marquardt (`solvePnPRefineLM`) then refines. The reprojection error is measured with the full
//! model against the detected corners.

use super::cv;
use crate::camera::Intrinsics;
use crate::cell::Checkerboard;
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Point2, Point3};
use opencv::core::{Mat, TermCriteria, TermCriteria_Type};

/// The board pose seen in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardPose {
    /// `T_cam_board`: board-frame coordinates to camera-frame coordinates, metres.
    pub t_cam_board: Isometry3<f64>,
    /// RMS reprojection error over the corners, pixels.
    pub rms_px: f64,
    /// Largest reprojection error of a corner, pixels.
    pub max_px: f64,
}

/// Reprojection errors (pixels) of the board's corners seen at `t_cam_board` against `corners`.
pub fn reprojection_errors(
    corners: &[Point2<f64>],
    board: &Checkerboard,
    intr: &Intrinsics,
    t_cam_board: &Isometry3<f64>,
) -> Vec<f64> {
    reprojection_errors_of(corners, &board.object_points(), intr, t_cam_board)
}

/// Reprojection errors (pixels) of target points `object` (target frame, metres) seen at `t_cam_board`
/// against their image points `corners`; infinite for a point behind the camera.
pub fn reprojection_errors_of(
    corners: &[Point2<f64>],
    object: &[Point3<f64>],
    intr: &Intrinsics,
    t_cam_board: &Isometry3<f64>,
) -> Vec<f64> {
    object
        .iter()
        .zip(corners)
        .map(|(p, q)| {
            let c = t_cam_board * p;
            if c.z <= 0.0 {
                return f64::INFINITY;
            }
            let [u, v] = intr.project([c.x, c.y, c.z]);
            (u - q.x).hypot(v - q.y)
        })
        .collect()
}

/// RMS and largest value of a list of pixel errors.
pub(crate) fn rms_max(e: &[f64]) -> (f64, f64) {
    (crate::stats::rms(e), crate::stats::max_or_zero(e))
}

/// Solves for `T_cam_board` from the board's inner corners (in [`Checkerboard`] order, pixels).
///
/// Errors when the corner count does not match the board, the intrinsics are invalid, or no pose in front
/// of the camera fits.
pub fn board_pose(
    corners: &[Point2<f64>],
    board: &Checkerboard,
    intr: &Intrinsics,
) -> Result<BoardPose> {
    if corners.len() != board.corner_count() {
        return Err(Error::InvalidInput(format!(
            "{} corners for a board of {} inner corners",
            corners.len(),
            board.corner_count()
        )));
    }
    pose_of_points(corners, &board.object_points(), intr)
}

/// Solves for the pose of any planar target (points `object` in its frame, `z = 0`, metres) from their
/// image points `corners` (pixels, same order).
pub fn pose_of_points(
    corners: &[Point2<f64>],
    object: &[Point3<f64>],
    intr: &Intrinsics,
) -> Result<BoardPose> {
    if corners.len() != object.len() || corners.len() < 4 {
        return Err(Error::InvalidInput(format!(
            "{} image points for {} target points (need the same number, at least 4)",
            corners.len(),
            object.len()
        )));
    }
    intr.validate()
        .map_err(|m| Error::InvalidInput(format!("intrinsics: {m}")))?;
    let ideal: Vec<Point2<f64>> = corners
        .iter()
        .map(|q| {
            let [x, y] = intr.pixel_ray([q.x, q.y]);
            Point2::new(x * intr.fx + intr.ppx, y * intr.fy + intr.ppy)
        })
        .collect();
    let pinhole = Intrinsics {
        coeffs: [0.0; 5],
        model: crate::camera::DistortionModel::None,
        ..intr.clone()
    };
    let k = cv::camera_matrix(&pinhole)?;
    let d = cv::dist_coeffs(&pinhole)?;
    let obj = cv::points3f(object);
    let img = cv::points2f(&ideal);
    let mut rvec = Mat::default();
    let mut tvec = Mat::default();
    let ok = opencv::calib3d::solve_pnp(
        &obj,
        &img,
        &k,
        &d,
        &mut rvec,
        &mut tvec,
        false,
        opencv::calib3d::SOLVEPNP_IPPE,
    )
    .map_err(|e| cv::error("solvePnP (IPPE)", e))?;
    if !ok {
        return Err(Error::Failed(
            "PnP found no board pose for these corners".into(),
        ));
    }
    let crit = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        50,
        1e-12,
    )
    .map_err(|e| cv::error("TermCriteria", e))?;
    opencv::calib3d::solve_pnp_refine_lm(&obj, &img, &k, &d, &mut rvec, &mut tvec, crit)
        .map_err(|e| cv::error("solvePnPRefineLM", e))?;
    let t = cv::isometry_from_rt(&rvec, &tvec)?;
    if t.translation.vector.z <= 0.0 {
        return Err(Error::Failed("PnP put the board behind the camera".into()));
    }
    let (rms_px, max_px) = rms_max(&reprojection_errors_of(corners, object, intr, &t));
    Ok(BoardPose {
        t_cam_board: t,
        rms_px,
        max_px,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::DistortionModel;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn exact_corners_give_the_exact_pose_with_distortion() {
        let board = Checkerboard::new(9, 6, 0.025).unwrap();
        let intr = Intrinsics {
            model: DistortionModel::BrownConrady,
            coeffs: [-0.2, 0.05, 0.001, -0.0005, 0.01],
            ..Intrinsics::pinhole(640, 480, 540.0, 541.0, 322.0, 238.0)
        };
        let truth = Isometry3::from_parts(
            Translation3::new(-0.08, -0.05, 0.55),
            UnitQuaternion::from_euler_angles(0.3, -0.2, 0.4),
        );
        let corners: Vec<Point2<f64>> = board
            .object_points()
            .iter()
            .map(|p| {
                let c = truth * p;
                let [u, v] = intr.project([c.x, c.y, c.z]);
                Point2::new(u, v)
            })
            .collect();
        let pose = board_pose(&corners, &board, &intr).unwrap();
        let d = truth.inverse() * pose.t_cam_board;
        assert!(d.rotation.angle() < 1e-6, "{}", d.rotation.angle());
        assert!(d.translation.vector.norm() < 1e-6);
        assert!(pose.rms_px < 1e-4, "{}", pose.rms_px);
        assert!(board_pose(&corners[1..], &board, &intr).is_err());
    }
}
