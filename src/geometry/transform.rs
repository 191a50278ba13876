//! Rigid-transform helpers: 4x4 matrices, pose errors, small-motion updates, random poses.

use crate::error::{Error, Result};
use crate::geometry::rng::Rng;
use nalgebra::{
    Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// Largest deviation from orthonormality (max |RᵀR − I| entry) accepted for a rotation read from input.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-3;

/// The proper rotation nearest to `m` in the Frobenius norm (the polar factor, by SVD: `U·D·Vᵀ` with `D`
/// flipping the direction of the smallest singular value when `U·Vᵀ` is a reflection). `None` when `m` has
/// rank below 2 (the rotation is then undetermined). The one projection of the crate: Arun/Umeyama's
/// rigid fit takes it of `Hᵀ`, the hand-eye closed forms of their rotation estimates.
pub fn nearest_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    let mut sorted = [s[0], s[1], s[2]];
    sorted.sort_by(|a, b| b.total_cmp(a));
    if sorted[0] <= 0.0 || sorted[1] <= 1e-12 * sorted[0] {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        let k = s.imin();
        d[(k, k)] = -1.0;
    }
    Some(Rotation3::from_matrix_unchecked(u * d * vt))
}

/// Builds an isometry from a 4x4 row-major matrix, checking that it is rigid.
///
/// The bottom row must be `0 0 0 1` and the rotation block orthonormal with determinant +1 (within
/// [`ORTHONORMAL_TOLERANCE`]); small round-off is removed by re-orthonormalising. `what` names the matrix in the error.
pub fn isometry_from_rows(m: &[f64; 16], what: &str) -> Result<Isometry3<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(Error::InvalidInput(format!(
            "{what}: matrix has a NaN or infinite entry"
        )));
    }
    let bottom = [m[12], m[13], m[14], m[15]];
    if (bottom[0].abs() + bottom[1].abs() + bottom[2].abs()) > 1e-6
        || (bottom[3] - 1.0).abs() > 1e-6
    {
        return Err(Error::InvalidInput(format!(
            "{what}: the bottom row must be 0 0 0 1, found {bottom:?}"
        )));
    }
    let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let dev = (r.transpose() * r - Matrix3::identity()).abs().max();
    if dev > ORTHONORMAL_TOLERANCE || r.determinant() < 0.0 {
        return Err(Error::InvalidInput(format!(
            "{what}: the rotation block is not a proper rotation (|RᵀR − I| = {dev:.2e}, det = {:.4}); \
             give a rigid transform (rotation in radians-consistent form, no scale or shear)",
            r.determinant()
        )));
    }
    // The nearest rotation (SVD) removes the round-off; the quaternion then comes from the closed form.
    // nalgebra's iterative `UnitQuaternion::from_matrix` starts at the identity and stops there on a half
    // turn (a symmetric matrix gives it no direction to move in): a 180° pose read as no rotation at all.
    let nearest = nearest_rotation(&r)
        .ok_or_else(|| Error::InvalidInput(format!("{what}: the rotation block is singular")))?;
    let rot = UnitQuaternion::from_rotation_matrix(&nearest);
    Ok(Isometry3::from_parts(
        Translation3::new(m[3], m[7], m[11]),
        rot,
    ))
}

/// The 4x4 row-major matrix of an isometry.
pub fn isometry_to_rows(t: &Isometry3<f64>) -> [f64; 16] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + c] = m[(r, c)];
        }
    }
    out
}

/// The 4x4 matrix as nested rows, for JSON output.
pub fn isometry_to_nested(t: &Isometry3<f64>) -> [[f64; 4]; 4] {
    let m: Matrix4<f64> = t.to_homogeneous();
    let mut out = [[0.0; 4]; 4];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    out
}

/// Rotation angle of `a⁻¹·b` in degrees.
pub fn rotation_error_deg(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    a.rotation.angle_to(&b.rotation).to_degrees()
}

/// `(rotation error in degrees, translation error in the transforms' unit)` of an estimate against a truth.
///
/// The translation error is the distance between the two translation vectors, as 3DMatch and the peers report it.
pub fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    (
        rotation_error_deg(estimate, truth),
        (estimate.translation.vector - truth.translation.vector).norm(),
    )
}

/// Applies a small motion `xi = [ωx, ωy, ωz, vx, vy, vz]` on the left: `exp(xi) · t`, with the rotation part
/// as an axis-angle (radians) and the translation added in the output frame.
pub fn apply_left_increment(t: &Isometry3<f64>, xi: &Vector6<f64>) -> Isometry3<f64> {
    let w = Vector3::new(xi[0], xi[1], xi[2]);
    let v = Vector3::new(xi[3], xi[4], xi[5]);
    let dr = UnitQuaternion::from_scaled_axis(w);
    let rotation = dr * t.rotation;
    let translation = dr * t.translation.vector + v;
    let mut out = Isometry3::from_parts(Translation3::from(translation), rotation);
    out.rotation.renormalize();
    out
}

/// A random rotation of angle uniform in `[0, max_angle_rad]` about a uniformly random axis, and a random
/// translation with each component uniform in `[-max_translation, max_translation]`.
pub fn random_isometry(rng: &mut Rng, max_angle_rad: f64, max_translation: f64) -> Isometry3<f64> {
    let axis = loop {
        let v = Vector3::new(
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
            rng.uniform(-1.0, 1.0),
        );
        let n = v.norm();
        if n > 1e-3 && n <= 1.0 {
            break v / n;
        }
    };
    let angle = rng.uniform(0.0, max_angle_rad);
    let rot = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle);
    let t = Vector3::new(
        rng.uniform(-max_translation, max_translation),
        rng.uniform(-max_translation, max_translation),
        rng.uniform(-max_translation, max_translation),
    );
    Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pose row of issue 36 (a half turn, as `convert --to matrix` wrote it from a UR pose of angle π)
    /// was read as the identity.
    #[test]
    fn a_half_turn_row_is_read_as_a_half_turn() {
        let m = [
            0.421964153,
            -0.192161107,
            0.886013748,
            0.457742764,
            -0.192161107,
            -0.974031771,
            -0.119733949,
            0.200569575,
            0.886013748,
            -0.119733949,
            -0.447932382,
            0.422907741,
            0.0,
            0.0,
            0.0,
            1.0,
        ];
        let t = isometry_from_rows(&m, "row").unwrap();
        assert!((t.rotation.angle().to_degrees() - 180.0).abs() < 1e-4);
        let back = isometry_to_rows(&t);
        for (a, b) in m.iter().zip(back.iter()) {
            assert!((a - b).abs() < 1e-8, "{m:?} read back as {back:?}");
        }
    }

    /// Every rotation reads back as itself, half turns about any axis and angles within 1e-9 rad of one
    /// included: against a brute-force oracle, the matrix itself.
    #[test]
    fn rows_of_every_rotation_read_back_as_that_rotation() {
        let mut rng = Rng::new(36);
        let pi = std::f64::consts::PI;
        for i in 0..2000 {
            let axis = nalgebra::Unit::new_normalize(Vector3::new(
                rng.normal(),
                rng.normal(),
                rng.normal(),
            ));
            let angle = match i % 5 {
                0 => pi,
                1 => pi - 1e-9,
                2 => pi - rng.uniform(0.0, 1e-4),
                3 => rng.uniform(0.0, 1e-9),
                _ => rng.uniform(0.0, pi),
            };
            let t = Isometry3::from_parts(
                Translation3::new(rng.normal(), rng.normal(), rng.normal()),
                UnitQuaternion::from_axis_angle(&axis, angle),
            );
            let m = isometry_to_rows(&t);
            let back = isometry_to_rows(&isometry_from_rows(&m, "t").unwrap());
            for (a, b) in m.iter().zip(back.iter()) {
                assert!(
                    (a - b).abs() < 1e-12,
                    "angle {angle}, axis {axis:?}: {a} != {b}"
                );
            }
        }
        for d in [[-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, -1.0]] {
            let mut m = [0.0; 16];
            (m[0], m[5], m[10], m[15]) = (d[0], d[1], d[2], 1.0);
            let t = isometry_from_rows(&m, "diag").unwrap();
            assert_eq!(isometry_to_rows(&t).map(|v| v.round()), m);
        }
    }

    #[test]
    fn rows_round_trip_and_checks() {
        let mut rng = Rng::new(7);
        for _ in 0..200 {
            let t = random_isometry(&mut rng, std::f64::consts::PI, 5.0);
            let back = isometry_from_rows(&isometry_to_rows(&t), "t").unwrap();
            let (r, d) = pose_error(&t, &back);
            assert!(r < 1e-6 && d < 1e-12, "{r} {d}");
        }
        let mut m = isometry_to_rows(&Isometry3::identity());
        m[0] = 2.0;
        assert!(isometry_from_rows(&m, "scaled").is_err());
        let mut m = isometry_to_rows(&Isometry3::identity());
        m[12] = 1.0;
        assert!(isometry_from_rows(&m, "bottom").is_err());
        let mut m = isometry_to_rows(&Isometry3::identity());
        m[0] = -1.0; // reflection
        assert!(isometry_from_rows(&m, "reflection").is_err());
    }

    #[test]
    fn increment_composes_like_a_left_multiplication() {
        let mut rng = Rng::new(3);
        for _ in 0..100 {
            let t = random_isometry(&mut rng, 3.0, 2.0);
            let xi = Vector6::new(0.01, -0.02, 0.005, 0.1, 0.2, -0.3);
            let a = apply_left_increment(&t, &xi);
            let dr = UnitQuaternion::from_scaled_axis(Vector3::new(xi[0], xi[1], xi[2]));
            let b = Isometry3::from_parts(Translation3::new(xi[3], xi[4], xi[5]), dr) * t;
            let (r, d) = pose_error(&a, &b);
            assert!(r < 1e-9 && d < 1e-12);
        }
    }

    #[test]
    fn random_isometry_respects_bounds() {
        let mut rng = Rng::new(11);
        for _ in 0..500 {
            let t = random_isometry(&mut rng, 1.0, 0.5);
            assert!(t.rotation.angle() <= 1.0 + 1e-12);
            assert!(t.translation.vector.amax() <= 0.5);
        }
    }
}
