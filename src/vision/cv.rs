//! Conversions between OpenCV and the crate's types; nothing outside `vision` sees these.

use crate::camera::{DistortionModel, Intrinsics};
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use opencv::core::{Mat, Point2f, Point3f, Vector, CV_64F};
use opencv::prelude::*;

/// An OpenCV error as the crate's error, saying what was being done.
pub(crate) fn error(what: &str, e: opencv::Error) -> Error {
    Error::Failed(format!("OpenCV, {what}: {e}"))
}

pub(crate) fn points2f(p: &[Point2<f64>]) -> Vector<Point2f> {
    p.iter()
        .map(|q| Point2f::new(q.x as f32, q.y as f32))
        .collect()
}

pub(crate) fn points3f(p: &[Point3<f64>]) -> Vector<Point3f> {
    p.iter()
        .map(|q| Point3f::new(q.x as f32, q.y as f32, q.z as f32))
        .collect()
}

pub(crate) fn from_points2f(v: &Vector<Point2f>) -> Vec<Point2<f64>> {
    v.iter()
        .map(|q| Point2::new(q.x as f64, q.y as f64))
        .collect()
}

/// A `rows × cols` `CV_64F` matrix from row-major values.
pub(crate) fn mat_f64(rows: i32, cols: i32, v: &[f64]) -> Result<Mat> {
    let mut m = Mat::new_rows_cols_with_default(rows, cols, CV_64F, 0.0.into())
        .map_err(|e| error("allocating a matrix", e))?;
    for r in 0..rows {
        for c in 0..cols {
            *m.at_2d_mut::<f64>(r, c)
                .map_err(|e| error("filling a matrix", e))? = v[(r * cols + c) as usize];
        }
    }
    Ok(m)
}

/// The values of a `CV_64F` matrix, row-major.
pub(crate) fn mat_values(m: &Mat) -> Result<Vec<f64>> {
    let mut out = Vec::with_capacity(m.total());
    for r in 0..m.rows() {
        for c in 0..m.cols() {
            out.push(
                *m.at_2d::<f64>(r, c)
                    .map_err(|e| error("reading a matrix", e))?,
            );
        }
    }
    Ok(out)
}

/// The 3x3 camera matrix of `intr`.
pub(crate) fn camera_matrix(intr: &Intrinsics) -> Result<Mat> {
    mat_f64(
        3,
        3,
        &[
            intr.fx, 0.0, intr.ppx, 0.0, intr.fy, intr.ppy, 0.0, 0.0, 1.0,
        ],
    )
}

/// `[k1, k2, p1, p2, k3]` as OpenCV's 1x5 distortion vector: the crate's `brown_conrady` is OpenCV's
/// model (librealsense's `RS2_DISTORTION_BROWN_CONRADY` uses the same formula and order).
pub(crate) fn dist_coeffs(intr: &Intrinsics) -> Result<Mat> {
    let c = match intr.model {
        DistortionModel::None => [0.0; 5],
        DistortionModel::BrownConrady => intr.coeffs,
        m => {
            return Err(Error::InvalidInput(format!(
                "OpenCV's pinhole model has no {m} distortion (points are undistorted first)"
            )))
        }
    };
    mat_f64(1, 5, &c)
}

/// A rotation vector and translation (OpenCV's `rvec`, `tvec`) as an isometry.
pub(crate) fn isometry_from_rt(rvec: &Mat, tvec: &Mat) -> Result<Isometry3<f64>> {
    let r = mat_values(rvec)?;
    let t = mat_values(tvec)?;
    if r.len() != 3 || t.len() != 3 || r.iter().chain(&t).any(|v| !v.is_finite()) {
        return Err(Error::Failed(
            "OpenCV returned a pose that is not 3 + 3 finite numbers".into(),
        ));
    }
    let rot = Rotation3::from_scaled_axis(Vector3::new(r[0], r[1], r[2]));
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}
