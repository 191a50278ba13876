//! The homography between two views of a plane from point matches: a robust fit (OpenCV's
//! `findHomography`, RANSAC by default), then least-squares refits on the inliers until the inlier set
//! stops growing.
//!
//! The robust estimators of OpenCV seed their own random generators on every call (RANSAC, LMedS and RHO
//! with fixed seeds, USAC with `randomGeneratorState` 0), so a call gives the same result every time and at
//! any thread count.

use super::super::cv;
use crate::error::{Error, Result};
use nalgebra::{Matrix3, Point2, Vector3};
use opencv::core::{Mat, Point2d, Vector};
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

/// The robust estimator of the first fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HomographyMethod {
    /// RANSAC (OpenCV `RANSAC`).
    #[default]
    Ransac,
    /// MAGSAC++ (OpenCV `USAC_MAGSAC`): marginalises over the threshold.
    Magsac,
    /// PROSAC-based RHO (OpenCV `RHO`).
    Rho,
    /// Least median of squares (OpenCV `LMEDS`): no threshold, needs more than half inliers.
    Lmeds,
}

impl HomographyMethod {
    fn opencv(self) -> i32 {
        match self {
            HomographyMethod::Ransac => opencv::calib3d::RANSAC,
            HomographyMethod::Magsac => opencv::calib3d::USAC_MAGSAC,
            HomographyMethod::Rho => opencv::calib3d::RHO,
            HomographyMethod::Lmeds => opencv::calib3d::LMEDS,
        }
    }
}

/// Homography fitting settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HomographyConfig {
    /// The robust estimator (default RANSAC).
    pub method: HomographyMethod,
    /// A match is an inlier when its transfer error ([`transfer_error`]) is at most this, pixels
    /// (default 3).
    pub threshold_px: f64,
    /// Most robust-estimator iterations (default 2000).
    pub max_iterations: u32,
    /// Confidence at which the robust estimator may stop early, in (0, 1) (default 0.995).
    pub confidence: f64,
    /// Least-squares refits on the inliers after the robust fit (each refit re-selects the inliers and is
    /// kept when they do not decrease; stops when they no longer change). Default 5; 0 = none.
    pub refits: u32,
    /// Fewer inliers than this is no homography (four points always fit one exactly). Default 10.
    pub min_inliers: usize,
}

impl Default for HomographyConfig {
    fn default() -> Self {
        HomographyConfig {
            method: HomographyMethod::Ransac,
            threshold_px: 3.0,
            max_iterations: 2000,
            confidence: 0.995,
            refits: 5,
            min_inliers: 10,
        }
    }
}

impl HomographyConfig {
    /// Checks the ranges of the settings; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("homography.{field}"),
                msg,
            })
        };
        if !(self.threshold_px.is_finite() && self.threshold_px > 0.0) {
            return bad(
                "threshold_px",
                format!("must be > 0, found {}", self.threshold_px),
            );
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return bad(
                "confidence",
                format!("must be in (0, 1), found {}", self.confidence),
            );
        }
        if self.max_iterations == 0 || self.max_iterations > i32::MAX as u32 {
            return bad(
                "max_iterations",
                format!("must be in 1..={}, found {}", i32::MAX, self.max_iterations),
            );
        }
        if self.min_inliers < 4 {
            return bad(
                "min_inliers",
                format!("must be at least 4, found {}", self.min_inliers),
            );
        }
        Ok(())
    }
}

/// A fitted homography.
#[derive(Clone, Debug, PartialEq)]
pub struct Homography {
    /// Maps first-image pixels to second-image pixels: `p2 ~ h · (p1.x, p1.y, 1)`; scaled so `h[(2, 2)]`
    /// is 1 (unless it is 0, then to unit Frobenius norm).
    pub h: Matrix3<f64>,
    /// Per input pair: its transfer error under `h` is within the threshold.
    pub inliers: Vec<bool>,
}

impl Homography {
    /// Number of inliers.
    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|&&b| b).count()
    }

    /// `p` (first image, pixels) mapped into the second image; `None` when it maps to infinity.
    pub fn map(&self, p: &Point2<f64>) -> Option<Point2<f64>> {
        map_point(&self.h, p)
    }
}

/// `p` mapped by the homography `h`; `None` when it maps to (or near) infinity or is not finite.
pub fn map_point(h: &Matrix3<f64>, p: &Point2<f64>) -> Option<Point2<f64>> {
    let q = h * Vector3::new(p.x, p.y, 1.0);
    let scale = h.abs().max() * (1.0 + p.x.abs() + p.y.abs());
    if q.z.is_nan() || q.z.abs() <= 1e-12 * scale {
        return None;
    }
    let r = Point2::new(q.x / q.z, q.y / q.z);
    (r.x.is_finite() && r.y.is_finite()).then_some(r)
}

/// The transfer error of a match: the distance between `h · p1` and `p2`, pixels (infinite when `p1` maps
/// to infinity).
pub fn transfer_error(h: &Matrix3<f64>, p1: &Point2<f64>, p2: &Point2<f64>) -> f64 {
    map_point(h, p1).map_or(f64::INFINITY, |q| (q - p2).norm())
}

/// Fits the homography mapping `p1[i]` to `p2[i]` (pixels): a robust fit with `cfg.method`, then
/// least-squares refits (DLT and Levenberg-Marquardt on the transfer error) on the inliers.
///
/// `Ok(None)` when no homography fits: fewer than 4 pairs, a degenerate configuration (e.g. collinear
/// points), or fewer than `cfg.min_inliers` inliers. Errors when the slices differ in length, a point is
/// not finite, or the settings are out of range.
pub fn fit_homography(
    p1: &[Point2<f64>],
    p2: &[Point2<f64>],
    cfg: &HomographyConfig,
) -> Result<Option<Homography>> {
    cfg.validate()?;
    if p1.len() != p2.len() {
        return Err(Error::InvalidInput(format!(
            "{} points in the first image for {} in the second",
            p1.len(),
            p2.len()
        )));
    }
    if p1
        .iter()
        .chain(p2)
        .any(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(Error::InvalidInput(
            "homography fit: a point is not finite".into(),
        ));
    }
    if p1.len() < 4 {
        return Ok(None);
    }
    let Some(h) = opencv_fit(p1, p2, cfg.method.opencv(), cfg)? else {
        return Ok(None);
    };
    let mut best = inliers_of(h, p1, p2, cfg.threshold_px);
    for _ in 0..cfg.refits {
        let (n, sel) = (best.inlier_count(), best.inliers.clone());
        if n < 4 {
            break;
        }
        let (q1, q2): (Vec<_>, Vec<_>) = p1
            .iter()
            .zip(p2)
            .zip(&sel)
            .filter(|(_, &keep)| keep)
            .map(|((a, b), _)| (*a, *b))
            .unzip();
        let Some(h) = opencv_fit(&q1, &q2, 0, cfg)? else {
            break;
        };
        let next = inliers_of(h, p1, p2, cfg.threshold_px);
        if next.inlier_count() < n {
            break;
        }
        let same = next.inliers == sel;
        best = next;
        if same {
            break;
        }
    }
    Ok((best.inlier_count() >= cfg.min_inliers).then_some(best))
}

/// The homography with its inliers at `threshold_px`.
fn inliers_of(
    h: Matrix3<f64>,
    p1: &[Point2<f64>],
    p2: &[Point2<f64>],
    threshold_px: f64,
) -> Homography {
    let inliers = p1
        .iter()
        .zip(p2)
        .map(|(a, b)| transfer_error(&h, a, b) <= threshold_px)
        .collect();
    Homography { h, inliers }
}

/// One `findHomography` call (`method` 0 = least squares on all points); `None` when OpenCV finds none
/// or returns a degenerate matrix.
fn opencv_fit(
    p1: &[Point2<f64>],
    p2: &[Point2<f64>],
    method: i32,
    cfg: &HomographyConfig,
) -> Result<Option<Matrix3<f64>>> {
    let to_cv = |p: &[Point2<f64>]| -> Vector<Point2d> {
        p.iter().map(|q| Point2d::new(q.x, q.y)).collect()
    };
    let (src, dst) = (to_cv(p1), to_cv(p2));
    let mut mask = Mat::default();
    let m = opencv::calib3d::find_homography_ext(
        &src,
        &dst,
        method,
        cfg.threshold_px,
        &mut mask,
        cfg.max_iterations as i32,
        cfg.confidence,
    )
    .map_err(|e| cv::error("findHomography", e))?;
    if m.empty() || m.rows() != 3 || m.cols() != 3 {
        return Ok(None);
    }
    let v = cv::mat_values(&m)?;
    Ok(normalised(Matrix3::from_row_slice(&v)))
}

/// `h` scaled so `h[(2, 2)] = 1` (or to unit norm when that is 0); `None` when not finite or singular.
fn normalised(h: Matrix3<f64>) -> Option<Matrix3<f64>> {
    if h.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let n = h.norm();
    if n == 0.0 {
        return None;
    }
    let h = h / n;
    if h.determinant().abs() < 1e-12 {
        return None;
    }
    let s = h[(2, 2)];
    Some(if s.abs() > 1e-12 { h / s } else { h })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    fn truth() -> Matrix3<f64> {
        Matrix3::new(0.9, -0.2, 40.0, 0.15, 1.05, -20.0, 2e-4, -1e-4, 1.0)
    }

    /// `n` pairs under `h` with pixel noise `sigma`, and `outliers` random pairs after them.
    fn pairs(
        rng: &mut Rng,
        h: &Matrix3<f64>,
        n: usize,
        sigma: f64,
        outliers: usize,
    ) -> (Vec<Point2<f64>>, Vec<Point2<f64>>) {
        let mut p1 = Vec::new();
        let mut p2 = Vec::new();
        for i in 0..n + outliers {
            let a = Point2::new(rng.uniform(0.0, 640.0), rng.uniform(0.0, 480.0));
            let b = if i < n {
                let q = map_point(h, &a).unwrap();
                Point2::new(q.x + sigma * rng.normal(), q.y + sigma * rng.normal())
            } else {
                Point2::new(rng.uniform(0.0, 640.0), rng.uniform(0.0, 480.0))
            };
            p1.push(a);
            p2.push(b);
        }
        (p1, p2)
    }

    fn worst_error(h: &Matrix3<f64>, truth: &Matrix3<f64>) -> f64 {
        let mut worst: f64 = 0.0;
        for y in (0..=480).step_by(40) {
            for x in (0..=640).step_by(40) {
                let p = Point2::new(x as f64, y as f64);
                let want = map_point(truth, &p).unwrap();
                worst = worst.max(transfer_error(h, &p, &want));
            }
        }
        worst
    }

    #[test]
    fn exact_and_noisy_pairs_with_outliers_give_the_truth() {
        let mut rng = Rng::new(1);
        let h0 = truth();
        let (p1, p2) = pairs(&mut rng, &h0, 60, 0.0, 0);
        let h = fit_homography(&p1, &p2, &HomographyConfig::default())
            .unwrap()
            .unwrap();
        assert!(worst_error(&h.h, &h0) < 1e-3, "{}", worst_error(&h.h, &h0));
        assert_eq!(h.h[(2, 2)], 1.0);
        for method in [
            HomographyMethod::Ransac,
            HomographyMethod::Magsac,
            HomographyMethod::Rho,
            HomographyMethod::Lmeds,
        ] {
            // LMedS needs a majority of inliers: 200 good, 120 outliers.
            let (p1, p2) = pairs(&mut rng, &h0, 200, 0.5, 120);
            let cfg = HomographyConfig {
                method,
                ..Default::default()
            };
            let h = fit_homography(&p1, &p2, &cfg).unwrap().unwrap();
            let e = worst_error(&h.h, &h0);
            assert!(e < 1.0, "{method:?}: worst error {e} px");
            let good = h.inliers[..200].iter().filter(|&&b| b).count();
            let bad = h.inliers[200..].iter().filter(|&&b| b).count();
            assert!(
                good >= 195 && bad <= 3,
                "{method:?}: {good} good, {bad} bad inliers"
            );
            // Seeded: the same result every time and at any thread count.
            let again = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap()
                .install(|| fit_homography(&p1, &p2, &cfg).unwrap().unwrap());
            assert_eq!(again, h, "{method:?}");
        }
    }

    #[test]
    fn too_few_or_degenerate_pairs_give_none() {
        let mut rng = Rng::new(2);
        let h0 = truth();
        let cfg = HomographyConfig::default();
        let (p1, p2) = pairs(&mut rng, &h0, 3, 0.0, 0);
        assert!(fit_homography(&p1, &p2, &cfg).unwrap().is_none());
        // Nine exact pairs: fewer than min_inliers (10).
        let (p1, p2) = pairs(&mut rng, &h0, 9, 0.0, 0);
        assert!(fit_homography(&p1, &p2, &cfg).unwrap().is_none());
        // Pure noise: no homography gathers 10 inliers within 3 px.
        let (p1, p2) = pairs(&mut rng, &h0, 0, 0.0, 40);
        assert!(fit_homography(&p1, &p2, &cfg).unwrap().is_none());
        // All on one line.
        let p1: Vec<_> = (0..30)
            .map(|i| Point2::new(i as f64 * 10.0, i as f64 * 5.0))
            .collect();
        let p2: Vec<_> = p1.iter().map(|p| map_point(&h0, p).unwrap()).collect();
        assert!(fit_homography(&p1, &p2, &cfg).unwrap().is_none());
        assert!(fit_homography(&p1, &p2[1..], &cfg).is_err());
        let mut nan = p1.clone();
        nan[3].x = f64::NAN;
        assert!(fit_homography(&nan, &p2, &cfg).is_err());
        let bad = HomographyConfig {
            threshold_px: 0.0,
            ..cfg
        };
        assert!(fit_homography(&p1, &p2, &bad).is_err());
    }

    #[test]
    fn transfer_error_and_map() {
        let h = Matrix3::new(2.0, 0.0, 1.0, 0.0, 2.0, -1.0, 0.0, 0.0, 1.0);
        let e = transfer_error(&h, &Point2::new(1.0, 1.0), &Point2::new(3.0, 4.0));
        assert!((e - 3.0).abs() < 1e-12);
        // A point on the line at infinity.
        let p = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, -1.0);
        assert_eq!(map_point(&p, &Point2::new(1.0, 5.0)), None);
        assert!(transfer_error(&p, &Point2::new(1.0, 5.0), &Point2::new(0.0, 0.0)).is_infinite());
    }
}
