//! What the cell's own inputs add to the uncertainty of `T_base1_base2`.
//!
//! ICP's covariance says how well the two fused clouds pin each other down; it knows nothing of how well
//! each cloud was put together. Each robot's cloud is its frames moved into its base by
//! `T_base_ee · T_ee_cam`, so an error in the hand-eye, in the robot's poses or in the depth scale moves
//! the whole cloud (or each frame's part of it), and the registration follows. This module propagates
//! those inputs' 1-σ ([`RobotUncertainty`]) to first order: each error source displaces every frame's
//! points, `d(p) = B(p) δ`; the rigid motion that best explains the displacement of all points is
//! `ξ = N⁻¹ Σ A(p)ᵀ B(p) δ` with `A(p) = [−[p]×, I]` and `N = Σ A(p)ᵀ A(p)`; its covariance follows from
//! δ's. A hand-eye and a depth scale are shared by all frames of a robot (their errors add up coherently);
//! pose errors are independent per frame (they average down).
//!
//! Conventions: twists `[ω (rad), v (m)]`, `d = ω × p + v`, a left increment in the robot's base frame.

use crate::camera::DepthView;
use crate::cell::{CellRobot, RobotUncertainty};
use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, Point3, Vector3, Vector6};

/// Most points sampled from each frame's depth view.
const POINTS_PER_FRAME: usize = 150;

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// A stride sample of a view's points in the base frame: each block with depth at its centre pixel and
/// its nearest depth.
fn view_points(view: &DepthView) -> Vec<Point3<f64>> {
    let t_base_cam = view.t_cam_base.inverse();
    let valid: Vec<usize> = (0..view.near.len())
        .filter(|&k| view.near[k] > 0.0)
        .collect();
    let step = valid.len().div_ceil(POINTS_PER_FRAME).max(1);
    valid
        .iter()
        .step_by(step)
        .map(|&k| {
            let (bu, bv) = (k as u32 % view.size[0], k as u32 / view.size[0]);
            let half = view.block as f64 / 2.0 - 0.5;
            let u = (bu * view.block) as f64 + half;
            let v = (bv * view.block) as f64 + half;
            let p = view.intrinsics.deproject([u, v], view.near[k] as f64);
            t_base_cam * Point3::new(p[0], p[1], p[2])
        })
        .collect()
}

/// Covariance (6x6, `[ω, v]` about the base origin) of the rigid motion of one robot's fused cloud that
/// its hand-eye, pose and depth-scale uncertainty cause. `views` are the robot's frames' depth views in
/// frame order ([`crate::fusion::FusedCloud::views`]). Zero when there are no views.
pub fn cloud_motion_covariance(robot: &CellRobot, views: &[DepthView]) -> Matrix6<f64> {
    let u: &RobotUncertainty = &robot.uncertainty;
    let mut n = Matrix6::<f64>::zeros();
    let mut he = Matrix6::<f64>::zeros();
    let mut scale = Vector6::<f64>::zeros();
    let mut pose_parts: Vec<Matrix6<f64>> = Vec::new();
    for (i, view) in views.iter().enumerate().take(robot.frames.len()) {
        let t_base_ee: Isometry3<f64> = robot.frames[i].t_base_ee;
        let r_ee = *t_base_ee.rotation.to_rotation_matrix().matrix();
        let flange = Point3::from(t_base_ee.translation.vector);
        let cam = Point3::from(view.t_cam_base.inverse().translation.vector);
        let mut pose = Matrix6::<f64>::zeros();
        for p in view_points(view) {
            let mut a = Matrix3x6::<f64>::zeros();
            a.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-skew(&p.coords)));
            a.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            let at = a.transpose();
            n += at * a;
            // Hand-eye: the camera turns about its centre and shifts, in flange axes.
            let mut b = Matrix3x6::<f64>::zeros();
            b.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-skew(&(p - cam)) * r_ee));
            b.fixed_view_mut::<3, 3>(0, 3).copy_from(&r_ee);
            he += at * b;
            // Pose: the flange turns about itself and shifts, in base axes.
            let mut b = Matrix3x6::<f64>::zeros();
            b.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-skew(&(p - flange))));
            b.fixed_view_mut::<3, 3>(0, 3)
                .copy_from(&Matrix3::identity());
            pose += at * b;
            // Depth scale: every point slides along its ray.
            scale += at * (p - cam);
        }
        pose_parts.push(pose);
    }
    let Some(n_inv) = n.try_inverse() else {
        return Matrix6::zeros();
    };
    let diag = |r: f64, t: f64| {
        Matrix6::from_diagonal(&Vector6::new(r * r, r * r, r * r, t * t, t * t, t * t))
    };
    let j_he = n_inv * he;
    let mut cov = j_he * diag(u.hand_eye_rotation_rad, u.hand_eye_translation_m) * j_he.transpose();
    let s_pose = diag(u.pose_rotation_rad, u.pose_translation_m);
    let mut acc = Matrix6::<f64>::zeros();
    for m in &pose_parts {
        acc += m * s_pose * m.transpose();
    }
    cov += n_inv * acc * n_inv.transpose();
    let g = n_inv * scale;
    cov += g * g.transpose() * (u.depth_scale * u.depth_scale);
    cov
}

/// The covariance of a twist `[ω, v]` whose every rotation axis has 1-σ `sr` (radians) and every translation
/// axis `st` (metres), all independent.
pub fn twist_covariance(sr: f64, st: f64) -> Matrix6<f64> {
    let (r, t) = (sr * sr, st * st);
    Matrix6::from_diagonal(&Vector6::new(r, r, r, t, t, t))
}

/// The adjoint of `t` for twists `[ω, v]`: a twist in `t`'s source frame expressed in its target frame.
pub fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r = *t.rotation.to_rotation_matrix().matrix();
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    m.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(skew(&t.translation.vector) * r));
    m
}

/// Covariance of `T_base1_base2` (left increment in base1) from both robots' cloud motions: the
/// reference robot's cloud moves `T` on the left, the other's on the right.
pub fn inputs_covariance(
    t_base1_base2: &Isometry3<f64>,
    reference: &Matrix6<f64>,
    other: &Matrix6<f64>,
) -> Matrix6<f64> {
    let ad = adjoint(t_base1_base2);
    reference + ad * other * ad.transpose()
}

/// The error of `estimate` against `truth` as a left increment `[ω, v]` (`estimate ≈ exp(ξ) · truth`).
pub fn left_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Vector6<f64> {
    let d = estimate * truth.inverse();
    let w = d.rotation.scaled_axis();
    let v = d.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// Normalised errors of an estimate against the truth under `covariance`: the rotation and translation
/// parts `sqrt(eᵀ Σ⁻¹ e / 3)` (about 1 when the covariance is honest, below 3 on nearly all cells) and
/// the whole `sqrt(eᵀ Σ⁻¹ e / 6)`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct NormalisedError {
    /// Rotation part.
    pub rotation: f64,
    /// Translation part.
    pub translation: f64,
    /// All six.
    pub pose: f64,
}

/// See [`NormalisedError`]; `None` when the covariance is not invertible.
pub fn normalised_error(
    estimate: &Isometry3<f64>,
    truth: &Isometry3<f64>,
    covariance: &Matrix6<f64>,
) -> Option<NormalisedError> {
    let e = left_error(estimate, truth);
    let part = |k: usize| -> Option<f64> {
        let c = covariance
            .fixed_view::<3, 3>(k, k)
            .into_owned()
            .try_inverse()?;
        let x = e.fixed_rows::<3>(k).into_owned();
        Some((x.dot(&(c * x)) / 3.0).max(0.0).sqrt())
    };
    let all = covariance.try_inverse()?;
    Some(NormalisedError {
        rotation: part(0)?,
        translation: part(3)?,
        pose: (e.dot(&(all * e)) / 6.0).max(0.0).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn adjoint_maps_twists_like_conjugation() {
        let t = Isometry3::from_parts(
            Translation3::new(0.4, -0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.1, -0.3, 1.2),
        );
        let xi = Vector6::new(1e-4, -2e-4, 3e-4, 1e-4, 2e-4, -1e-4);
        let exp = |x: &Vector6<f64>| {
            Isometry3::from_parts(
                Translation3::from(Vector3::new(x[3], x[4], x[5])),
                UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])),
            )
        };
        // T · exp(ξ) · T⁻¹ ≈ exp(Ad_T ξ).
        let lhs = t * exp(&xi) * t.inverse();
        let rhs = exp(&(adjoint(&t) * xi));
        let e = left_error(&lhs, &rhs);
        assert!(e.norm() < 1e-7, "{e}");
    }

    #[test]
    fn normalised_error_is_one_sigma_over_sigma() {
        let cov = Matrix6::from_diagonal(&Vector6::new(1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6));
        let truth = Isometry3::identity();
        let est = Isometry3::from_parts(
            Translation3::new(3e-3, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let n = normalised_error(&est, &truth, &cov).unwrap();
        assert!((n.translation - 3f64.sqrt()).abs() < 1e-9, "{n:?}");
        assert!(n.rotation.abs() < 1e-9);
    }
}
