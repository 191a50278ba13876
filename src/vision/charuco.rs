//! ChArUco corners: OpenCV 4.6's aruco module finds the board's markers (`detectMarkers`, then
//! `refineDetectedMarkers` with the board layout to recover missed ones), interpolates the chessboard
//! corners between them (`interpolateCornersCharuco`, local homographies from the markers, no camera model
//! needed) and refines them; then `cornerSubPix` refines them again to a thousandth of a pixel with a window
//! that stays clear of the markers (OpenCV stops its own refinement at 0.1 px).
//!
//! Each corner comes with its id (see [`CharucoBoard`] for the layout), so a board partly out of the image,
//! or partly hidden, still gives the corners between the markers that are seen. A corner is interpolated
//! only where [`CharucoConfig::min_adjacent_markers`] of the two markers beside it were found (OpenCV's
//! `minMarkers`, default 2), and a view counts only with at least [`CharucoConfig::min_corners`] corners
//! not all on one line (a board pose needs them).

use super::aruco::{detector_parameters, dictionary, markers_from_cv, ArucoConfig};
use super::cv;
use super::image::GreyImage;
use crate::cell::CharucoBoard;
use crate::error::{Error, Result};
use nalgebra::Point2;
use opencv::aruco::{BoardTraitConst, CharucoBoardTrait};
use opencv::core::{Mat, Point2f, Ptr, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

/// ChArUco detection settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CharucoConfig {
    /// The marker detector (OpenCV's ArUco detector settings).
    pub aruco: ArucoConfig,
    /// Recover markers the detector missed from the board layout (`refineDetectedMarkers`; default true).
    pub refine_markers: bool,
    /// Found markers beside a corner needed to interpolate it, 1 or 2 (OpenCV's `minMarkers`, default 2:
    /// both).
    pub min_adjacent_markers: u32,
    /// Refine the corners again with `cornerSubPix` to `subpix_epsilon_px` (default true).
    pub subpix: bool,
    /// Half side of that `cornerSubPix` window, pixels. Default none: per corner, 90% of the white gap
    /// between its squares and the nearest marker, measured in the image as the distance to the nearest
    /// marker corner over √2, 2–11 px (a larger window reaches into the markers and biases the corner; 90%
    /// is the most accurate of 60–110% on rendered views, see docs/vision.md).
    pub subpix_half_window_px: Option<u32>,
    /// Most `cornerSubPix` iterations (default 50).
    pub subpix_max_iterations: u32,
    /// `cornerSubPix` stops when a corner moves less than this, pixels (default 0.001).
    pub subpix_epsilon_px: f64,
    /// Fewest corners for a view to count (default 6; at least 4).
    pub min_corners: usize,
}

impl Default for CharucoConfig {
    fn default() -> Self {
        CharucoConfig {
            aruco: ArucoConfig::default(),
            refine_markers: true,
            min_adjacent_markers: 2,
            subpix: true,
            subpix_half_window_px: None,
            subpix_max_iterations: 50,
            subpix_epsilon_px: 0.001,
            min_corners: 6,
        }
    }
}

impl CharucoConfig {
    /// Checks the values; the error names the field.
    pub fn validate(&self) -> Result<()> {
        if !(1..=2).contains(&self.min_adjacent_markers) {
            return Err(Error::config(
                "charuco.min_adjacent_markers",
                format!("must be 1 or 2, found {}", self.min_adjacent_markers),
            ));
        }
        if self.min_corners < 4 {
            return Err(Error::config(
                "charuco.min_corners",
                format!(
                    "must be at least 4 (a board pose needs them), found {}",
                    self.min_corners
                ),
            ));
        }
        if !(self.subpix_epsilon_px.is_finite() && self.subpix_epsilon_px > 0.0) {
            return Err(Error::config(
                "charuco.subpix_epsilon_px",
                format!(
                    "must be a positive number of pixels, found {}",
                    self.subpix_epsilon_px
                ),
            ));
        }
        if self.subpix_half_window_px == Some(0) {
            return Err(Error::config(
                "charuco.subpix_half_window_px",
                "must be at least 1 pixel",
            ));
        }
        Ok(())
    }
}

/// The ChArUco corners found in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct CharucoCorners {
    /// Corner ids ([`CharucoBoard::corner_point`]), ascending.
    pub ids: Vec<u32>,
    /// Pixel coordinates of each corner (`(0, 0)` = centre of the top-left pixel), same order as `ids`.
    pub points: Vec<Point2<f64>>,
    /// Ids of the board's markers found (after recovery), ascending.
    pub markers: Vec<u32>,
    /// Markers recovered from the board layout (`refineDetectedMarkers`).
    pub recovered_markers: usize,
}

/// OpenCV's board for `board`.
fn cv_board(board: &CharucoBoard) -> Result<Ptr<opencv::aruco::CharucoBoard>> {
    let d = dictionary(board.dictionary)?;
    opencv::aruco::CharucoBoard::create(
        board.squares_x as i32,
        board.squares_y as i32,
        board.square_m as f32,
        board.marker_m as f32,
        &d,
    )
    .map_err(|e| cv::error("aruco::CharucoBoard::create", e))
}

/// Finds the board's corners in `img`: `Ok(None)` when fewer than `cfg.min_corners` corners (or only
/// collinear ones) are found; errors only for bad settings or when OpenCV fails.
pub fn detect_charuco(
    img: &GreyImage,
    board: &CharucoBoard,
    cfg: &CharucoConfig,
) -> Result<Option<CharucoCorners>> {
    cfg.validate()?;
    board
        .validate()
        .map_err(|(k, m)| Error::config(format!("board.{k}"), m))?;
    let mat = img.to_mat()?;
    let dict = dictionary(board.dictionary)?;
    let params = detector_parameters(&cfg.aruco)?;
    let mut corners: Vector<Vector<Point2f>> = Vector::new();
    let mut ids: Vector<i32> = Vector::new();
    let mut rejected: Vector<Vector<Point2f>> = Vector::new();
    opencv::aruco::detect_markers(&mat, &dict, &mut corners, &mut ids, &params, &mut rejected)
        .map_err(|e| cv::error("aruco::detectMarkers", e))?;
    let cvb = cv_board(board)?;
    let mut recovered_markers = 0;
    if cfg.refine_markers && !ids.is_empty() {
        let generic: Ptr<opencv::aruco::Board> = cv_board(board)?.into();
        let mut recovered: Vector<i32> = Vector::new();
        let before = ids.len();
        opencv::aruco::refine_detected_markers(
            &mat,
            &generic,
            &mut corners,
            &mut ids,
            &mut rejected,
            &Mat::default(),
            &Mat::default(),
            10.0,
            3.0,
            true,
            &mut recovered,
            &params,
        )
        .map_err(|e| cv::error("aruco::refineDetectedMarkers", e))?;
        recovered_markers = ids.len().saturating_sub(before);
    }
    // Only the board's own markers (another board or stray markers in view are left out).
    let found = markers_from_cv(&ids, &corners)?;
    let mine: Vec<(u32, [Point2<f64>; 4])> = found
        .into_iter()
        .filter(|(id, _)| *id < board.marker_count())
        .collect();
    if mine.is_empty() {
        return Ok(None);
    }
    let m_ids: Vector<i32> = mine.iter().map(|(id, _)| *id as i32).collect();
    let m_corners: Vector<Vector<Point2f>> = mine.iter().map(|(_, c)| cv::points2f(c)).collect();
    let mut ch_corners: Vector<Point2f> = Vector::new();
    let mut ch_ids: Vector<i32> = Vector::new();
    opencv::aruco::interpolate_corners_charuco(
        &m_corners,
        &m_ids,
        &mat,
        &cvb,
        &mut ch_corners,
        &mut ch_ids,
        &Mat::default(),
        &Mat::default(),
        cfg.min_adjacent_markers as i32,
    )
    .map_err(|e| cv::error("aruco::interpolateCornersCharuco", e))?;
    let mut pts = cv::from_points2f(&ch_corners);
    let mut cids: Vec<u32> = Vec::with_capacity(ch_ids.len());
    for id in ch_ids.iter() {
        if id < 0 || id as usize >= board.corner_count() {
            return Err(Error::Failed(format!(
                "OpenCV's ChArUco interpolation returned corner {id} of a board with {} corners",
                board.corner_count()
            )));
        }
        cids.push(id as u32);
    }
    if cfg.subpix && !pts.is_empty() {
        let marker_pts: Vec<Point2<f64>> = mine.iter().flat_map(|(_, c)| *c).collect();
        (cids, pts) = refine(&mat, &cids, &pts, &marker_pts, cfg)?;
    }
    let mut order: Vec<usize> = (0..cids.len()).collect();
    order.sort_by_key(|&k| cids[k]);
    let ids: Vec<u32> = order.iter().map(|&k| cids[k]).collect();
    let points: Vec<Point2<f64>> = order.iter().map(|&k| pts[k]).collect();
    if points.len() < cfg.min_corners
        || board.corners_collinear(&ids)
        || points.iter().any(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Ok(None);
    }
    let mut markers: Vec<u32> = mine.iter().map(|(id, _)| *id).collect();
    markers.sort_unstable();
    Ok(Some(CharucoCorners {
        ids,
        points,
        markers,
        recovered_markers,
    }))
}

/// `cornerSubPix` on each corner with its own window (see [`CharucoConfig::subpix_half_window_px`]);
/// a corner that moves farther than its window (it found another corner) is dropped.
fn refine(
    mat: &Mat,
    ids: &[u32],
    pts: &[Point2<f64>],
    marker_pts: &[Point2<f64>],
    cfg: &CharucoConfig,
) -> Result<(Vec<u32>, Vec<Point2<f64>>)> {
    let crit = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        cfg.subpix_max_iterations as i32,
        cfg.subpix_epsilon_px,
    )
    .map_err(|e| cv::error("TermCriteria", e))?;
    let mut out_ids = Vec::with_capacity(ids.len());
    let mut out = Vec::with_capacity(pts.len());
    for (&id, p) in ids.iter().zip(pts) {
        let half = cfg.subpix_half_window_px.unwrap_or_else(|| {
            let d = marker_pts
                .iter()
                .map(|q| (q - p).norm())
                .fold(f64::INFINITY, f64::min);
            ((0.9 * d / std::f64::consts::SQRT_2).floor() as u32).clamp(2, 11)
        });
        let mut one: Vector<Point2f> = cv::points2f(std::slice::from_ref(p));
        opencv::imgproc::corner_sub_pix(
            mat,
            &mut one,
            Size::new(half as i32, half as i32),
            Size::new(-1, -1),
            crit,
        )
        .map_err(|e| cv::error("cornerSubPix", e))?;
        let q = cv::from_points2f(&one)[0];
        if (q - p).norm() <= half as f64 {
            out_ids.push(id);
            out.push(q);
        }
    }
    Ok((out_ids, out))
}

/// OpenCV's own drawing of the board (`CharucoBoard::draw`): `px_per_square` pixels per square, a white
/// margin of `margin_px`, one-cell marker borders. For checking a printed or rendered board against
/// OpenCV's.
pub fn charuco_image(
    board: &CharucoBoard,
    px_per_square: u32,
    margin_px: u32,
) -> Result<GreyImage> {
    if !(4..=1000).contains(&px_per_square) || margin_px > 10_000 {
        return Err(Error::InvalidInput(format!(
            "ChArUco image: {px_per_square} px per square (4–1000) and a margin of {margin_px} px \
             (at most 10000)"
        )));
    }
    let mut b = cv_board(board)?;
    let (w, h) = (
        board.squares_x * px_per_square + 2 * margin_px,
        board.squares_y * px_per_square + 2 * margin_px,
    );
    let mut img = Mat::default();
    b.draw(Size::new(w as i32, h as i32), &mut img, margin_px as i32, 1)
        .map_err(|e| cv::error("aruco::CharucoBoard::draw", e))?;
    let data = img
        .data_bytes()
        .map_err(|e| cv::error("reading the board image", e))?
        .to_vec();
    GreyImage::new(img.cols() as u32, img.rows() as u32, data)
}

/// The marker ids of OpenCV's board (checks that OpenCV numbers them `0..marker_count` as
/// [`CharucoBoard`] documents).
pub fn opencv_marker_ids(board: &CharucoBoard) -> Result<Vec<u32>> {
    let b = cv_board(board)?;
    Ok(b.ids().iter().map(|i| i.max(0) as u32).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cell::MarkerDictionary;
    use nalgebra::Point3;

    fn board() -> CharucoBoard {
        CharucoBoard::new(5, 7, 0.04, 0.02, MarkerDictionary::Aruco6x6_250).unwrap()
    }

    /// OpenCV's own marker and corner positions are the layout [`CharucoBoard`] documents.
    #[test]
    fn opencv_board_geometry_is_the_documented_one() {
        for b in [
            board(),
            CharucoBoard::new(4, 6, 0.03, 0.022, MarkerDictionary::Aruco4x4_50).unwrap(),
        ] {
            let cvb = cv_board(&b).unwrap();
            let obj = cvb.obj_points();
            assert_eq!(obj.len() as u32, b.marker_count());
            assert_eq!(
                opencv_marker_ids(&b).unwrap(),
                (0..b.marker_count()).collect::<Vec<_>>()
            );
            for (id, m) in obj.iter().enumerate() {
                let ours = b.marker_corners(id as u32).unwrap();
                for (p, q) in m.iter().zip(ours) {
                    let p = Point3::new(p.x as f64, p.y as f64, p.z as f64);
                    assert!((p - q).norm() < 1e-6, "{b}: marker {id}: {p} vs {q}");
                }
            }
            let cc = cvb.chessboard_corners();
            assert_eq!(cc.len(), b.corner_count());
            for (k, p) in cc.iter().enumerate() {
                let q = b.corner_point(k as u32).unwrap();
                assert!(
                    (Point3::new(p.x as f64, p.y as f64, 0.0) - q).norm() < 1e-6,
                    "{b}: corner {k}"
                );
            }
        }
    }

    /// On OpenCV's own image of the board, every corner is found where the image puts it.
    #[test]
    fn corners_of_opencvs_own_image() {
        let b = board();
        let (px, margin) = (60u32, 30u32);
        let img = charuco_image(&b, px, margin).unwrap();
        let c = detect_charuco(&img, &b, &CharucoConfig::default())
            .unwrap()
            .expect("board found");
        assert_eq!(c.ids, (0..24).collect::<Vec<_>>());
        assert_eq!(c.markers.len(), 17);
        for (id, p) in c.ids.iter().zip(&c.points) {
            let q = b.corner_point(*id).unwrap();
            // Pixel edges are at integers; a corner between pixels k−1 and k is at k − 0.5.
            let e = Point2::new(
                margin as f64 + q.x / b.square_m * px as f64 - 0.5,
                margin as f64 + q.y / b.square_m * px as f64 - 0.5,
            );
            assert!((p - e).norm() < 0.1, "corner {id}: {p} vs {e}");
        }
        // A blank image and bad settings.
        let blank = GreyImage::new(200, 100, vec![200; 20_000]).unwrap();
        assert!(detect_charuco(&blank, &b, &CharucoConfig::default())
            .unwrap()
            .is_none());
        let bad = CharucoConfig {
            min_corners: 3,
            ..Default::default()
        };
        let e = detect_charuco(&img, &b, &bad).unwrap_err().to_string();
        assert!(e.contains("charuco.min_corners"), "{e}");
        // Another dictionary's board shows nothing of this one.
        let other = CharucoBoard::new(5, 7, 0.04, 0.02, MarkerDictionary::Aruco4x4_50).unwrap();
        assert!(detect_charuco(&img, &other, &CharucoConfig::default())
            .unwrap()
            .is_none());
    }
}
