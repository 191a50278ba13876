//! What the flange poses let the depth frames see of a hand-eye: the motion's excitation, and the weak
//! directions of the normal equations in words.

use super::super::log_rotation;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3, Vector6};
use serde::Serialize;

/// How the flange moved between the frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FlangeMotion {
    /// Largest rotation of the flange between two frames, degrees.
    pub max_rotation_deg: f64,
    /// Spread of the relative rotation axes (flange frame), degrees: `2·atan(√(λ₂/λ₁))` of the scatter of
    /// the rotation vectors (0 when every rotation is about one axis).
    pub axis_spread_deg: f64,
    /// The main rotation axis, a unit vector in the flange frame (the scatter's principal direction).
    pub main_axis_ee: [f64; 3],
    /// The main rotation axis in the camera frame (through the initial hand-eye's rotation).
    pub main_axis_cam: [f64; 3],
}

/// The flange motion of `t_base_ee` (all pairs).
pub fn flange_motion(t_base_ee: &[Isometry3<f64>], t_ee_cam: &Isometry3<f64>) -> FlangeMotion {
    let mut scatter = Matrix3::zeros();
    let mut max_rot: f64 = 0.0;
    for (i, a) in t_base_ee.iter().enumerate() {
        for b in &t_base_ee[i + 1..] {
            let w = log_rotation(&(a.inverse() * b).rotation);
            max_rot = max_rot.max(w.norm());
            scatter += w * w.transpose();
        }
    }
    let eig = scatter.symmetric_eigen();
    let mut order: Vec<usize> = (0..3).collect();
    order.sort_by(|&p, &q| eig.eigenvalues[q].total_cmp(&eig.eigenvalues[p]));
    let (l1, l2) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]]);
    let spread = if l1 > 0.0 {
        2.0 * (l2.max(0.0) / l1).sqrt().atan()
    } else {
        0.0
    };
    let axis: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    let axis_cam = t_ee_cam.rotation.inverse() * axis;
    FlangeMotion {
        max_rotation_deg: max_rot.to_degrees(),
        axis_spread_deg: spread.to_degrees(),
        main_axis_ee: [axis.x, axis.y, axis.z],
        main_axis_cam: [axis_cam.x, axis_cam.y, axis_cam.z],
    }
}

/// How well one of the six hand-eye parameters is determined.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DofObservability {
    /// `rx`, `ry`, `rz` (rotation about the camera's axes) or `tx`, `ty`, `tz` (translation along them).
    pub dof: &'static str,
    /// Its 1-σ: degrees for rotations, millimetres for translations (the hand-eye's units).
    pub sigma: f64,
    /// `observable`, `weak` (1-σ above the configured limit) or `unobservable` (the poses leave it free).
    pub status: &'static str,
}

/// A direction of the hand-eye correction the frames constrain poorly.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WeakDirection {
    /// The direction in words, e.g. "translation along the camera's z axis".
    pub description: String,
    /// Its rotation part (rotation vector, camera frame, unit-free) and translation part: `[rx, ry, rz,
    /// tx, ty, tz]`, scaled so that a rotation counts as its displacement at the characteristic range.
    pub vector: [f64; 6],
    /// 1-σ along it, millimetres (rotations as their displacement at the characteristic range).
    pub sigma_mm: f64,
    /// `weak` or `unobservable`.
    pub status: &'static str,
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// A unit 3-vector in words: "the camera's z axis", or "(0.71, 0.00, 0.71) in the camera frame".
pub fn axis_words(v: &Vector3<f64>) -> String {
    let k = v.iamax();
    if v[k].abs() >= 0.95 * v.norm() {
        format!("the camera's {} axis", AXES[k])
    } else {
        let u = v / v.norm().max(1e-300);
        let u = if u[k] < 0.0 { -u } else { u };
        format!(
            "({:.2}, {:.2}, {:.2}) in the camera frame (mostly its {} axis)",
            u.x, u.y, u.z, AXES[k]
        )
    }
}

/// A scaled direction `[rotation · L, translation]` in words.
pub fn direction_words(d: &Vector6<f64>) -> String {
    let rot = Vector3::new(d[0], d[1], d[2]);
    let tr = Vector3::new(d[3], d[4], d[5]);
    let (r, t) = (rot.norm(), tr.norm());
    if t >= 0.9 * (r * r + t * t).sqrt() {
        format!("translation along {}", axis_words(&tr))
    } else if r >= 0.9 * (r * r + t * t).sqrt() {
        format!("rotation about {}", axis_words(&rot))
    } else {
        format!(
            "a rotation about {} coupled with a translation along {}",
            axis_words(&rot),
            axis_words(&tr)
        )
    }
}

/// The eigen-decomposition of the covariance in scaled units (`L` metres per radian): each direction with
/// its 1-σ (metres), largest first.
pub fn directions(cov: &Matrix6<f64>, l: f64) -> Vec<(Vector6<f64>, f64)> {
    let s = Matrix6::from_diagonal(&Vector6::new(l, l, l, 1.0, 1.0, 1.0));
    let scaled = s * cov * s;
    let eig = scaled.symmetric_eigen();
    let mut out: Vec<(Vector6<f64>, f64)> = (0..6)
        .map(|k| {
            let mut v: Vector6<f64> = eig.eigenvectors.column(k).into_owned();
            let m = v.iamax();
            if v[m] < 0.0 {
                v = -v;
            }
            (v, eig.eigenvalues[k].max(0.0).sqrt())
        })
        .collect();
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_rotation_axis_has_no_spread() {
        let x = Isometry3::identity();
        let about_z: Vec<Isometry3<f64>> = (0..6)
            .map(|k| {
                Isometry3::new(
                    Vector3::new(0.1 * k as f64, 0.0, 0.0),
                    Vector3::new(0.0, 0.0, 0.2 * k as f64),
                )
            })
            .collect();
        let m = flange_motion(&about_z, &x);
        assert!(m.axis_spread_deg < 1e-6, "{m:?}");
        assert!((m.main_axis_ee[2].abs() - 1.0).abs() < 1e-9);
        assert!((m.max_rotation_deg - 57.2957795 * 1.0).abs() < 1e-3);
        let words = direction_words(&Vector6::new(0.0, 0.0, 0.0, 0.0, 0.1, 0.99));
        assert_eq!(words, "translation along the camera's z axis");
        let words = direction_words(&Vector6::new(0.7, 0.0, 0.0, 0.0, 0.7, 0.0));
        assert!(words.contains("coupled"), "{words}");
    }
}
