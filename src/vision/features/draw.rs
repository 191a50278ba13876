//! The picture of a set of matches: the two images side by side, each match a line between its
//! keypoints, green for inliers and red for outliers.

use super::super::cv;
use super::super::image::GreyImage;
use crate::camera::RgbImage;
use crate::error::{Error, Result};
use nalgebra::Point2;
use opencv::core::{Mat, Point, Scalar, Vec3b};
use opencv::imgproc::{circle, line, LINE_AA};

/// Colour of an inlier match (RGB).
const INLIER: [f64; 3] = [0.0, 220.0, 0.0];
/// Colour of an outlier match (RGB).
const OUTLIER: [f64; 3] = [235.0, 30.0, 30.0];
/// Sub-pixel bits of OpenCV's drawing coordinates.
const SHIFT: i32 = 4;

/// `img1` and `img2` side by side (`img2` to the right, both top-aligned, black below the shorter one),
/// with a line and end circles for every pair `(p1 in img1, p2 in img2)`, pixels: green where
/// `inliers[i]`, red otherwise (outliers are drawn first, so inliers stay visible).
///
/// Errors when `pairs` and `inliers` differ in length.
pub fn draw_matches(
    img1: &GreyImage,
    img2: &GreyImage,
    pairs: &[(Point2<f64>, Point2<f64>)],
    inliers: &[bool],
) -> Result<RgbImage> {
    if pairs.len() != inliers.len() {
        return Err(Error::InvalidInput(format!(
            "{} matches with {} inlier flags",
            pairs.len(),
            inliers.len()
        )));
    }
    let (w, h) = (img1.width + img2.width, img1.height.max(img2.height));
    let mut data = vec![0u8; w as usize * h as usize * 3];
    for (img, x0) in [(img1, 0), (img2, img1.width)] {
        for v in 0..img.height {
            for u in 0..img.width {
                let g = img.at(u, v);
                let k = ((v * w + x0 + u) * 3) as usize;
                data[k..k + 3].copy_from_slice(&[g, g, g]);
            }
        }
    }
    {
        let mut m = Mat::new_rows_cols_with_bytes_mut::<Vec3b>(h as i32, w as i32, &mut data)
            .map_err(|e| cv::error("wrapping the match image", e))?;
        let fixed = |p: &Point2<f64>, dx: f64| {
            let s = (1 << SHIFT) as f64;
            Point::new(
                ((p.x + dx) * s).round().clamp(-1e8, 1e8) as i32,
                (p.y * s).round().clamp(-1e8, 1e8) as i32,
            )
        };
        let dx = img1.width as f64;
        for pass_inliers in [false, true] {
            let c = if pass_inliers { INLIER } else { OUTLIER };
            let colour = Scalar::new(c[0], c[1], c[2], 0.0);
            for ((a, b), &inl) in pairs.iter().zip(inliers) {
                if inl != pass_inliers {
                    continue;
                }
                let (pa, pb) = (fixed(a, 0.0), fixed(b, dx));
                let r = 3 << SHIFT;
                line(&mut m, pa, pb, colour, 1, LINE_AA, SHIFT)
                    .map_err(|e| cv::error("drawing a match", e))?;
                circle(&mut m, pa, r, colour, 1, LINE_AA, SHIFT)
                    .map_err(|e| cv::error("drawing a keypoint", e))?;
                circle(&mut m, pb, r, colour, 1, LINE_AA, SHIFT)
                    .map_err(|e| cv::error("drawing a keypoint", e))?;
            }
        }
    }
    Ok(RgbImage {
        width: w,
        height: h,
        data,
    })
}
