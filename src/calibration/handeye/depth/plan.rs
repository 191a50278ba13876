//! Which flange poses to add when the hand-eye is weakly constrained: rotations of the camera about the
//! point it looks at, about an axis perpendicular to each weak translation direction (a translation along
//! `d` is seen only through flange rotations about axes not parallel to `d`), from the existing pose
//! nearest the centre of the others, kept within the span of the existing flange positions.

use super::observe::{FlangeMotion, WeakDirection};
use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
use serde::Serialize;

/// A flange pose to capture.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SuggestedPose {
    /// Why, in words.
    pub reason: String,
    /// The frame id of the existing pose it starts from.
    pub from_frame: String,
    /// The camera's rotation about the point it looks at, degrees, about `axis_ee`.
    pub rotation_deg: f64,
    /// The rotation axis, a unit vector in the flange frame.
    pub axis_ee: [f64; 3],
    /// What it turns about: `look_point` (the point the camera looks at, so the view stays on the scene)
    /// or `flange` (the flange origin, when turning about the look point leaves the span of the existing
    /// flange positions).
    pub pivot: &'static str,
    /// The flange pose `T_base_ee`, KUKA `[X, Y, Z (mm), A, B, C (degrees)]`.
    pub kuka_xyzabc: [f64; 6],
}

/// A unit vector perpendicular to `d` and, when possible, to `avoid` (an axis already used).
fn perpendicular(d: &Vector3<f64>, avoid: &Vector3<f64>) -> Vector3<f64> {
    let c = d.cross(avoid);
    if c.norm() > 0.3 * d.norm() * avoid.norm().max(1e-12) {
        return c.normalize();
    }
    let k = d.iamin();
    let mut e = Vector3::zeros();
    e[k] = 1.0;
    d.cross(&e).normalize()
}

/// Proposes up to two poses per weak direction (`±` the rotation). `t_base_ee` are the existing poses
/// (frame ids in `ids`), `x` the hand-eye, `range` the distance to the point the camera looks at, metres.
pub fn suggest_poses(
    weak: &[WeakDirection],
    motion: &FlangeMotion,
    t_base_ee: &[Isometry3<f64>],
    ids: &[String],
    x: &Isometry3<f64>,
    range: f64,
) -> Vec<SuggestedPose> {
    if t_base_ee.is_empty() || weak.is_empty() {
        return Vec::new();
    }
    let n = t_base_ee.len() as f64;
    let centre: Vector3<f64> = t_base_ee
        .iter()
        .map(|p| p.translation.vector)
        .sum::<Vector3<f64>>()
        / n;
    let (c, start) = t_base_ee
        .iter()
        .enumerate()
        .min_by(|a, b| {
            let da = (a.1.translation.vector - centre).norm();
            let db = (b.1.translation.vector - centre).norm();
            da.total_cmp(&db)
        })
        .unwrap();
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in t_base_ee {
        lo = lo.inf(&p.translation.vector);
        hi = hi.sup(&p.translation.vector);
    }
    let margin = Vector3::repeat(0.05);
    let (lo, hi) = (lo - margin, hi + margin);
    let used = Vector3::from(motion.main_axis_cam);
    let look = Vector3::new(0.0, 0.0, range);
    let mut out = Vec::new();
    for w in weak.iter().take(3) {
        let t = Vector3::new(w.vector[3], w.vector[4], w.vector[5]);
        let r = Vector3::new(w.vector[0], w.vector[1], w.vector[2]);
        // A weak translation needs rotations about an axis across it; a weak rotation, rotations about
        // other axes than the one used.
        let d = if t.norm() >= r.norm() { t } else { r };
        let axis_cam = perpendicular(&d, &used);
        let axis_ee = x.rotation * axis_cam;
        for sign in [1.0, -1.0] {
            // About the point the camera looks at while the flange stays within the span of the existing
            // positions; else the flange turned in place by 15°.
            for (deg, pivot) in [
                (25.0f64, "look_point"),
                (15.0, "look_point"),
                (15.0, "flange"),
            ] {
                let rot = UnitQuaternion::from_axis_angle(
                    &Unit::new_normalize(axis_cam),
                    sign * deg.to_radians(),
                );
                let new = if pivot == "flange" {
                    let rot_ee = UnitQuaternion::from_axis_angle(
                        &Unit::new_normalize(axis_ee),
                        sign * deg.to_radians(),
                    );
                    start * Isometry3::from_parts(Translation3::identity(), rot_ee)
                } else {
                    let about = Translation3::from(look)
                        * Isometry3::from_parts(Translation3::identity(), rot)
                        * Translation3::from(-look);
                    start * x * about * x.inverse()
                };
                let p = new.translation.vector;
                if (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]) {
                    let k = crate::geometry::pose::KukaPose::from_isometry(&new);
                    out.push(SuggestedPose {
                        reason: format!("{} is {}", w.description, w.status),
                        from_frame: ids.get(c).cloned().unwrap_or_default(),
                        rotation_deg: sign * deg,
                        axis_ee: [axis_ee.x, axis_ee.y, axis_ee.z],
                        pivot,
                        kuka_xyzabc: [k.x_mm, k.y_mm, k.z_mm, k.a_deg, k.b_deg, k.c_deg],
                    });
                    break;
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_weak_translation_along_z_gets_rotations_across_it() {
        let x = Isometry3::identity();
        let poses: Vec<Isometry3<f64>> = (0..5)
            .map(|k| Isometry3::new(Vector3::new(0.1 * k as f64, 0.0, 0.5), Vector3::zeros()))
            .collect();
        let ids: Vec<String> = (0..5).map(|k| k.to_string()).collect();
        let motion = FlangeMotion {
            max_rotation_deg: 30.0,
            axis_spread_deg: 0.0,
            main_axis_ee: [0.0, 0.0, 1.0],
            main_axis_cam: [0.0, 0.0, 1.0],
        };
        let weak = vec![WeakDirection {
            description: "translation along the camera's z axis".into(),
            vector: [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
            sigma_mm: 9.0,
            status: "unobservable",
        }];
        let s = suggest_poses(&weak, &motion, &poses, &ids, &x, 0.5);
        assert_eq!(s.len(), 2, "{s:?}");
        for p in &s {
            assert!(p.axis_ee[2].abs() < 1e-9, "{p:?}");
            assert_eq!(p.from_frame, "2");
        }
    }
}
