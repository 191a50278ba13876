//! Rotation and pose averaging, and the board pose in the robot base.
//!
//! Rotations are averaged properly, never by averaging matrices entry by entry: first the chordal L2 mean
//! (the rotation minimising `Σ wᵢ ‖R − Rᵢ‖²_F`, which is the principal eigenvector of `Σ wᵢ qᵢ qᵢᵀ` over
//! the unit quaternions, Markley et al. 2007), then optionally a few Weiszfeld steps towards the geodesic L1
//! median (Hartley et al. 2011), which a few bad rotations pull much less.
//!
//! [`board_in_base`] turns a hand-eye result into the board pose in the base for every frame,
//! `T_base_board = T_base_ee · T_ee_cam · T_cam_board`, and averages them with their spread.

use crate::error::{Error, Result};
use nalgebra::{Isometry3, Matrix4, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// How rotations and poses are averaged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AverageConfig {
    /// Weiszfeld steps towards the geodesic L1 median after the chordal L2 mean (0 = the L2 mean only).
    /// With steps, the translation is the geometric median (Weiszfeld) instead of the mean. Default 0.
    pub l1_iterations: usize,
    /// Stop the Weiszfeld steps when a step is below this angle, radians (and this many metres for the
    /// translation). Default 1e-12.
    pub tolerance: f64,
}

impl Default for AverageConfig {
    fn default() -> Self {
        AverageConfig {
            l1_iterations: 0,
            tolerance: 1e-12,
        }
    }
}

impl AverageConfig {
    /// Checks the ranges; the error names the field (`average.…`).
    pub fn validate(&self) -> crate::Result<()> {
        crate::error::check::positive("average.tolerance", self.tolerance)
    }
}

/// Angle of the rotation taking `a` to `b`, radians in `[0, π]`; accurate for tiny angles too (it uses
/// `atan2`, not `acos`).
pub fn rotation_angle_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> f64 {
    let d = a.inverse() * b;
    2.0 * d.imag().norm().atan2(d.w.abs())
}

/// The chordal L2 mean of unit quaternions with optional non-negative weights (all 1 when `None`).
///
/// The sign of each quaternion does not matter. Errors on an empty input, a weight count that differs from
/// the rotation count, negative/NaN weights or a zero total weight.
pub fn chordal_mean(
    rotations: &[UnitQuaternion<f64>],
    weights: Option<&[f64]>,
) -> Result<UnitQuaternion<f64>> {
    check_weights(rotations.len(), weights)?;
    let mut m = Matrix4::<f64>::zeros();
    for (i, q) in rotations.iter().enumerate() {
        let w = weights.map_or(1.0, |w| w[i]);
        let v = q.quaternion().coords;
        m += v * v.transpose() * w;
    }
    let eig = m.symmetric_eigen();
    let k = eig.eigenvalues.imax();
    let v = eig.eigenvectors.column(k).into_owned();
    Ok(UnitQuaternion::new_normalize(Quaternion::from(v)))
}

fn check_weights(n: usize, weights: Option<&[f64]>) -> Result<()> {
    if n == 0 {
        return Err(Error::InvalidInput(
            "cannot average an empty set of rotations or poses".into(),
        ));
    }
    if let Some(w) = weights {
        if w.len() != n {
            return Err(Error::InvalidInput(format!(
                "{} weights given for {n} rotations",
                w.len()
            )));
        }
        if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
            return Err(Error::InvalidInput(
                "averaging weights must be finite and non-negative".into(),
            ));
        }
        if w.iter().sum::<f64>() <= 0.0 {
            return Err(Error::InvalidInput("averaging weights sum to zero".into()));
        }
    }
    Ok(())
}

/// The rotation average: the chordal L2 mean, then `config.l1_iterations` Weiszfeld steps on SO(3) towards
/// the geodesic L1 median.
pub fn average_rotations(
    rotations: &[UnitQuaternion<f64>],
    weights: Option<&[f64]>,
    config: &AverageConfig,
) -> Result<UnitQuaternion<f64>> {
    let mut r = chordal_mean(rotations, weights)?;
    for _ in 0..config.l1_iterations {
        let mut num = Vector3::zeros();
        let mut den = 0.0;
        for (i, q) in rotations.iter().enumerate() {
            let w = weights.map_or(1.0, |w| w[i]);
            let v = (r.inverse() * q).scaled_axis();
            let d = v.norm();
            if d < 1e-15 || w == 0.0 {
                continue;
            }
            num += v * (w / d);
            den += w / d;
        }
        if den <= 0.0 {
            break;
        }
        let step = num / den;
        r *= UnitQuaternion::from_scaled_axis(step);
        if step.norm() < config.tolerance {
            break;
        }
    }
    Ok(r)
}

/// The average of a set of poses and how far the poses are from it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseAverage {
    /// The average pose (rotation average; translation mean, or geometric median with L1 steps), metres.
    pub mean: Isometry3<f64>,
    /// Rotation angle of each pose from the mean, degrees.
    pub rotation_deg: Vec<f64>,
    /// Distance of each pose's translation from the mean's, millimetres.
    pub translation_mm: Vec<f64>,
    /// RMS of `rotation_deg`, degrees.
    pub rotation_rms_deg: f64,
    /// Largest of `rotation_deg`, degrees.
    pub rotation_max_deg: f64,
    /// RMS of `translation_mm`, millimetres.
    pub translation_rms_mm: f64,
    /// Largest of `translation_mm`, millimetres.
    pub translation_max_mm: f64,
}

use crate::stats::rms;

/// Averages poses (rotation by [`average_rotations`], translation by the weighted mean or, with L1 steps,
/// the weighted geometric median) and reports the spread of the poses about the average.
pub fn average_poses(
    poses: &[Isometry3<f64>],
    weights: Option<&[f64]>,
    config: &AverageConfig,
) -> Result<PoseAverage> {
    check_weights(poses.len(), weights)?;
    if poses
        .iter()
        .any(|p| !p.translation.vector.iter().all(|x| x.is_finite()))
    {
        return Err(Error::InvalidInput(
            "a pose to average has a NaN or infinite translation".into(),
        ));
    }
    let rots: Vec<UnitQuaternion<f64>> = poses.iter().map(|p| p.rotation).collect();
    let rotation = average_rotations(&rots, weights, config)?;
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let wsum: f64 = (0..poses.len()).map(w).sum();
    let mut t = Vector3::zeros();
    for (i, p) in poses.iter().enumerate() {
        t += p.translation.vector * w(i);
    }
    t /= wsum;
    for _ in 0..config.l1_iterations {
        let mut num = Vector3::zeros();
        let mut den = 0.0;
        for (i, p) in poses.iter().enumerate() {
            let d = (p.translation.vector - t).norm();
            if d < 1e-15 || w(i) == 0.0 {
                continue;
            }
            num += p.translation.vector * (w(i) / d);
            den += w(i) / d;
        }
        if den <= 0.0 {
            break;
        }
        let next = num / den;
        let step = (next - t).norm();
        t = next;
        if step < config.tolerance {
            break;
        }
    }
    let mean = Isometry3::from_parts(Translation3::from(t), rotation);
    let rotation_deg: Vec<f64> = rots
        .iter()
        .map(|q| rotation_angle_between(&rotation, q).to_degrees())
        .collect();
    let translation_mm: Vec<f64> = poses
        .iter()
        .map(|p| (p.translation.vector - t).norm() * 1e3)
        .collect();
    Ok(PoseAverage {
        mean,
        rotation_rms_deg: rms(&rotation_deg),
        rotation_max_deg: rotation_deg.iter().cloned().fold(0.0, f64::max),
        translation_rms_mm: rms(&translation_mm),
        translation_max_mm: translation_mm.iter().cloned().fold(0.0, f64::max),
        rotation_deg,
        translation_mm,
    })
}

/// `T_base_board = T_base_ee · T_ee_cam · T_cam_board` for every frame (metres).
///
/// Errors when the two pose lists differ in length.
pub fn board_poses_in_base(
    t_base_ee: &[Isometry3<f64>],
    t_ee_cam: &Isometry3<f64>,
    t_cam_board: &[Isometry3<f64>],
) -> Result<Vec<Isometry3<f64>>> {
    if t_base_ee.len() != t_cam_board.len() {
        return Err(Error::InvalidInput(format!(
            "{} robot poses but {} board poses",
            t_base_ee.len(),
            t_cam_board.len()
        )));
    }
    Ok(t_base_ee
        .iter()
        .zip(t_cam_board)
        .map(|(a, b)| a * t_ee_cam * b)
        .collect())
}

/// The board pose in the base: per-frame `T_base_board` ([`board_poses_in_base`]), their average and spread.
pub fn board_in_base(
    t_base_ee: &[Isometry3<f64>],
    t_ee_cam: &Isometry3<f64>,
    t_cam_board: &[Isometry3<f64>],
    config: &AverageConfig,
) -> Result<PoseAverage> {
    let poses = board_poses_in_base(t_base_ee, t_ee_cam, t_cam_board)?;
    average_poses(&poses, None, config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::random_isometry;
    use crate::geometry::Rng;

    #[test]
    fn chordal_mean_is_exact_on_equal_rotations_and_sign_free() {
        let mut rng = Rng::new(1);
        for _ in 0..50 {
            let t = random_isometry(&mut rng, 3.1, 1.0);
            let q = t.rotation;
            let flipped = UnitQuaternion::new_unchecked(-q.into_inner());
            let m = chordal_mean(&[q, flipped, q], None).unwrap();
            assert!(rotation_angle_between(&m, &q) < 1e-12);
        }
        assert!(chordal_mean(&[], None).is_err());
        let q = UnitQuaternion::identity();
        assert!(chordal_mean(&[q], Some(&[0.0])).is_err());
        assert!(chordal_mean(&[q], Some(&[1.0, 2.0])).is_err());
    }

    #[test]
    fn symmetric_spread_averages_to_the_centre_and_l1_resists_an_outlier() {
        let mut rng = Rng::new(2);
        let centre = random_isometry(&mut rng, 3.0, 1.0).rotation;
        let mut rots = Vec::new();
        for axis in [Vector3::x(), Vector3::y(), Vector3::z()] {
            for s in [-1.0, 1.0] {
                rots.push(centre * UnitQuaternion::from_scaled_axis(axis * 0.1 * s));
            }
        }
        let m = chordal_mean(&rots, None).unwrap();
        assert!(rotation_angle_between(&m, &centre) < 1e-12);
        // One rotation 90° away: L2 moves, L1 (Weiszfeld) stays much closer.
        rots.push(centre * UnitQuaternion::from_scaled_axis(Vector3::new(1.57, 0.0, 0.0)));
        let l2 = chordal_mean(&rots, None).unwrap();
        let cfg = AverageConfig {
            l1_iterations: 50,
            ..Default::default()
        };
        let l1 = average_rotations(&rots, None, &cfg).unwrap();
        let e2 = rotation_angle_between(&l2, &centre);
        let e1 = rotation_angle_between(&l1, &centre);
        assert!(e1 < 0.3 * e2, "L1 {e1} rad, L2 {e2} rad");
    }

    #[test]
    fn pose_average_spread() {
        let base = Isometry3::translation(1.0, 2.0, 3.0);
        let poses = [
            base * Isometry3::translation(0.001, 0.0, 0.0),
            base * Isometry3::translation(-0.001, 0.0, 0.0),
        ];
        let a = average_poses(&poses, None, &AverageConfig::default()).unwrap();
        assert!((a.mean.translation.vector - base.translation.vector).norm() < 1e-12);
        assert!((a.translation_rms_mm - 1.0).abs() < 1e-9);
        assert!((a.translation_max_mm - 1.0).abs() < 1e-9);
        assert!(a.rotation_max_deg < 1e-9);
    }

    #[test]
    fn board_in_base_recovers_a_fixed_board() {
        let mut rng = Rng::new(4);
        let t_ee_cam = random_isometry(&mut rng, 1.0, 0.2);
        let t_base_board = random_isometry(&mut rng, 3.0, 1.0);
        let ee: Vec<Isometry3<f64>> = (0..8)
            .map(|_| random_isometry(&mut rng, 3.0, 1.0))
            .collect();
        let cam: Vec<Isometry3<f64>> = ee
            .iter()
            .map(|a| (a * t_ee_cam).inverse() * t_base_board)
            .collect();
        let avg = board_in_base(&ee, &t_ee_cam, &cam, &AverageConfig::default()).unwrap();
        assert!(rotation_angle_between(&avg.mean.rotation, &t_base_board.rotation) < 1e-9);
        assert!((avg.mean.translation.vector - t_base_board.translation.vector).norm() < 1e-9);
        assert!(avg.rotation_max_deg < 1e-6 && avg.translation_max_mm < 1e-6);
        assert!(board_in_base(&ee[..2], &t_ee_cam, &cam, &AverageConfig::default()).is_err());
    }
}
