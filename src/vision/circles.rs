//! Symmetric circle grids with one large dot marking the origin (ROS-Industrial's "modified circle grid"),
//! for real hand-eye data sets that use them.
//!
//! OpenCV's `findCirclesGrid` (symmetric grid, default blob detector: dark dots) finds the dot centres;
//! the order is then made canonical like [`crate::vision::corners`]: right-handed in the image (board `z`
//! away from the camera), and turned (by quarter turns on a square grid, half turns otherwise) so that the
//! large dot is dot 0. Dot `j·cols + i` is at `(i·spacing, j·spacing, 0)` in the grid frame.

use super::cv;
use super::image::GreyImage;
use crate::error::{Error, Result};
use nalgebra::{Point2, Point3};
use opencv::core::{Point2f, Size, Vector};

/// A symmetric grid of dots with a large origin dot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CircleGrid {
    /// Dots along the grid x axis.
    pub cols: u32,
    /// Dots along the grid y axis.
    pub rows: u32,
    /// Distance between neighbouring dot centres, metres.
    pub spacing_m: f64,
}

impl CircleGrid {
    /// The dot centres in the grid frame (metres, `z = 0`), row-major.
    pub fn object_points(&self) -> Vec<Point3<f64>> {
        let s = self.spacing_m;
        (0..self.rows)
            .flat_map(|j| (0..self.cols).map(move |i| Point3::new(i as f64 * s, j as f64 * s, 0.0)))
            .collect()
    }
}

/// Finds the grid's dot centres in canonical order (see the module documentation); `Ok(None)` when the
/// grid or its large dot is not found.
pub fn detect_circle_grid(img: &GreyImage, grid: &CircleGrid) -> Result<Option<Vec<Point2<f64>>>> {
    if grid.cols < 2 || grid.rows < 2 || grid.spacing_m.is_nan() || grid.spacing_m <= 0.0 {
        return Err(Error::InvalidInput(format!(
            "circle grid {}x{} with spacing {} m: need at least 2x2 dots and a positive spacing",
            grid.cols, grid.rows, grid.spacing_m
        )));
    }
    let mat = img.to_mat()?;
    let mut found: Vector<Point2f> = Vector::new();
    let ok = opencv::calib3d::find_circles_grid_def(
        &mat,
        Size::new(grid.cols as i32, grid.rows as i32),
        &mut found,
    )
    .map_err(|e| cv::error("findCirclesGrid", e))?;
    let (c, r) = (grid.cols as usize, grid.rows as usize);
    if !ok || found.len() != c * r {
        return Ok(None);
    }
    let mut g: Vec<Point2<f64>> = cv::from_points2f(&found);
    // Handedness: reverse the rows when x̂ × ŷ < 0 in the image.
    let dx = g[c - 1] - g[0];
    let dy = g[(r - 1) * c] - g[0];
    if dx.x * dy.y - dx.y * dy.x < 0.0 {
        for row in g.chunks_mut(c) {
            row.reverse();
        }
    }
    // Dark area around each of the four corner dots; the large dot has the most.
    let spacing_px = ((g[1] - g[0]).norm() + (g[c] - g[0]).norm()) / 2.0;
    let corners = [0, c - 1, (r - 1) * c + c - 1, (r - 1) * c];
    let dark: Vec<f64> = corners
        .iter()
        .map(|&k| dark_fraction(img, g[k], 0.38 * spacing_px))
        .collect();
    let best = (0..4).max_by(|&a, &b| dark[a].total_cmp(&dark[b])).unwrap();
    let mut sorted = dark.clone();
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted[0] < 1.6 * sorted[1] {
        return Ok(None); // no clearly larger dot
    }
    // Turn the grid so that corner `best` (counted counter-clockwise in index space from (0, 0)) becomes
    // dot 0: `best` quarter turns.
    for _ in 0..best {
        if c == r {
            g = quarter_turn(&g, c);
        } else {
            return if best == 2 {
                g.reverse();
                Ok(Some(g))
            } else {
                Ok(None) // a non-square grid cannot have its origin dot at a side corner
            };
        }
    }
    Ok(Some(g))
}

/// The grid turned by a quarter: the dot at index corner 1 (`(c−1, 0)`) becomes dot 0.
fn quarter_turn(g: &[Point2<f64>], n: usize) -> Vec<Point2<f64>> {
    // New (i, j) is old (n−1−j, i): new (0, 0) = old (n−1, 0); new x runs along old y.
    let mut out = Vec::with_capacity(g.len());
    for j in 0..n {
        for i in 0..n {
            out.push(g[i * n + (n - 1 - j)]);
        }
    }
    out
}

/// Fraction of pixels within `radius` of `c` darker than the midpoint of the local grey range.
fn dark_fraction(img: &GreyImage, c: Point2<f64>, radius: f64) -> f64 {
    let r = radius.ceil() as i64 + 1;
    let (cx, cy) = (c.x.round() as i64, c.y.round() as i64);
    let mut vals = Vec::new();
    for v in (cy - 2 * r)..=(cy + 2 * r) {
        for u in (cx - 2 * r)..=(cx + 2 * r) {
            if u < 0 || v < 0 || u >= img.width as i64 || v >= img.height as i64 {
                continue;
            }
            let d = ((u as f64 - c.x).powi(2) + (v as f64 - c.y).powi(2)).sqrt();
            vals.push((d, img.at(u as u32, v as u32) as f64));
        }
    }
    if vals.is_empty() {
        return 0.0;
    }
    let lo = vals.iter().map(|v| v.1).fold(f64::MAX, f64::min);
    let hi = vals.iter().map(|v| v.1).fold(f64::MIN, f64::max);
    let mid = (lo + hi) / 2.0;
    let inside: Vec<f64> = vals.iter().filter(|v| v.0 <= radius).map(|v| v.1).collect();
    inside.iter().filter(|&&g| g < mid).count() as f64 / inside.len().max(1) as f64
}
