//! Checkerboard inner-corner detection with subpixel refinement, in the board's canonical corner order.
//!
//! OpenCV's `findChessboardCorners` (adaptive threshold, normalised image) finds the corners (optionally,
//! failing that, the sector-based `findChessboardCornersSB`); `cornerSubPix` refines them with a window
//! sized from the corner spacing. OpenCV may return the
//! rows or the columns in either direction, so the order is then made canonical for
//! [`Checkerboard`]'s frame:
//!
//! 1. *Handedness*: with image `u` right and `v` down, the image directions of board `x` (along a row)
//!    and `y` (along a column) must satisfy `x̂ × ŷ > 0`, which makes the board `z` point away from
//!    the camera (the camera sees the printed side). Otherwise each row is reversed.
//! 2. *Half turn*: for a board with `cols + rows` odd, the squares between inner corners whose index sum
//!    is even must be the dark ones; otherwise the whole list is reversed. For a symmetric board
//!    (`cols + rows` even) the half turn cannot be told and [`BoardCorners::order_unique`] is false.

use super::cv;
use super::image::GreyImage;
use crate::cell::Checkerboard;
use crate::error::{check, Error, Result};
use nalgebra::{Point2, Vector2};
use opencv::core::{Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use serde::{Deserialize, Serialize};

/// Corner detection settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CornerConfig {
    /// Half side of the `cornerSubPix` search window, pixels (OpenCV's `winSize`; the window is
    /// `2·n + 1` pixels wide). Default none: 40% of the smallest distance between neighbouring corners,
    /// between 2 and 11 px, so the window never reaches a neighbouring corner.
    pub subpix_half_window_px: Option<u32>,
    /// Most `cornerSubPix` iterations (default 50).
    pub subpix_max_iterations: u32,
    /// `cornerSubPix` stops when a corner moves less than this, pixels (default 0.001).
    pub subpix_epsilon_px: f64,
    /// When the classic detector fails, try the sector-based one (`findChessboardCornersSB`, slower,
    /// more tolerant of blur and noise). Default false: it also finds a smaller pattern inside a larger
    /// board (measured: 8x5 inside OpenCV's 9x6 sample images), so a wrong `--board` would go unnoticed.
    pub sector_based_fallback: bool,
}

impl CornerConfig {
    /// Checks the values; the error names the field (`corners.…`).
    pub fn validate(&self) -> Result<()> {
        if self.subpix_half_window_px == Some(0) {
            return Err(Error::config(
                "corners.subpix_half_window_px",
                "must be at least 1 pixel",
            ));
        }
        check::at_least(
            "corners.subpix_max_iterations",
            self.subpix_max_iterations as usize,
            1,
        )?;
        check::positive("corners.subpix_epsilon_px", self.subpix_epsilon_px)
    }
}

impl Default for CornerConfig {
    fn default() -> Self {
        CornerConfig {
            subpix_half_window_px: None,
            subpix_max_iterations: 50,
            subpix_epsilon_px: 0.001,
            sector_based_fallback: false,
        }
    }
}

/// The inner corners found in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardCorners {
    /// Pixel coordinates (`(0, 0)` = centre of the top-left pixel) of the `cols · rows` inner corners in
    /// the board's row-major order.
    pub points: Vec<Point2<f64>>,
    /// Which detector found them: `classic` or `sector-based`.
    pub detector: &'static str,
    /// The corner order is certain (false for a symmetric board: it may be off by a half turn).
    pub order_unique: bool,
    /// The `cornerSubPix` half window used, pixels (0 for the sector-based detector, which refines itself).
    pub subpix_half_window_px: u32,
}

/// Finds the board's inner corners in `img`: `Ok(None)` when the board is not found, errors only when
/// OpenCV fails.
pub fn detect_checkerboard(
    img: &GreyImage,
    board: &Checkerboard,
    cfg: &CornerConfig,
) -> Result<Option<BoardCorners>> {
    cfg.validate()?;
    let mat = img.to_mat()?;
    let size = Size::new(board.cols as i32, board.rows as i32);
    let mut found: Vector<Point2f> = Vector::new();
    let flags =
        opencv::calib3d::CALIB_CB_ADAPTIVE_THRESH | opencv::calib3d::CALIB_CB_NORMALIZE_IMAGE;
    let classic = opencv::calib3d::find_chessboard_corners(&mat, size, &mut found, flags)
        .map_err(|e| cv::error("findChessboardCorners", e))?;
    let n = board.corner_count();
    let (detector, mut points, half) = if classic && found.len() == n {
        let pts = cv::from_points2f(&found);
        let half = cfg
            .subpix_half_window_px
            .unwrap_or_else(|| auto_half_window(&pts, board));
        let crit = TermCriteria::new(
            TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
            cfg.subpix_max_iterations as i32,
            cfg.subpix_epsilon_px,
        )
        .map_err(|e| cv::error("TermCriteria", e))?;
        opencv::imgproc::corner_sub_pix(
            &mat,
            &mut found,
            Size::new(half as i32, half as i32),
            Size::new(-1, -1),
            crit,
        )
        .map_err(|e| cv::error("cornerSubPix", e))?;
        ("classic", cv::from_points2f(&found), half)
    } else if cfg.sector_based_fallback {
        let mut sb: Vector<Point2f> = Vector::new();
        let flags = opencv::calib3d::CALIB_CB_EXHAUSTIVE | opencv::calib3d::CALIB_CB_ACCURACY;
        let ok = opencv::calib3d::find_chessboard_corners_sb(&mat, size, &mut sb, flags)
            .map_err(|e| cv::error("findChessboardCornersSB", e))?;
        if !ok || sb.len() != n {
            return Ok(None);
        }
        ("sector-based", cv::from_points2f(&sb), 0)
    } else {
        return Ok(None);
    };
    if points.iter().any(|p| !(p.x.is_finite() && p.y.is_finite())) {
        return Ok(None);
    }
    canonical_order(&mut points, board, img);
    Ok(Some(BoardCorners {
        points,
        detector,
        order_unique: !board.is_symmetric(),
        subpix_half_window_px: half,
    }))
}

/// 40% of the smallest neighbour distance, clamped to 2–11 px.
fn auto_half_window(p: &[Point2<f64>], board: &Checkerboard) -> u32 {
    let (c, r) = (board.cols as usize, board.rows as usize);
    let mut d = f64::MAX;
    for j in 0..r {
        for i in 0..c {
            let k = j * c + i;
            if i + 1 < c {
                d = d.min((p[k + 1] - p[k]).norm());
            }
            if j + 1 < r {
                d = d.min((p[k + c] - p[k]).norm());
            }
        }
    }
    ((0.4 * d).floor() as u32).clamp(2, 11)
}

/// Bilinear grey value at a sub-pixel position (clamped to the image).
fn sample(img: &GreyImage, p: Point2<f64>) -> f64 {
    let (w, h) = (img.width as f64, img.height as f64);
    let x = p.x.clamp(0.0, w - 1.0);
    let y = p.y.clamp(0.0, h - 1.0);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as u32, y0 as u32);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let g = |u, v| img.at(u, v) as f64;
    (1.0 - fy) * ((1.0 - fx) * g(x0, y0) + fx * g(x1, y0))
        + fy * ((1.0 - fx) * g(x0, y1) + fx * g(x1, y1))
}

/// Puts the corners into the board's canonical order (see the module documentation).
fn canonical_order(p: &mut [Point2<f64>], board: &Checkerboard, img: &GreyImage) {
    let (c, r) = (board.cols as usize, board.rows as usize);
    let dx: Vector2<f64> = p[c - 1] - p[0];
    let dy: Vector2<f64> = p[(r - 1) * c] - p[0];
    if dx.x * dy.y - dx.y * dy.x < 0.0 {
        for row in p.chunks_mut(c) {
            row.reverse();
        }
    }
    if board.is_symmetric() {
        return;
    }
    // Squares (a, b) with a in 1..cols, b in 1..rows lie between inner corners (a-1..a, b-1..b); they are
    // dark when a + b is even.
    let mut score = 0.0;
    for b in 1..r {
        for a in 1..c {
            let k = |i: usize, j: usize| p[j * c + i];
            let (p00, p10, p01, p11) = (k(a - 1, b - 1), k(a, b - 1), k(a - 1, b), k(a, b));
            let centre = Point2::from((p00.coords + p10.coords + p01.coords + p11.coords) / 4.0);
            let d1 = (p11 - p00) * 0.2;
            let d2 = (p10 - p01) * 0.2;
            let g = (sample(img, centre)
                + sample(img, centre + d1)
                + sample(img, centre - d1)
                + sample(img, centre + d2)
                + sample(img, centre - d2))
                / 5.0;
            score += if (a + b) % 2 == 0 { -g } else { g };
        }
    }
    if score < 0.0 {
        p.reverse();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic fronto-parallel board image: `px` pixels per square, the black square before corner 0
    /// at the top-left, with the board's x axis along `u` (or mirrored/turned by the arguments).
    fn synthetic(board: &Checkerboard, px: f64, turned: bool) -> GreyImage {
        let (w, h) = (
            ((board.cols + 3) as f64 * px) as u32,
            ((board.rows + 3) as f64 * px) as u32,
        );
        let mut data = vec![200u8; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                // 4x4 supersampling of the pixel footprint.
                let mut acc = 0.0f64;
                for s in 0..16 {
                    let (su, sv) = ((s % 4) as f64 / 4.0 - 0.375, (s / 4) as f64 / 4.0 - 0.375);
                    let (mut x, mut y) = ((u as f64 + su) / px - 2.0, (v as f64 + sv) / px - 2.0);
                    if turned {
                        x = (board.cols - 1) as f64 - x;
                        y = (board.rows - 1) as f64 - y;
                    }
                    acc += match board.is_black(x * board.square_m, y * board.square_m) {
                        Some(true) => 20.0,
                        _ => 200.0,
                    };
                }
                data[(v * w + u) as usize] = (acc / 16.0).round() as u8;
            }
        }
        GreyImage::new(w, h, data).unwrap()
    }

    #[test]
    fn corners_are_found_accurately_in_canonical_order() {
        let board = Checkerboard::new(9, 6, 0.03).unwrap();
        let px = 24.0;
        for turned in [false, true] {
            let img = synthetic(&board, px, turned);
            let c = detect_checkerboard(&img, &board, &CornerConfig::default())
                .unwrap()
                .expect("board found");
            assert!(c.order_unique);
            let mut worst: f64 = 0.0;
            for (k, q) in c.points.iter().enumerate() {
                let (i, j) = ((k % 9) as f64, (k / 9) as f64);
                let (x, y) = if turned { (8.0 - i, 5.0 - j) } else { (i, j) };
                // Corner (i, j) lies at pixel ((x + 2)·px, (y + 2)·px) (pixel (0, 0) centred at the origin).
                let e = Point2::new((x + 2.0) * px, (y + 2.0) * px);
                worst = worst.max((q - e).norm());
            }
            assert!(
                worst < 0.05,
                "turned {turned}: worst corner error {worst} px"
            );
        }
        let blank = GreyImage::new(100, 80, vec![128; 8000]).unwrap();
        assert!(
            detect_checkerboard(&blank, &board, &CornerConfig::default())
                .unwrap()
                .is_none()
        );
    }
}
