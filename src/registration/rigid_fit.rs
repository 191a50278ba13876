//! Closed-form least-squares rigid fit (Arun 1987 / Umeyama 1991 without scale): the rotation and
//! translation minimising Σ wᵢ ‖R pᵢ + t − qᵢ‖².

use crate::geometry::transform::nearest_rotation;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// Best rigid transform mapping `src[i]` onto `dst[i]` with weights `w[i]` (all 1 when `None`).
///
/// Returns `None` for fewer than 3 pairs, zero total weight, or collinear points (the rotation about the
/// line is then undetermined).
pub fn rigid_fit(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    w: Option<&[f64]>,
) -> Option<Isometry3<f64>> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let weight = |i: usize| w.map_or(1.0, |w| w[i]);
    let wsum: f64 = (0..n).map(weight).sum();
    if wsum.is_nan() || wsum <= 0.0 {
        return None;
    }
    let mut cs = Vector3::zeros();
    let mut cd = Vector3::zeros();
    for i in 0..n {
        cs += src[i].coords * weight(i);
        cd += dst[i].coords * weight(i);
    }
    cs /= wsum;
    cd /= wsum;
    let mut h = Matrix3::zeros();
    for i in 0..n {
        h += (src[i].coords - cs) * (dst[i].coords - cd).transpose() * weight(i);
    }
    // R = V·D·Uᵀ for H = U·S·Vᵀ: the transpose of the rotation nearest to H (None when collinear or
    // coincident: the rotation about the line is then undetermined).
    let r = nearest_rotation(&h)?.transpose();
    let rot = UnitQuaternion::from_rotation_matrix(&r);
    let t = cd - rot * cs;
    Some(Isometry3::from_parts(Translation3::from(t), rot))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::{pose_error, random_isometry};
    use crate::geometry::Rng;

    #[test]
    fn recovers_exact_transforms() {
        let mut rng = Rng::new(12);
        for _ in 0..200 {
            let t = random_isometry(&mut rng, std::f64::consts::PI, 10.0);
            let src: Vec<Point3<f64>> = (0..10)
                .map(|_| Point3::new(rng.normal(), rng.normal(), rng.normal()))
                .collect();
            let dst: Vec<Point3<f64>> = src.iter().map(|p| t * p).collect();
            let est = rigid_fit(&src, &dst, None).unwrap();
            let (r, d) = pose_error(&est, &t);
            assert!(r < 1e-6 && d < 1e-9, "{r} {d}");
            // A planar configuration (exactly 3 points) too.
            let est = rigid_fit(&src[..3], &dst[..3], None).unwrap();
            let (r, d) = pose_error(&est, &t);
            assert!(r < 1e-6 && d < 1e-9, "{r} {d}");
        }
        let line: Vec<Point3<f64>> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(rigid_fit(&line, &line, None).is_none());
    }
}
