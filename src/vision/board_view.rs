//! A calibration board seen in one image, whichever its kind: the corners found, each with its place on
//! the board. A checkerboard view has every inner corner ([`super::corners`]); a ChArUco view has those
//! between the markers found ([`super::charuco`]), which may be a part of the board.

use super::charuco::{detect_charuco, CharucoConfig};
use super::corners::{detect_checkerboard, CornerConfig};
use super::image::GreyImage;
use crate::cell::Board;
use crate::error::Result;
use nalgebra::{Point2, Point3};

/// The corners of a board found in one image.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardView {
    /// Corner ids ([`Board::corner_point`]), ascending.
    pub ids: Vec<u32>,
    /// Pixel coordinates (`(0, 0)` = centre of the top-left pixel) of each corner, same order.
    pub image_points: Vec<Point2<f64>>,
    /// Each corner in the board frame, metres (`z = 0`), same order.
    pub object_points: Vec<Point3<f64>>,
    /// Which detector found them: `classic` or `sector-based` (checkerboard), `charuco`.
    pub detector: &'static str,
    /// ChArUco markers found (0 for a checkerboard).
    pub markers: usize,
}

impl BoardView {
    /// Number of corners found.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// True when no corner was found (never for a view [`detect_board`] returns).
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// Finds `board` in `img` with the settings of its kind: `Ok(None)` when it is not found (a checkerboard
/// not whole, a ChArUco board with fewer than `charuco.min_corners` corners).
pub fn detect_board(
    img: &GreyImage,
    board: &Board,
    corners: &CornerConfig,
    charuco: &CharucoConfig,
) -> Result<Option<BoardView>> {
    Ok(match board {
        Board::Checkerboard(b) => detect_checkerboard(img, b, corners)?.map(|c| BoardView {
            ids: (0..c.points.len() as u32).collect(),
            image_points: c.points,
            object_points: b.object_points(),
            detector: c.detector,
            markers: 0,
        }),
        Board::Charuco(b) => detect_charuco(img, b, charuco)?.map(|c| BoardView {
            object_points: c.ids.iter().filter_map(|&k| b.corner_point(k)).collect(),
            ids: c.ids,
            image_points: c.points,
            detector: "charuco",
            markers: c.markers.len(),
        }),
    })
}
