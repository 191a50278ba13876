//! Pictures of detections for a person to check: the image in colour with each marker's outline, its
//! corner 0 and its id drawn on it.

use super::cv;
use super::image::GreyImage;
use super::markers::MarkerDetection;
use crate::error::{Error, Result};
use opencv::core::{Mat, Point, Scalar, Vector};
use std::path::Path;

/// Fixed-point bits of the drawing coordinates (OpenCV's `shift`): sub-pixel outlines, 1/16 px.
const SHIFT: i32 = 4;

fn fixed(p: nalgebra::Point2<f64>) -> Point {
    let s = (1 << SHIFT) as f64;
    Point::new((p.x * s).round() as i32, (p.y * s).round() as i32)
}

/// Writes `img` with `markers` drawn on it to `path` (the format follows the extension; PNG keeps it
/// exact): each outline in green, corner 0 (the detector's first corner) as a red dot, the id in blue
/// beside the centre. Errors name the file when it cannot be written.
pub fn write_marker_annotation(
    img: &GreyImage,
    markers: &[MarkerDetection],
    path: &Path,
) -> Result<()> {
    let grey = img.to_mat()?;
    let mut bgr = Mat::default();
    opencv::imgproc::cvt_color(&grey, &mut bgr, opencv::imgproc::COLOR_GRAY2BGR, 0)
        .map_err(|e| cv::error("cvtColor", e))?;
    let green = Scalar::new(0.0, 220.0, 0.0, 0.0);
    let red = Scalar::new(0.0, 0.0, 255.0, 0.0);
    let blue = Scalar::new(255.0, 80.0, 0.0, 0.0);
    let aa = opencv::imgproc::LINE_AA;
    for m in markers {
        let side = (0..4)
            .map(|k| (m.corners[(k + 1) % 4] - m.corners[k]).norm())
            .fold(f64::MAX, f64::min);
        let pts: Vector<Point> = m.corners.iter().map(|&p| fixed(p)).collect();
        let polys: Vector<Vector<Point>> = std::iter::once(pts).collect();
        opencv::imgproc::polylines(&mut bgr, &polys, true, green, 1, aa, SHIFT)
            .map_err(|e| cv::error("polylines", e))?;
        let r = ((side / 10.0).clamp(1.5, 8.0) * (1 << SHIFT) as f64) as i32;
        opencv::imgproc::circle(&mut bgr, fixed(m.corners[0]), r, red, -1, aa, SHIFT)
            .map_err(|e| cv::error("circle", e))?;
        let scale = (side / 60.0).clamp(0.35, 1.5);
        let c = m.centre();
        let at = Point::new(
            (c.x - side * 0.25).round() as i32,
            (c.y + side * 0.1).round() as i32,
        );
        opencv::imgproc::put_text(
            &mut bgr,
            &m.id.to_string(),
            at,
            opencv::imgproc::FONT_HERSHEY_SIMPLEX,
            scale,
            blue,
            1,
            aa,
            false,
        )
        .map_err(|e| cv::error("putText", e))?;
    }
    let name = path.to_str().ok_or_else(|| {
        Error::format(path, "the file name is not valid UTF-8, which OpenCV needs")
    })?;
    let ok = opencv::imgcodecs::imwrite(name, &bgr, &Vector::new())
        .map_err(|e| Error::format(path, format!("cannot write the image: {e}")))?;
    if !ok {
        return Err(Error::io(
            path,
            std::io::Error::other(
                "OpenCV could not write the image (missing folder or no permission?)",
            ),
        ));
    }
    Ok(())
}
