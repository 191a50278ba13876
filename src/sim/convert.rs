//! Conversions between the crate's nalgebra transforms and parry's glam types. glam stays inside `sim`:
//! everything public in the simulator takes and returns `nalgebra::Isometry3<f64>`.

use nalgebra::{Isometry3, Vector3};
use parry3d_f64::math::{Pose, Rotation, Vector};

/// `Isometry3<f64>` → parry's `Pose` (glam `DPose3`), through the unit quaternion and the translation.
pub(crate) fn to_pose(t: &Isometry3<f64>) -> Pose {
    let q = t.rotation.quaternion();
    let v = t.translation.vector;
    Pose::from_parts(
        Vector::new(v.x, v.y, v.z),
        Rotation::from_xyzw(q.i, q.j, q.k, q.w),
    )
}

/// parry's `Pose` → `Isometry3<f64>`.
#[cfg(test)]
pub(crate) fn from_pose(p: &Pose) -> Isometry3<f64> {
    use nalgebra::{Quaternion, Translation3, UnitQuaternion};
    let q = p.rotation;
    Isometry3::from_parts(
        Translation3::new(p.translation.x, p.translation.y, p.translation.z),
        UnitQuaternion::new_normalize(Quaternion::new(q.w, q.x, q.y, q.z)),
    )
}

/// nalgebra vector → glam vector.
#[inline]
pub(crate) fn to_vec(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

/// glam vector → nalgebra vector.
#[cfg(test)]
pub(crate) fn from_vec(v: Vector) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::random_isometry;
    use crate::geometry::Rng;

    #[test]
    fn round_trip_and_same_action() {
        let mut rng = Rng::new(3);
        for _ in 0..20 {
            let t = random_isometry(&mut rng, 3.0, 2.0);
            let p = to_pose(&t);
            let back = from_pose(&p);
            assert!((back.to_homogeneous() - t.to_homogeneous()).abs().max() < 1e-12);
            let x = Vector3::new(0.3, -1.2, 0.7);
            let a = t * nalgebra::Point3::from(x);
            let b = p.transform_point(to_vec(&x));
            assert!((a.coords - from_vec(b)).norm() < 1e-12);
        }
    }
}
