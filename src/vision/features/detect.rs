//! Keypoint detection and description (OpenCV SIFT, ORB or AKAZE) in a canonical order.
//!
//! The keypoints are sorted by response (strongest first; ties by position, size, angle), then cut to
//! [`FeatureConfig::max_features`], so the result does not depend on the order OpenCV's worker threads
//! produce them in.

use super::super::cv;
use super::super::image::GreyImage;
use super::{Descriptors, FeatureConfig, FeatureKind, Features, Keypoint};
use crate::error::{Error, Result};
use nalgebra::Point2;
use opencv::core::{KeyPoint, Mat, Vector};
use opencv::features2d::{
    AKAZE_DescriptorType, KAZE_DiffusivityType, ORB_ScoreType, AKAZE, ORB, SIFT,
};
use opencv::prelude::*;
use std::cmp::Ordering;

/// The keypoints and descriptors of `img` (see [`detect_features_masked`]).
pub fn detect_features(img: &GreyImage, cfg: &FeatureConfig) -> Result<Features> {
    detect_features_masked(img, None, cfg)
}

/// The keypoints and descriptors of `img`, only where `mask` (one value per pixel, row-major from the
/// top-left, `true` = detection allowed) allows; no mask = the whole image.
///
/// Keypoints come strongest first (by detector response; ties by `y`, `x`, size, angle) and are cut to
/// `cfg.max_features`. Errors when the mask has the wrong length, the settings are out of range, or
/// OpenCV fails; an image without texture gives no keypoints, not an error.
pub fn detect_features_masked(
    img: &GreyImage,
    mask: Option<&[bool]>,
    cfg: &FeatureConfig,
) -> Result<Features> {
    cfg.validate()?;
    let mat = img.to_mat()?;
    let mask_mat = match mask {
        None => Mat::default(),
        Some(m) => {
            if m.len() != img.data.len() {
                return Err(Error::InvalidInput(format!(
                    "detection mask has {} values for a {}x{} image",
                    m.len(),
                    img.width,
                    img.height
                )));
            }
            let bytes: Vec<u8> = m.iter().map(|&b| if b { 255 } else { 0 }).collect();
            let wrapped = Mat::new_rows_cols_with_data(img.height as i32, img.width as i32, &bytes)
                .map_err(|e| cv::error("wrapping the detection mask", e))?;
            wrapped
                .try_clone()
                .map_err(|e| cv::error("copying the detection mask", e))?
        }
    };
    let mut kps: Vector<KeyPoint> = Vector::new();
    let mut desc = Mat::default();
    let limit = cfg.max_features as i32;
    let what = format!("{} detectAndCompute", cfg.kind);
    let run = |e: opencv::Error| cv::error(&what, e);
    match cfg.kind {
        FeatureKind::Sift => {
            // OpenCV's defaults apart from the contrast threshold; nfeatures 0 = no limit.
            let mut d = SIFT::create(limit, 3, cfg.sift_contrast_threshold, 10.0, 1.6)
                .map_err(|e| cv::error("SIFT::create", e))?;
            d.detect_and_compute(&mat, &mask_mat, &mut kps, &mut desc, false)
                .map_err(run)?;
        }
        FeatureKind::Orb => {
            let mut d = ORB::create(
                orb_limit(cfg.max_features, img),
                1.2,
                8,
                31,
                0,
                2,
                ORB_ScoreType::HARRIS_SCORE,
                31,
                cfg.orb_fast_threshold as i32,
            )
            .map_err(|e| cv::error("ORB::create", e))?;
            d.detect_and_compute(&mat, &mask_mat, &mut kps, &mut desc, false)
                .map_err(run)?;
        }
        FeatureKind::Akaze => {
            let mut d = AKAZE::create(
                AKAZE_DescriptorType::DESCRIPTOR_MLDB,
                0,
                3,
                cfg.akaze_threshold as f32,
                4,
                4,
                KAZE_DiffusivityType::DIFF_PM_G2,
            )
            .map_err(|e| cv::error("AKAZE::create", e))?;
            d.detect_and_compute(&mat, &mask_mat, &mut kps, &mut desc, false)
                .map_err(run)?;
        }
    }
    let descriptors = Descriptors::from_mat(cfg.kind, &desc)?;
    let keypoints: Vec<Keypoint> = kps
        .iter()
        .map(|k| Keypoint {
            pt: Point2::new(k.pt().x as f64, k.pt().y as f64),
            size_px: k.size() as f64,
            angle_deg: k.angle() as f64,
            response: k.response() as f64,
        })
        .collect();
    if descriptors.len() != keypoints.len() {
        return Err(Error::Failed(format!(
            "OpenCV {} returned {} descriptors for {} keypoints",
            cfg.kind,
            descriptors.len(),
            keypoints.len()
        )));
    }
    let all = Features {
        keypoints,
        descriptors,
    };
    let mut order: Vec<usize> = (0..all.len())
        .filter(|&i| {
            let k = &all.keypoints[i];
            k.pt.x.is_finite() && k.pt.y.is_finite()
        })
        .collect();
    order.sort_by(|&a, &b| canonical(&all.keypoints[a], &all.keypoints[b]).then(a.cmp(&b)));
    if cfg.max_features > 0 {
        order.truncate(cfg.max_features);
    }
    Ok(all.select(&order))
}

/// Strongest first, then by position, size and angle.
fn canonical(a: &Keypoint, b: &Keypoint) -> Ordering {
    b.response
        .total_cmp(&a.response)
        .then(a.pt.y.total_cmp(&b.pt.y))
        .then(a.pt.x.total_cmp(&b.pt.x))
        .then(a.size_px.total_cmp(&b.size_px))
        .then(a.angle_deg.total_cmp(&b.angle_deg))
}

/// ORB's `nfeatures` for a limit (0 = none). ORB needs a number (it reserves memory for it), so "no
/// limit" is two per pixel of the image, more than FAST's non-maximum suppression can find over the
/// whole pyramid.
fn orb_limit(max_features: usize, img: &GreyImage) -> i32 {
    if max_features > 0 {
        return max_features as i32;
    }
    (2 * img.data.len()).clamp(1, 1 << 27) as i32
}
