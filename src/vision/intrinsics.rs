//! Intrinsic calibration from checkerboard or ChArUco images (Zhang's method, OpenCV's `calibrateCamera`).
//! A ChArUco view may show part of the board: each view brings its own corners (the object points of the
//! corner ids found), as OpenCV's `calibrateCameraCharuco` does.
//!
//! The result is the crate's [`Intrinsics`] with model `brown_conrady`: OpenCV's `(k1, k2, p1, p2, k3)`
//! are librealsense's `RS2_DISTORTION_BROWN_CONRADY` coefficients in the same order and formula, and both
//! put pixel `(0, 0)` at the centre of the top-left pixel, so no conversion is needed.
//!
//! Images where the board is not found are rejected and named in [`IntrinsicCalibration::rejected`];
//! calibration needs at least [`IntrinsicsConfig::min_views`] views. The per-view and overall RMS
//! reprojection errors are recomputed with the crate's own projection (they equal OpenCV's).

use super::board_view::detect_board;
use super::charuco::CharucoConfig;
use super::corners::CornerConfig;
use super::cv;
use super::image::{read_grey_image, GreyImage};
use super::pnp::{reprojection_errors_of, rms_max};
use crate::camera::{DistortionModel, Intrinsics};
use crate::cell::Board;
use crate::error::{check, Error, Result};
use nalgebra::{Isometry3, Point2, Point3};
use opencv::core::{Mat, Size, TermCriteria, TermCriteria_Type, Vector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Intrinsic calibration settings (the `calibrateCamera` flags a careful user sets).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IntrinsicsConfig {
    /// Keep `fx / fy = 1` (OpenCV `CALIB_FIX_ASPECT_RATIO`); for square pixels and few views. Default false.
    pub fix_aspect_ratio: bool,
    /// Estimate the sixth-order radial term k3 (default true; false sets `CALIB_FIX_K3`, k3 = 0, which
    /// suits narrow lenses and few views better).
    pub estimate_k3: bool,
    /// Estimate the tangential terms p1, p2 (default true; false sets `CALIB_ZERO_TANGENT_DIST`).
    pub estimate_tangential: bool,
    /// Keep the principal point at the image centre (`CALIB_FIX_PRINCIPAL_POINT`). Default false.
    pub fix_principal_point: bool,
    /// Most Levenberg-Marquardt iterations (default 100).
    pub max_iterations: u32,
    /// Stop when the relative parameter change is below this (default 1e-12).
    pub epsilon: f64,
    /// Fewest views with the board found (default 3).
    pub min_views: usize,
    /// Checkerboard corner detection.
    pub corners: CornerConfig,
    /// ChArUco corner detection.
    pub charuco: CharucoConfig,
}

impl IntrinsicsConfig {
    /// Checks the values and the nested detection settings; the error names the field.
    pub fn validate(&self) -> Result<()> {
        check::at_least("max_iterations", self.max_iterations as usize, 1)?;
        check::positive("epsilon", self.epsilon)?;
        check::at_least("min_views", self.min_views, 1)?;
        self.corners.validate()?;
        self.charuco.validate()
    }
}

impl Default for IntrinsicsConfig {
    fn default() -> Self {
        IntrinsicsConfig {
            fix_aspect_ratio: false,
            estimate_k3: true,
            estimate_tangential: true,
            fix_principal_point: false,
            max_iterations: 100,
            epsilon: 1e-12,
            min_views: 3,
            corners: CornerConfig::default(),
            charuco: CharucoConfig::default(),
        }
    }
}

/// One view used by the calibration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ViewResidual {
    /// The image's name (its path as given).
    pub name: String,
    /// RMS reprojection error over the view's corners, pixels.
    pub rms_px: f64,
    /// Largest corner reprojection error, pixels.
    pub max_px: f64,
    /// Corners of the view used (a ChArUco view may show part of the board).
    pub corners: usize,
    /// The board pose in the camera, metres.
    #[serde(skip)]
    pub t_cam_board: Isometry3<f64>,
}

/// The result of [`calibrate_intrinsics`].
#[derive(Clone, Debug, PartialEq)]
pub struct IntrinsicCalibration {
    /// The intrinsics (`brown_conrady`, `rms` set; `depth_scale` is the default and means nothing here).
    pub intrinsics: Intrinsics,
    /// RMS reprojection error over all corners of all views, pixels.
    pub rms_px: f64,
    /// The views used, in input order.
    pub views: Vec<ViewResidual>,
    /// Images not used, with the reason (board not found, unreadable, other size).
    pub rejected: Vec<(String, String)>,
    /// 1-σ of `[fx, fy, ppx, ppy, k1, k2, p1, p2, k3]` from OpenCV (pixels; coefficients dimensionless;
    /// 0 for a fixed parameter).
    pub sigma: [f64; 9],
}

/// One view of a planar target: its points in the image and on the target.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetView {
    /// The view's name (its image's path as given), for results and errors.
    pub name: String,
    /// Pixel coordinates of the target points seen (`(0, 0)` = centre of the top-left pixel).
    pub image_points: Vec<Point2<f64>>,
    /// The same points in the target frame, metres (`z = 0`).
    pub object_points: Vec<Point3<f64>>,
}

/// Calibrates from any planar target whose points are all seen in every view: `object` are its points
/// (target frame, `z = 0`, metres) and each view's image points are in the same order.
pub fn calibrate_from_points(
    views: &[(String, Vec<Point2<f64>>)],
    object: &[Point3<f64>],
    width: u32,
    height: u32,
    cfg: &IntrinsicsConfig,
) -> Result<IntrinsicCalibration> {
    if let Some((name, c)) = views.iter().find(|(_, c)| c.len() != object.len()) {
        return Err(Error::InvalidInput(format!(
            "{name}: {} image points for {} target points",
            c.len(),
            object.len()
        )));
    }
    let views: Vec<TargetView> = views
        .iter()
        .map(|(name, c)| TargetView {
            name: name.clone(),
            image_points: c.clone(),
            object_points: object.to_vec(),
        })
        .collect();
    calibrate_from_views(&views, width, height, cfg)
}

/// Calibrates from views that each see their own points of a planar target (e.g. the ChArUco corners
/// found in each image); every view needs at least 4 points. `(width, height)` is the image size, pixels.
pub fn calibrate_from_views(
    views: &[TargetView],
    width: u32,
    height: u32,
    cfg: &IntrinsicsConfig,
) -> Result<IntrinsicCalibration> {
    cfg.validate()?;
    if views.len() < cfg.min_views.max(1) {
        return Err(Error::InvalidInput(format!(
            "intrinsic calibration needs the target in at least {} images, found it in {}",
            cfg.min_views.max(1),
            views.len()
        )));
    }
    if let Some(v) = views
        .iter()
        .find(|v| v.image_points.len() != v.object_points.len() || v.image_points.len() < 4)
    {
        return Err(Error::InvalidInput(format!(
            "{}: {} image points for {} target points (need the same number, at least 4)",
            v.name,
            v.image_points.len(),
            v.object_points.len()
        )));
    }
    let obj: Vector<Vector<opencv::core::Point3f>> = views
        .iter()
        .map(|v| cv::points3f(&v.object_points))
        .collect();
    let img: Vector<Vector<opencv::core::Point2f>> = views
        .iter()
        .map(|v| cv::points2f(&v.image_points))
        .collect();
    let mut flags = 0;
    if cfg.fix_aspect_ratio {
        flags |= opencv::calib3d::CALIB_FIX_ASPECT_RATIO;
    }
    if !cfg.estimate_k3 {
        flags |= opencv::calib3d::CALIB_FIX_K3;
    }
    if !cfg.estimate_tangential {
        flags |= opencv::calib3d::CALIB_ZERO_TANGENT_DIST;
    }
    if cfg.fix_principal_point {
        flags |= opencv::calib3d::CALIB_FIX_PRINCIPAL_POINT;
    }
    // Without CALIB_USE_INTRINSIC_GUESS only the fx/fy ratio (1) and, with a fixed principal point, the
    // image centre are taken from this matrix.
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let mut k = cv::mat_f64(3, 3, &[1.0, 0.0, cx, 0.0, 1.0, cy, 0.0, 0.0, 1.0])?;
    let mut d = cv::mat_f64(1, 5, &[0.0; 5])?;
    let mut rvecs: Vector<Mat> = Vector::new();
    let mut tvecs: Vector<Mat> = Vector::new();
    let mut sd_intr = Mat::default();
    let mut sd_extr = Mat::default();
    let mut per_view = Mat::default();
    let crit = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        cfg.max_iterations as i32,
        cfg.epsilon,
    )
    .map_err(|e| cv::error("TermCriteria", e))?;
    let rms_cv = opencv::calib3d::calibrate_camera_extended(
        &obj,
        &img,
        Size::new(width as i32, height as i32),
        &mut k,
        &mut d,
        &mut rvecs,
        &mut tvecs,
        &mut sd_intr,
        &mut sd_extr,
        &mut per_view,
        flags,
        crit,
    )
    .map_err(|e| cv::error("calibrateCamera", e))?;
    let kv = cv::mat_values(&k)?;
    let dv = cv::mat_values(&d)?;
    let sv = cv::mat_values(&sd_intr).unwrap_or_default();
    let mut coeffs = [0.0; 5];
    for (c, v) in coeffs.iter_mut().zip(&dv) {
        *c = *v;
    }
    let mut intrinsics = Intrinsics {
        model: DistortionModel::BrownConrady,
        coeffs,
        ..Intrinsics::pinhole(width, height, kv[0], kv[4], kv[2], kv[5])
    };
    intrinsics
        .validate()
        .map_err(|m| Error::Failed(format!("calibrateCamera gave unusable intrinsics: {m}")))?;
    let mut all = Vec::new();
    let mut out = Vec::with_capacity(views.len());
    for (i, v) in views.iter().enumerate() {
        let t = cv::isometry_from_rt(
            &rvecs.get(i).map_err(|e| cv::error("rvecs", e))?,
            &tvecs.get(i).map_err(|e| cv::error("tvecs", e))?,
        )?;
        let e = reprojection_errors_of(&v.image_points, &v.object_points, &intrinsics, &t);
        let (rms_px, max_px) = rms_max(&e);
        all.extend(e);
        out.push(ViewResidual {
            name: v.name.clone(),
            rms_px,
            max_px,
            corners: v.image_points.len(),
            t_cam_board: t,
        });
    }
    let (rms_px, _) = rms_max(&all);
    if !rms_px.is_finite() || (rms_px - rms_cv).abs() > 1e-3 * rms_cv.max(1.0) {
        log::warn!("reprojection RMS {rms_px} px differs from OpenCV's {rms_cv} px");
    }
    intrinsics.rms = Some(rms_px);
    let mut sigma = [0.0; 9];
    for (s, v) in sigma.iter_mut().zip(&sv) {
        *s = *v;
    }
    Ok(IntrinsicCalibration {
        intrinsics,
        rms_px,
        views: out,
        rejected: Vec::new(),
        sigma,
    })
}

/// An image with the board's view, or why the board was not found.
type Detected = std::result::Result<(GreyImage, TargetView), String>;

/// Reads the images, finds the board in each (in parallel) and calibrates. Images that cannot be read or
/// where the board is not found are rejected (named in the result); images of another size than the first
/// readable one are an error naming both. A ChArUco view counts with the corners it shows.
pub fn calibrate_intrinsics(
    paths: &[PathBuf],
    board: &Board,
    cfg: &IntrinsicsConfig,
) -> Result<IntrinsicCalibration> {
    cfg.validate()?;
    if paths.is_empty() {
        return Err(Error::InvalidInput("no images given".into()));
    }
    let detected: Vec<(String, Detected)> = paths
        .par_iter()
        .map(|p| {
            let name = p.display().to_string();
            let r = (|| -> Result<Detected> {
                let img = read_grey_image(p)?;
                Ok(
                    match detect_board(&img, board, &cfg.corners, &cfg.charuco)? {
                        Some(c) => {
                            let v = TargetView {
                                name: name.clone(),
                                image_points: c.image_points,
                                object_points: c.object_points,
                            };
                            Ok((img, v))
                        }
                        None => Err(format!("board ({board}) not found")),
                    },
                )
            })();
            match r {
                Ok(x) => (name, x),
                Err(e) => (name, Err(e.to_string())),
            }
        })
        .collect();
    let mut size: Option<(u32, u32, String)> = None;
    let mut views = Vec::new();
    let mut rejected = Vec::new();
    for (name, r) in detected {
        match r {
            Ok((img, v)) => {
                match &size {
                    None => size = Some((img.width, img.height, name.clone())),
                    Some((w, h, first)) if (*w, *h) != (img.width, img.height) => {
                        return Err(Error::InvalidInput(format!(
                            "{name} is {}x{} pixels but {first} is {w}x{h}: calibrate one camera (one \
                             image size) at a time",
                            img.width, img.height
                        )));
                    }
                    _ => {}
                }
                views.push(v);
            }
            Err(reason) => rejected.push((name, reason)),
        }
    }
    let Some((w, h, _)) = size else {
        let list: Vec<String> = rejected.iter().map(|(n, r)| format!("{n}: {r}")).collect();
        return Err(Error::InvalidInput(format!(
            "the board ({board}) was found in none of the {} images:\n  {}",
            paths.len(),
            list.join("\n  ")
        )));
    };
    if views.len() < cfg.min_views.max(1) {
        let list: String = rejected
            .iter()
            .map(|(n, r)| format!("\n  {n}: {r}"))
            .collect();
        return Err(Error::InvalidInput(format!(
            "intrinsic calibration needs the board in at least {} images, found it in {} of {}{}",
            cfg.min_views.max(1),
            views.len(),
            paths.len(),
            if list.is_empty() {
                String::new()
            } else {
                format!("; rejected:{list}")
            }
        )));
    }
    let mut r = calibrate_from_views(&views, w, h, cfg)?;
    r.rejected = rejected;
    Ok(r)
}
