//! Robot poses: KUKA XYZ-ABC, 4x4 matrices, x,y,z + quaternion, UR pose vectors, ABB x,y,z + q1..q4 and
//! Fanuc XYZ-WPR (the pose files of a cell are [`crate::io::poses`]).
//!
//! Units are converted exactly once, here: every [`Isometry3`] is in metres and radians; KUKA values are
//! millimetres and degrees (`x_mm`, `a_deg`, ...).
//!
//! KUKA convention: `R = Rz(A) · Ry(B) · Rx(C)` (intrinsic Z-Y'-X''), `t = (x, y, z)`. The conversion
//! back from a rotation returns `A, C ∈ (-180°, 180°]`, `B ∈ [-90°, 90°]`; at gimbal lock (`B = ±90°`)
//! only `A ∓ C` is defined and depthcal returns `C = 0`.
//!
//! UR convention: `x, y, z` in metres and the rotation vector `(rx, ry, rz)` in radians (axis times angle,
//! angle in `[0, π]`). ABB convention: `x, y, z` in millimetres and the unit quaternion `q1..q4 = w, x, y, z`
//! (`q1 ≥ 0`). Fanuc convention: `x, y, z` in millimetres and `W, P, R` in degrees, fixed axes X-Y-Z:
//! `R = Rz(R)·Ry(P)·Rx(W)` (the same matrix as KUKA's `Rz(A)·Ry(B)·Rx(C)` with `W = C, P = B, R = A`).

use nalgebra::{Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A KUKA pose: position in millimetres and A, B, C Euler angles in degrees (`R = Rz(A)·Ry(B)·Rx(C)`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KukaPose {
    /// X, millimetres.
    pub x_mm: f64,
    /// Y, millimetres.
    pub y_mm: f64,
    /// Z, millimetres.
    pub z_mm: f64,
    /// A: rotation about Z, degrees (applied first in the intrinsic sequence).
    pub a_deg: f64,
    /// B: rotation about the new Y, degrees.
    pub b_deg: f64,
    /// C: rotation about the newest X, degrees.
    pub c_deg: f64,
}

/// The rotation `Rz(a)·Ry(b)·Rx(c)` for angles in radians.
pub fn rotation_from_zyx(a: f64, b: f64, c: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), a)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), b)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), c)
}

/// The angles `(a, b, c)` in radians with `R = Rz(a)·Ry(b)·Rx(c)`; at gimbal lock `c = 0`.
pub fn zyx_from_rotation(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let cb = (r[(0, 0)] * r[(0, 0)] + r[(1, 0)] * r[(1, 0)]).sqrt();
    let b = (-r[(2, 0)]).atan2(cb);
    if cb < 1e-9 {
        // B = ±90°: R depends only on A − C (B = +90°) or A + C (B = −90°); choose C = 0.
        let a = (-r[(0, 1)]).atan2(r[(1, 1)]);
        (a, b, 0.0)
    } else {
        let a = r[(1, 0)].atan2(r[(0, 0)]);
        let c = r[(2, 1)].atan2(r[(2, 2)]);
        (a, b, c)
    }
}

impl KukaPose {
    /// The pose as an isometry in metres.
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let r = rotation_from_zyx(
            self.a_deg.to_radians(),
            self.b_deg.to_radians(),
            self.c_deg.to_radians(),
        );
        Isometry3::from_parts(
            Translation3::new(self.x_mm * 1e-3, self.y_mm * 1e-3, self.z_mm * 1e-3),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    /// The KUKA values of an isometry in metres (angles in `(-180, 180]`, B in `[-90, 90]`, C = 0 at
    /// gimbal lock).
    pub fn from_isometry(t: &Isometry3<f64>) -> Self {
        let m = t.rotation.to_rotation_matrix();
        let (a, b, c) = zyx_from_rotation(m.matrix());
        let v = t.translation.vector * 1e3;
        KukaPose {
            x_mm: v.x,
            y_mm: v.y,
            z_mm: v.z,
            a_deg: a.to_degrees(),
            b_deg: b.to_degrees(),
            c_deg: c.to_degrees(),
        }
    }
}

/// `[x, y, z, qx, qy, qz, qw]` (metres, unit quaternion with `qw ≥ 0`) of an isometry.
pub fn isometry_to_xyzquat(t: &Isometry3<f64>) -> [f64; 7] {
    let mut q = *t.rotation.quaternion();
    if q.w < 0.0 {
        q = -q;
    }
    let v = t.translation.vector;
    [v.x, v.y, v.z, q.i, q.j, q.k, q.w]
}

/// `[x, y, z, rx, ry, rz]` of an isometry: the Universal Robots pose vector (metres, rotation vector in
/// radians, angle in `[0, π]`).
///
/// Near a half turn the axis and its opposite give the same rotation; the axis is then chosen with its
/// first non-zero component positive, so that the written vector reads back to itself.
pub fn isometry_to_ur(t: &Isometry3<f64>) -> [f64; 6] {
    let q = t.rotation.quaternion();
    let (mut w, mut axis) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        axis = -axis;
    }
    let n = axis.norm();
    let r = if n == 0.0 {
        Vector3::zeros()
    } else {
        if w < 1e-9 {
            let first = axis
                .iter()
                .copied()
                .find(|c| c.abs() > 1e-12)
                .unwrap_or(1.0);
            if first < 0.0 {
                axis = -axis;
            }
        }
        axis * (2.0 * n.atan2(w) / n)
    };
    let v = t.translation.vector;
    [v.x, v.y, v.z, r.x, r.y, r.z]
}

/// The isometry of a Universal Robots pose vector `[x, y, z, rx, ry, rz]` (metres, radians).
pub fn ur_to_isometry(v: &[f64; 6]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[3], v[4], v[5])),
    )
}

/// `[x_mm, y_mm, z_mm, q1, q2, q3, q4]` of an isometry: an ABB frame (millimetres, unit quaternion
/// `q1..q4 = w, x, y, z` with `q1 ≥ 0`).
pub fn isometry_to_abb(t: &Isometry3<f64>) -> [f64; 7] {
    let q = isometry_to_xyzquat(t);
    [q[0] * 1e3, q[1] * 1e3, q[2] * 1e3, q[6], q[3], q[4], q[5]]
}

/// The isometry of an ABB frame `[x_mm, y_mm, z_mm, q1, q2, q3, q4]` (`q1..q4 = w, x, y, z`, unit norm
/// within [`QUATERNION_NORM_TOLERANCE`]; normalised).
pub fn abb_to_isometry(v: &[f64; 7]) -> std::result::Result<Isometry3<f64>, String> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err("a value is NaN or infinite".into());
    }
    let q = Quaternion::new(v[3], v[4], v[5], v[6]);
    let n = q.norm();
    if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "the quaternion (q1,q2,q3,q4) = ({}, {}, {}, {}) has norm {n:.6}, not 1",
            v[3], v[4], v[5], v[6]
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3),
        UnitQuaternion::new_normalize(q),
    ))
}

/// `[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]` of an isometry: Fanuc XYZ-WPR with `R = Rz(r)·Ry(p)·Rx(w)`
/// (`w, r ∈ (-180, 180]`, `p ∈ [-90, 90]`, `w = 0` at gimbal lock).
pub fn isometry_to_fanuc(t: &Isometry3<f64>) -> [f64; 6] {
    let k = KukaPose::from_isometry(t);
    [k.x_mm, k.y_mm, k.z_mm, k.c_deg, k.b_deg, k.a_deg]
}

/// The isometry of Fanuc XYZ-WPR `[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]`.
pub fn fanuc_to_isometry(v: &[f64; 6]) -> Isometry3<f64> {
    KukaPose {
        x_mm: v[0],
        y_mm: v[1],
        z_mm: v[2],
        a_deg: v[5],
        b_deg: v[4],
        c_deg: v[3],
    }
    .to_isometry()
}

/// Roll, pitch, yaw (radians) of a rotation as URDF defines them: fixed axes X-Y-Z,
/// `R = Rz(yaw)·Ry(pitch)·Rx(roll)` (`roll = 0` at gimbal lock).
pub fn rpy_from_rotation(r: &Matrix3<f64>) -> [f64; 3] {
    let (yaw, pitch, roll) = zyx_from_rotation(r);
    [roll, pitch, yaw]
}

/// Largest accepted deviation of a quaternion's norm from 1 (it is then normalised).
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// The isometry of `[x, y, z, qx, qy, qz, qw]` (metres). The quaternion must have unit norm within
/// [`QUATERNION_NORM_TOLERANCE`]; it is normalised.
pub fn xyzquat_to_isometry(v: &[f64; 7]) -> std::result::Result<Isometry3<f64>, String> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err("a value is NaN or infinite".into());
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    let n = q.norm();
    if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "the quaternion (qx,qy,qz,qw) = ({}, {}, {}, {}) has norm {n:.6}, not 1",
            v[3], v[4], v[5], v[6]
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::new_normalize(q),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::pose_error;
    use crate::geometry::Rng;

    #[test]
    fn kuka_matches_the_definition() {
        // A = 90° about Z maps x to y.
        let t = KukaPose {
            x_mm: 100.0,
            y_mm: -20.0,
            z_mm: 5.0,
            a_deg: 90.0,
            b_deg: 0.0,
            c_deg: 0.0,
        }
        .to_isometry();
        let p = t * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!(
            (p - nalgebra::Point3::new(0.1, 0.98, 0.005)).norm() < 1e-12,
            "{p}"
        );
        // Intrinsic order: Rz(A) then Ry(B) then Rx(C), i.e. R = Rz·Ry·Rx.
        let (a, b, c) = (30f64, -40f64, 75f64);
        let t = KukaPose {
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
            a_deg: a,
            b_deg: b,
            c_deg: c,
        }
        .to_isometry();
        let expect = Rotation3::from_euler_angles(c.to_radians(), b.to_radians(), a.to_radians());
        assert!(
            (t.rotation.to_rotation_matrix().matrix() - expect.matrix())
                .abs()
                .max()
                < 1e-12
        );
    }

    #[test]
    fn kuka_round_trips_including_gimbal_lock() {
        let mut rng = Rng::new(5);
        for i in 0..2000 {
            let b = match i % 4 {
                0 => 90.0,
                1 => -90.0,
                _ => rng.uniform(-90.0, 90.0),
            };
            let k = KukaPose {
                x_mm: rng.uniform(-2000.0, 2000.0),
                y_mm: rng.uniform(-2000.0, 2000.0),
                z_mm: rng.uniform(-2000.0, 2000.0),
                a_deg: rng.uniform(-180.0, 180.0),
                b_deg: b,
                c_deg: rng.uniform(-180.0, 180.0),
            };
            let t = k.to_isometry();
            let back = KukaPose::from_isometry(&t);
            let t2 = back.to_isometry();
            let (r, d) = pose_error(&t, &t2);
            assert!(r < 1e-6 && d < 1e-12, "{k:?} -> {back:?}: {r} deg {d} m");
            assert!((back.b_deg - k.b_deg).abs() < 1e-5, "{k:?} -> {back:?}");
            if b.abs() < 89.0 {
                // Away from the lock the angles themselves come back.
                assert!((back.a_deg - k.a_deg).abs() < 1e-8 && (back.c_deg - k.c_deg).abs() < 1e-8);
            } else if b.abs() == 90.0 {
                assert_eq!(back.c_deg, 0.0);
            }
        }
    }
}
