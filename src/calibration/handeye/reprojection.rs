//! Hand-eye refined in the image: `X` and `Z` that minimise the reprojection error of the board's
//! corners through the whole chain (the maximum-likelihood solution for pixel noise, as ROS-Industrial's
//! `industrial_calibration` and Ceres-based tools solve it), from a start such as
//! [`super::calibrate_hand_eye`]'s pose-residual solution.
//!
//! Each view `i` predicts the board pose in the camera from the robot pose `Aᵢ = T_base_ee_i`:
//!
//! * eye-in-hand (`X = T_ee_cam`, `Z = T_base_board`): `T_cam_board_i = X⁻¹ · Aᵢ⁻¹ · Z`;
//! * eye-to-hand (`X = T_ee_board`, `Z = T_base_cam`): `T_cam_board_i = Z⁻¹ · Aᵢ · X`;
//!
//! and every corner seen is projected with the camera's own model ([`Intrinsics::project`], any
//! distortion) and compared with where it was found. Levenberg-Marquardt (Gauss-Newton normal equations
//! with a numerical Jacobian, central differences) over left increments of `X` and `Z`, plain least
//! squares over all views.

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::transform::apply_left_increment;
use nalgebra::{DVector, Isometry3, Point2, Point3, SMatrix, SVector, Vector6};

/// One view of the board for [`refine_by_reprojection`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReprojectionView {
    /// Frame id.
    pub id: String,
    /// The flange pose in the robot base, `T_base_ee`, metres.
    pub t_base_ee: Isometry3<f64>,
    /// Where the board's corners were found, pixels (`(0, 0)` = centre of the top-left pixel).
    pub image_points: Vec<Point2<f64>>,
    /// The same corners in the board frame, metres.
    pub object_points: Vec<Point3<f64>>,
}

/// The result of [`refine_by_reprojection`].
#[derive(Clone, Debug, PartialEq)]
pub struct ReprojectionFit {
    /// `X`: `T_ee_cam` (eye-in-hand) or `T_ee_board` (eye-to-hand), metres.
    pub x: Isometry3<f64>,
    /// `Z`: `T_base_board` (eye-in-hand) or `T_base_cam` (eye-to-hand), metres.
    pub z: Isometry3<f64>,
    /// RMS distance between the corners found and reprojected, over all corners, pixels.
    pub rms_px: f64,
    /// The same at the start, pixels.
    pub initial_rms_px: f64,
    /// `√(cost / residuals)` with `cost = ½ Σ r²` over the `u` and `v` residuals: the figure Ceres-based
    /// tools report as `sqrt(final_cost_per_obs)` (it equals `rms_px / 2`), pixels.
    pub sqrt_cost_per_residual_px: f64,
    /// RMS per view, pixels, in input order.
    pub view_rms_px: Vec<f64>,
    /// Iterations run.
    pub iterations: usize,
    /// True when the cost stopped falling before the iteration limit.
    pub converged: bool,
}

/// The board pose in the camera that view `t_base_ee` predicts from `x` and `z` (see the module
/// documentation).
pub fn predicted_t_cam_board(
    t_base_ee: &Isometry3<f64>,
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    eye_to_hand: bool,
) -> Isometry3<f64> {
    if eye_to_hand {
        z.inverse() * t_base_ee * x
    } else {
        x.inverse() * t_base_ee.inverse() * z
    }
}

/// Reprojection residuals `[u − u_found, v − v_found]` of every corner of every view; a corner behind the
/// camera gets a large residual so that the solver moves away from it.
fn residuals(
    views: &[ReprojectionView],
    intr: &Intrinsics,
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    eye_to_hand: bool,
) -> DVector<f64> {
    let n: usize = views.iter().map(|v| v.image_points.len()).sum();
    let mut r = Vec::with_capacity(2 * n);
    for v in views {
        let t = predicted_t_cam_board(&v.t_base_ee, x, z, eye_to_hand);
        for (q, p) in v.image_points.iter().zip(&v.object_points) {
            let c = t * p;
            if c.z <= 1e-9 {
                r.extend([1e6, 1e6]);
                continue;
            }
            let [u, w] = intr.project([c.x, c.y, c.z]);
            r.push(u - q.x);
            r.push(w - q.y);
        }
    }
    DVector::from_vec(r)
}

/// Applies the 12-vector of left increments `[δX, δZ]`.
fn step(
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    d: &SVector<f64, 12>,
) -> (Isometry3<f64>, Isometry3<f64>) {
    let dx = Vector6::from_iterator(d.iter().take(6).copied());
    let dz = Vector6::from_iterator(d.iter().skip(6).copied());
    (apply_left_increment(x, &dx), apply_left_increment(z, &dz))
}

/// Refines `X` and `Z` from `(x0, z0)` by minimising the corners' reprojection error over all views (see
/// the module documentation). Errors when a view's image and board points differ in number, when there
/// are fewer than 3 views or 12 corners, or the intrinsics are invalid.
pub fn refine_by_reprojection(
    views: &[ReprojectionView],
    intr: &Intrinsics,
    x0: &Isometry3<f64>,
    z0: &Isometry3<f64>,
    eye_to_hand: bool,
    max_iterations: usize,
) -> Result<ReprojectionFit> {
    intr.validate()
        .map_err(|m| Error::InvalidInput(format!("intrinsics: {m}")))?;
    if let Some(v) = views
        .iter()
        .find(|v| v.image_points.len() != v.object_points.len())
    {
        return Err(Error::InvalidInput(format!(
            "view {}: {} image points for {} board points",
            v.id,
            v.image_points.len(),
            v.object_points.len()
        )));
    }
    let corners: usize = views.iter().map(|v| v.image_points.len()).sum();
    if views.len() < 3 || corners < 12 {
        return Err(Error::InvalidInput(format!(
            "reprojection refinement needs at least 3 views and 12 corners, found {} views with {corners} corners",
            views.len()
        )));
    }
    let (mut x, mut z) = (*x0, *z0);
    let mut r = residuals(views, intr, &x, &z, eye_to_hand);
    let initial = r.norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    // Increments for the numerical Jacobian: radians and metres.
    let h = 1e-7;
    while iterations < max_iterations {
        iterations += 1;
        let mut jtj = SMatrix::<f64, 12, 12>::zeros();
        let mut jtr = SVector::<f64, 12>::zeros();
        let mut cols: Vec<DVector<f64>> = Vec::with_capacity(12);
        for k in 0..12 {
            let mut d = SVector::<f64, 12>::zeros();
            d[k] = h;
            let (xp, zp) = step(&x, &z, &d);
            d[k] = -h;
            let (xm, zm) = step(&x, &z, &d);
            let col = (residuals(views, intr, &xp, &zp, eye_to_hand)
                - residuals(views, intr, &xm, &zm, eye_to_hand))
                / (2.0 * h);
            cols.push(col);
        }
        for a in 0..12 {
            jtr[a] = cols[a].dot(&r);
            for b in a..12 {
                let v = cols[a].dot(&cols[b]);
                jtj[(a, b)] = v;
                jtj[(b, a)] = v;
            }
        }
        let cost = r.norm_squared();
        let mut improved = false;
        while lambda < 1e12 {
            let mut a = jtj;
            for k in 0..12 {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(d) = a.lu().solve(&(-jtr)) else {
                lambda *= 10.0;
                continue;
            };
            let (x2, z2) = step(&x, &z, &d);
            let r2 = residuals(views, intr, &x2, &z2, eye_to_hand);
            let c2 = r2.norm_squared();
            if c2.is_finite() && c2 < cost {
                (x, z, r) = (x2, z2, r2);
                lambda = (lambda * 0.3).max(1e-12);
                improved = true;
                if cost - c2 < 1e-12 * cost.max(1e-300) || d.norm() < 1e-12 {
                    converged = true;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved || converged {
            converged = true;
            break;
        }
    }
    let rms = |sq: f64| (sq / corners as f64).sqrt();
    let mut view_rms_px = Vec::with_capacity(views.len());
    let mut k = 0;
    for v in views {
        let n = v.image_points.len();
        let sq: f64 = r.rows(k, 2 * n).norm_squared();
        view_rms_px.push(if n > 0 { (sq / n as f64).sqrt() } else { 0.0 });
        k += 2 * n;
    }
    let sq = r.norm_squared();
    Ok(ReprojectionFit {
        x,
        z,
        rms_px: rms(sq),
        initial_rms_px: rms(initial),
        sqrt_cost_per_residual_px: (0.5 * sq / (2 * corners) as f64).sqrt(),
        view_rms_px,
        iterations,
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::{pose_error, random_isometry};
    use crate::geometry::Rng;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// Views of a 6x4 grid of 3 cm from a camera 0.5–0.7 m away, the robot pose following from the truth.
    fn views(
        eye_to_hand: bool,
        noise_px: f64,
    ) -> (Vec<ReprojectionView>, Intrinsics, [Isometry3<f64>; 2]) {
        let intr = Intrinsics::pinhole(640, 480, 600.0, 600.0, 320.0, 240.0);
        let mut rng = Rng::new(5);
        let x = random_isometry(&mut rng, 1.0, 0.1);
        let z = random_isometry(&mut rng, 2.0, 1.0);
        let grid: Vec<Point3<f64>> = (0..24)
            .map(|k| {
                Point3::new(
                    (k % 6) as f64 * 0.03 - 0.075,
                    (k / 6) as f64 * 0.03 - 0.045,
                    0.0,
                )
            })
            .collect();
        let mut out = Vec::new();
        for i in 0..8 {
            // The board 0.5–0.7 m in front of the camera, tilted up to ~25°.
            let t_cam_board = Isometry3::from_parts(
                Translation3::new(
                    rng.uniform(-0.05, 0.05),
                    rng.uniform(-0.05, 0.05),
                    rng.uniform(0.5, 0.7),
                ),
                UnitQuaternion::from_scaled_axis(Vector3::new(
                    rng.uniform(-0.45, 0.45),
                    rng.uniform(-0.45, 0.45),
                    rng.uniform(-0.5, 0.5),
                )),
            );
            // Solve the chain for the robot pose.
            let a = if eye_to_hand {
                z * t_cam_board * x.inverse()
            } else {
                z * t_cam_board.inverse() * x.inverse()
            };
            let image_points = grid
                .iter()
                .map(|p| {
                    let c = t_cam_board * p;
                    let [u, v] = intr.project([c.x, c.y, c.z]);
                    Point2::new(u + noise_px * rng.normal(), v + noise_px * rng.normal())
                })
                .collect();
            out.push(ReprojectionView {
                id: i.to_string(),
                t_base_ee: a,
                image_points,
                object_points: grid.clone(),
            });
        }
        (out, intr, [x, z])
    }

    #[test]
    fn recovers_the_chain_from_a_perturbed_start() {
        for eye_to_hand in [false, true] {
            let (v, intr, [x, z]) = views(eye_to_hand, 0.0);
            let mut rng = Rng::new(9);
            let x0 = random_isometry(&mut rng, 0.02, 0.005) * x;
            let z0 = random_isometry(&mut rng, 0.02, 0.005) * z;
            let fit = refine_by_reprojection(&v, &intr, &x0, &z0, eye_to_hand, 50).unwrap();
            let (ex, tx) = pose_error(&fit.x, &x);
            let (ez, tz) = pose_error(&fit.z, &z);
            assert!(fit.initial_rms_px > 1.0, "{}", fit.initial_rms_px);
            assert!(
                fit.rms_px < 1e-5,
                "eye_to_hand {eye_to_hand}: {}",
                fit.rms_px
            );
            assert!(
                ex < 1e-6 && tx < 1e-8 && ez < 1e-6 && tz < 1e-8,
                "{ex} {tx} {ez} {tz}"
            );
            assert!(fit.converged);
            assert!((fit.sqrt_cost_per_residual_px - fit.rms_px / 2.0).abs() < 1e-12);
        }
        // With 0.3 px of noise, the RMS is about the noise (√2 · 0.3 per corner) and the chain close.
        let (v, intr, [x, z]) = views(false, 0.3);
        let fit = refine_by_reprojection(&v, &intr, &x, &z, false, 50).unwrap();
        assert!(fit.rms_px > 0.3 && fit.rms_px < 0.5, "{}", fit.rms_px);
        let (ex, tx) = pose_error(&fit.x, &x);
        assert!(ex < 0.1 && tx < 1e-3, "{ex}° {tx} m");
    }

    #[test]
    fn bad_input_is_refused() {
        let (mut v, intr, [x, z]) = views(false, 0.0);
        assert!(refine_by_reprojection(&v[..2], &intr, &x, &z, false, 10).is_err());
        v[1].object_points.pop();
        let e = refine_by_reprojection(&v, &intr, &x, &z, false, 10)
            .unwrap_err()
            .to_string();
        assert!(e.contains("view 1") && e.contains("24 image points"), "{e}");
    }
}
