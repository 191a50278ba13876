//! The pose vocabulary every report uses: one shape for a rigid transform, its 1-σ and its error.

use crate::geometry::pose::{isometry_to_xyzquat, KukaPose};
use crate::geometry::transform::isometry_to_nested;
use nalgebra::{Isometry3, Matrix6};
use serde::ser::{SerializeMap, Serializer};
use serde::Serialize;

/// A rigid transform in every form a user pastes somewhere. Lengths in metres (for `register`: the clouds'
/// unit, metres for depthcal's own clouds).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PoseReport {
    /// The 4x4 homogeneous matrix, row-major.
    pub matrix: [[f64; 4]; 4],
    /// Translation `[x, y, z]`, metres.
    pub xyz_m: [f64; 3],
    /// Rotation as a unit quaternion `[x, y, z, w]` with `w ≥ 0`.
    pub quaternion_xyzw: [f64; 4],
    /// KUKA `[X, Y, Z (mm), A, B, C (degrees)]`, `R = Rz(A)·Ry(B)·Rx(C)`.
    pub kuka_xyzabc: [f64; 6],
}

impl PoseReport {
    /// Every form of `t`.
    pub fn new(t: &Isometry3<f64>) -> Self {
        let q = isometry_to_xyzquat(t);
        let k = KukaPose::from_isometry(t);
        PoseReport {
            matrix: isometry_to_nested(t),
            xyz_m: [q[0], q[1], q[2]],
            quaternion_xyzw: [q[3], q[4], q[5], q[6]],
            kuka_xyzabc: [k.x_mm, k.y_mm, k.z_mm, k.a_deg, k.b_deg, k.c_deg],
        }
    }
}

/// Per-axis 1-σ of a pose: the square roots of a 6x6 covariance's diagonal.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SigmaReport {
    /// About x, y, z, degrees.
    pub rotation_deg: [f64; 3],
    /// Along x, y, z, metres.
    pub translation_m: [f64; 3],
}

impl SigmaReport {
    /// The 1-σ of a covariance of `[rx, ry, rz (rad), tx, ty, tz (m)]`.
    pub fn from_covariance(c: &Matrix6<f64>) -> Self {
        let s = |k: usize| c[(k, k)].max(0.0).sqrt();
        SigmaReport {
            rotation_deg: [s(0).to_degrees(), s(1).to_degrees(), s(2).to_degrees()],
            translation_m: [s(3), s(4), s(5)],
        }
    }
}

/// The difference between two poses (an estimate and the truth, or two estimates).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ErrorReport {
    /// Rotation angle, degrees.
    pub rotation_deg: f64,
    /// Translation distance, metres.
    pub translation_m: f64,
}

impl ErrorReport {
    /// From `(degrees, metres)` as [`crate::geometry::transform::pose_error`] gives them.
    pub fn new(e: (f64, f64)) -> Self {
        ErrorReport {
            rotation_deg: e.0,
            translation_m: e.1,
        }
    }

    /// [`ErrorReport::new`] of an optional pair.
    pub fn from_opt(e: Option<(f64, f64)>) -> Option<Self> {
        e.map(Self::new)
    }
}

/// A 6x6 matrix as 6 rows of 6 numbers.
pub fn matrix6_rows(m: &Matrix6<f64>) -> [[f64; 6]; 6] {
    let mut r = [[0.0; 6]; 6];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = m[(i, j)];
        }
    }
    r
}

/// Stage timings, milliseconds, serialised as an object in stage order (rounded to 1 µs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Timings(pub Vec<(String, f64)>);

impl Serialize for Timings {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, &((v * 1000.0).round() / 1000.0))?;
        }
        m.end()
    }
}

/// A far-away runner-up that scored almost as well as the answer.
#[derive(Clone, Debug, Serialize)]
pub struct AmbiguityReport {
    /// The runner-up transform.
    pub runner_up: PoseReport,
    /// Its score over the best's, 0–1.
    pub score_ratio: f64,
    /// Rotation between the best and the runner-up, degrees.
    pub rotation_deg: f64,
    /// Translation between them, metres.
    pub translation_m: f64,
}

impl AmbiguityReport {
    /// From the registration's ambiguity.
    pub fn new(a: &crate::registration::pipeline::Ambiguity) -> Self {
        AmbiguityReport {
            runner_up: PoseReport::new(&a.runner_up),
            score_ratio: a.score_ratio,
            rotation_deg: a.rotation_deg,
            translation_m: a.translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn every_form_describes_the_same_pose() {
        let t = Isometry3::from_parts(
            Translation3::new(0.5, -1.25, 0.125),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 2.9),
        );
        let p = PoseReport::new(&t);
        assert_eq!(p.matrix[0][3], 0.5);
        assert_eq!(p.xyz_m, [0.5, -1.25, 0.125]);
        let [x, y, z, w] = p.quaternion_xyzw;
        assert!(w >= 0.0);
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
        assert!(q.angle_to(&t.rotation) < 1e-12);
        let k = KukaPose {
            x_mm: p.kuka_xyzabc[0],
            y_mm: p.kuka_xyzabc[1],
            z_mm: p.kuka_xyzabc[2],
            a_deg: p.kuka_xyzabc[3],
            b_deg: p.kuka_xyzabc[4],
            c_deg: p.kuka_xyzabc[5],
        };
        let back = k.to_isometry();
        assert!(back.rotation.angle_to(&t.rotation) < 1e-12);
        assert!((back.translation.vector - t.translation.vector).norm() < 1e-12);
    }

    #[test]
    fn timings_keep_their_order() {
        let t = Timings(vec![("z".into(), 1.23456), ("a".into(), 2.0)]);
        assert_eq!(serde_json::to_string(&t).unwrap(), r#"{"z":1.235,"a":2.0}"#);
    }

    #[test]
    fn sigma_is_the_root_of_the_diagonal() {
        let c = Matrix6::from_diagonal(&nalgebra::Vector6::new(1e-6, 4e-6, 9e-6, 1e-6, 4e-6, 9e-6));
        let s = SigmaReport::from_covariance(&c);
        assert!((s.rotation_deg[2] - 3e-3f64.to_degrees()).abs() < 1e-12);
        assert_eq!(s.translation_m, [1e-3, 2e-3, 3e-3]);
    }
}
