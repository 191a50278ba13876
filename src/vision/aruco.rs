//! OpenCV's ArUco detector (`cv::aruco::detectMarkers`, OpenCV 4.6 contrib) and its predefined
//! dictionaries, ArUco and AprilTag alike.
//!
//! OpenCV returns each marker's corners in ArUco order — top-left, top-right, bottom-right, bottom-left of
//! the marker as `cv::aruco::drawMarker` draws it (clockwise on the screen when the printed face is seen)
//! — in OpenCV's pixel convention (centre of the top-left pixel at `(0, 0)`).

use super::cv;
use super::image::GreyImage;
use crate::cell::MarkerDictionary;
use crate::error::{Error, Result};
use nalgebra::Point2;
use opencv::aruco::{DetectorParameters, DetectorParametersTrait, Dictionary};
use opencv::core::{Mat, Point2f, Ptr, Vector};
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

/// OpenCV's own corner refinement (`DetectorParameters::cornerRefinementMethod`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ArucoRefinement {
    /// The corners of the fitted polygon, whole pixels (`CORNER_REFINE_NONE`).
    None,
    /// `cornerSubPix` with OpenCV's fixed window (`CORNER_REFINE_SUBPIX`).
    Subpix,
    /// Lines fitted to the contour points (`CORNER_REFINE_CONTOUR`).
    Contour,
    /// AprilTag 2's edge refinement inside OpenCV (`CORNER_REFINE_APRILTAG`).
    AprilTag,
}

/// Settings of OpenCV's ArUco detector (a subset of `cv::aruco::DetectorParameters`, OpenCV's defaults
/// unless stated).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ArucoConfig {
    /// Smallest adaptive threshold window, pixels (`adaptiveThreshWinSizeMin`, default 3).
    pub adaptive_thresh_win_size_min: u32,
    /// Largest adaptive threshold window, pixels (`adaptiveThreshWinSizeMax`, default 23).
    pub adaptive_thresh_win_size_max: u32,
    /// Step between the adaptive threshold windows, pixels (`adaptiveThreshWinSizeStep`, default 10).
    pub adaptive_thresh_win_size_step: u32,
    /// Constant subtracted from the local mean, grey levels (`adaptiveThreshConstant`, default 7).
    pub adaptive_thresh_constant: f64,
    /// Smallest marker perimeter as a fraction of the image's larger side (`minMarkerPerimeterRate`,
    /// default 0.03: 24 px, i.e. 6 px sides, in an 800 px wide image).
    pub min_marker_perimeter_rate: f64,
    /// Polygon approximation accuracy as a fraction of the perimeter (`polygonalApproxAccuracyRate`,
    /// default 0.03).
    pub polygonal_approx_accuracy_rate: f64,
    /// Smallest distance of a marker corner to the image border, pixels (`minDistanceToBorder`,
    /// default 3).
    pub min_distance_to_border_px: u32,
    /// Pixels per cell when the marker is unwarped for decoding (`perspectiveRemovePixelPerCell`,
    /// default 4).
    pub perspective_remove_pixel_per_cell: u32,
    /// Fraction of the dictionary's correctable bits that may be corrected (`errorCorrectionRate`,
    /// default 0.6).
    pub error_correction_rate: f64,
    /// OpenCV's own corner refinement (default `none`: [`super::markers::SubpixConfig`] refines
    /// afterwards by fitting the marker's edges).
    pub corner_refinement: ArucoRefinement,
    /// Half window of OpenCV's own refinement, pixels (`cornerRefinementWinSize`, default 5).
    pub corner_refinement_half_window_px: u32,
}

impl Default for ArucoConfig {
    fn default() -> Self {
        ArucoConfig {
            adaptive_thresh_win_size_min: 3,
            adaptive_thresh_win_size_max: 23,
            adaptive_thresh_win_size_step: 10,
            adaptive_thresh_constant: 7.0,
            min_marker_perimeter_rate: 0.03,
            polygonal_approx_accuracy_rate: 0.03,
            min_distance_to_border_px: 3,
            perspective_remove_pixel_per_cell: 4,
            error_correction_rate: 0.6,
            corner_refinement: ArucoRefinement::None,
            corner_refinement_half_window_px: 5,
        }
    }
}

impl ArucoConfig {
    /// Checks the settings; the error names the field (`opencv.…`).
    pub fn validate(&self) -> Result<()> {
        let cfg = self;
        let bad = |field: &str, msg: &str| {
            Err(Error::Config {
                field: format!("opencv.{field}"),
                msg: msg.into(),
            })
        };
        if cfg.adaptive_thresh_win_size_min < 3
            || cfg.adaptive_thresh_win_size_max < cfg.adaptive_thresh_win_size_min
            || cfg.adaptive_thresh_win_size_step == 0
        {
            return bad(
                "adaptive_thresh_win_size_*",
                "need 3 <= min <= max and a positive step",
            );
        }
        if !(cfg.min_marker_perimeter_rate > 0.0 && cfg.min_marker_perimeter_rate < 4.0) {
            return bad("min_marker_perimeter_rate", "must be in (0, 4)");
        }
        if !(cfg.polygonal_approx_accuracy_rate > 0.0 && cfg.polygonal_approx_accuracy_rate < 1.0) {
            return bad("polygonal_approx_accuracy_rate", "must be in (0, 1)");
        }
        if cfg.perspective_remove_pixel_per_cell == 0 {
            return bad("perspective_remove_pixel_per_cell", "must be at least 1");
        }
        if !(0.0..=1.0).contains(&cfg.error_correction_rate) {
            return bad("error_correction_rate", "must be between 0 and 1");
        }
        if !cfg.adaptive_thresh_constant.is_finite() {
            return bad("adaptive_thresh_constant", "must be a number");
        }
        if cfg.corner_refinement_half_window_px == 0 {
            return bad("corner_refinement_half_window_px", "must be at least 1");
        }
        Ok(())
    }
}

/// OpenCV's predefined dictionary for `dict`.
pub(crate) fn dictionary(dict: MarkerDictionary) -> Result<Ptr<Dictionary>> {
    opencv::aruco::get_predefined_dictionary_i32(dict.opencv_index()).map_err(|e| {
        cv::error(
            &format!("getPredefinedDictionary({})", dict.opencv_name()),
            e,
        )
    })
}

/// Every marker of `dict` that OpenCV's detector finds in `img`: `(id, corners in ArUco order)`.
pub(crate) fn detect_aruco(
    img: &GreyImage,
    dict: MarkerDictionary,
    cfg: &ArucoConfig,
) -> Result<Vec<(u32, [Point2<f64>; 4])>> {
    let mat = img.to_mat()?;
    let d = dictionary(dict)?;
    let p = detector_parameters(cfg)?;
    let mut corners: Vector<Vector<Point2f>> = Vector::new();
    let mut ids: Vector<i32> = Vector::new();
    let mut rejected: Vector<Vector<Point2f>> = Vector::new();
    opencv::aruco::detect_markers(&mat, &d, &mut corners, &mut ids, &p, &mut rejected)
        .map_err(|e| cv::error("aruco::detectMarkers", e))?;
    markers_from_cv(&ids, &corners)
}

/// OpenCV's detector parameters for `cfg` (checked first).
pub(crate) fn detector_parameters(cfg: &ArucoConfig) -> Result<Ptr<DetectorParameters>> {
    cfg.validate()?;
    let mut p = DetectorParameters::create().map_err(|e| cv::error("DetectorParameters", e))?;
    p.set_adaptive_thresh_win_size_min(cfg.adaptive_thresh_win_size_min as i32);
    p.set_adaptive_thresh_win_size_max(cfg.adaptive_thresh_win_size_max as i32);
    p.set_adaptive_thresh_win_size_step(cfg.adaptive_thresh_win_size_step as i32);
    p.set_adaptive_thresh_constant(cfg.adaptive_thresh_constant);
    p.set_min_marker_perimeter_rate(cfg.min_marker_perimeter_rate);
    p.set_polygonal_approx_accuracy_rate(cfg.polygonal_approx_accuracy_rate);
    p.set_min_distance_to_border(cfg.min_distance_to_border_px as i32);
    p.set_perspective_remove_pixel_per_cell(cfg.perspective_remove_pixel_per_cell as i32);
    p.set_error_correction_rate(cfg.error_correction_rate);
    p.set_corner_refinement_method(match cfg.corner_refinement {
        ArucoRefinement::None => opencv::aruco::CORNER_REFINE_NONE,
        ArucoRefinement::Subpix => opencv::aruco::CORNER_REFINE_SUBPIX,
        ArucoRefinement::Contour => opencv::aruco::CORNER_REFINE_CONTOUR,
        ArucoRefinement::AprilTag => opencv::aruco::CORNER_REFINE_APRILTAG,
    });
    p.set_corner_refinement_win_size(cfg.corner_refinement_half_window_px as i32);
    Ok(p)
}

/// OpenCV's marker ids and corners as `(id, corners in ArUco order)`; errors on a malformed result.
pub(crate) fn markers_from_cv(
    ids: &Vector<i32>,
    corners: &Vector<Vector<Point2f>>,
) -> Result<Vec<(u32, [Point2<f64>; 4])>> {
    let mut out = Vec::with_capacity(ids.len());
    for (id, c) in ids.iter().zip(corners.iter()) {
        let c = cv::from_points2f(&c);
        if id < 0 || c.len() != 4 {
            return Err(Error::Failed(format!(
                "OpenCV's ArUco detector returned marker {id} with {} corners",
                c.len()
            )));
        }
        out.push((id as u32, [c[0], c[1], c[2], c[3]]));
    }
    Ok(out)
}

/// The inner bits of marker `id` of `dict` as OpenCV's `drawMarker` prints it: `bits()²` values,
/// row-major from the top-left inner cell, `true` = white, the black border excluded.
///
/// For the AprilTag families these are OpenCV's `DICT_APRILTAG_*` tables, which draw each tag turned by a
/// half turn relative to AprilTag's own images: AprilTag's image of the same tag, read row-major from its
/// top-left data cell, is this list reversed.
pub fn dictionary_bits(dict: MarkerDictionary, id: u32) -> Result<Vec<bool>> {
    if id >= dict.marker_count() {
        return Err(Error::InvalidInput(format!(
            "{dict} has markers 0 to {}, not {id}",
            dict.marker_count() - 1
        )));
    }
    let n = dict.bits() as i32;
    let d = dictionary(dict)?;
    let mut img = Mat::default();
    // One pixel per cell, a one-cell border.
    opencv::aruco::draw_marker(&d, id as i32, n + 2, &mut img, 1)
        .map_err(|e| cv::error("aruco::drawMarker", e))?;
    let mut bits = Vec::with_capacity((n * n) as usize);
    for r in 1..=n {
        for c in 1..=n {
            let v = *img
                .at_2d::<u8>(r, c)
                .map_err(|e| cv::error("reading a marker image", e))?;
            bits.push(v > 127);
        }
    }
    Ok(bits)
}
