//! Quality of an estimate: covariance from the information matrix, and degeneracy detection.

use nalgebra::{Isometry3, Matrix6, SymmetricEigen, Translation3, UnitQuaternion, Vector3};
use serde::Serialize;

/// One poorly constrained direction of the estimate.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WeakDirection {
    /// `"rotation"` or `"translation"` (the dominant part of the eigenvector).
    pub kind: &'static str,
    /// Unit axis in the target frame.
    pub axis: [f64; 3],
    /// Eigenvalue relative to the largest (0 = unconstrained).
    pub relative_strength: f64,
    /// The whole motion along it, about [`WeakDirection::center`]: rotation (radians) and translation of
    /// the centre (cloud units) per cloud unit that the points at the RMS radius move (the unit
    /// eigenvector with its rotation part divided by that radius).
    #[serde(skip)]
    pub motion_per_unit: [f64; 6],
    /// The centre the motion is about (target frame).
    #[serde(skip)]
    pub center: [f64; 3],
    /// The RMS radius of the points about the centre (cloud units).
    #[serde(skip)]
    pub radius: f64,
    /// The hold test's measurement along it, when it ran (see [`slide_gap`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hold: Option<HoldTest>,
}

/// What the hold test measured along one weak direction: ICP at the finest level started `step` off the
/// answer along it, once each way, and its two ends lay `gap` apart along it. Both in cloud units of motion
/// of the points at the RMS radius (a rotation of `step / radius` radians).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HoldTest {
    /// How far off each start was (cloud units at the RMS radius).
    pub step: f64,
    /// How far apart the two ends lay along the direction (same units; infinite when a run failed).
    pub gap: f64,
    /// `step` as a rotation, degrees, for a rotation; `None` for a translation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub step_deg: Option<f64>,
    /// `gap` as a rotation, degrees, for a rotation; `None` for a translation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gap_deg: Option<f64>,
}

impl WeakDirection {
    /// "rotation about (x, y, z)" or "translation along (x, y, z)".
    pub fn label(&self) -> String {
        let prep = if self.kind == "rotation" {
            "about"
        } else {
            "along"
        };
        format!(
            "{} {prep} ({:.2}, {:.2}, {:.2})",
            self.kind, self.axis[0], self.axis[1], self.axis[2]
        )
    }

    /// The hold test's figures in words, e.g. "started ±0.81° off, the ends 0.128° apart", with `unit`
    /// naming the cloud's length unit; `None` when the test did not run.
    pub fn hold_description(&self, unit: &str) -> Option<String> {
        let h = self.hold?;
        Some(match (h.step_deg, h.gap_deg) {
            (Some(s), Some(g)) => format!("started ±{s:.2}° off, the ends {g:.3}° apart"),
            _ => {
                let sp = if unit.is_empty() { "" } else { " " };
                format!(
                    "started ±{:.4}{sp}{unit} off, the ends {:.4}{sp}{unit} apart",
                    h.step, h.gap
                )
            }
        })
    }
}

impl HoldTest {
    /// The measurement for direction `w` (its kind and RMS radius give the degrees).
    pub fn new(w: &WeakDirection, step: f64, gap: f64) -> Self {
        let deg =
            |x: f64| (w.kind == "rotation" && w.radius > 0.0).then(|| (x / w.radius).to_degrees());
        Self {
            step,
            gap,
            step_deg: deg(step),
            gap_deg: deg(gap),
        }
    }

    /// The gap as a fraction of the step (∞ when the step is 0).
    pub fn fraction(&self) -> f64 {
        if self.step > 0.0 {
            self.gap / self.step
        } else {
            f64::INFINITY
        }
    }
}

/// The least gap (as a fraction of the step) at which the hold test's two ends lie along a noisy bare
/// plane's free directions: they ended 0.54 of the step apart or more (ICP closed at most 73 % of the
/// distance between its starts; docs/accuracy.md, "The hold test's bar"), so a gap below half the step is
/// more than a plane's noise pulls back.
pub const PLANE_HOLD_FRACTION: f64 = 0.5;

/// Degeneracy analysis of an information matrix.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Degeneracy {
    /// Smallest over largest eigenvalue of the normalised information matrix.
    pub condition: f64,
    /// Directions whose relative strength is below the threshold and along which the result can slide:
    /// ICP started off along them did not come back (see [`slide_gap`]). Without that test, every direction
    /// below the threshold.
    pub weak: Vec<WeakDirection>,
    /// Directions below the threshold that the geometry holds all the same: ICP started off along them, once
    /// each way, came back (a floor that outweighs the objects standing on it: the yaw is weak next to the
    /// floor's tilt and height, not unconstrained).
    pub held: Vec<WeakDirection>,
    /// The relative strength below which the geometry itself leaves a direction free: a noisy bare
    /// plane's in-plane motions measure 2e-5 to 2.2e-4
    /// ([`crate::registration::RegisterConfig::degeneracy_threshold`], 6e-4 by default). A weak direction
    /// at or above it is constrained by the geometry, only weakly: when the hold test finds that ICP does
    /// not hold the result along it, the reason says so and does not call it unconstrained. Infinite
    /// (every weak direction counts as free) when not known.
    #[serde(skip)]
    pub free_below: f64,
}

impl Degeneracy {
    /// True when some direction is unconstrained.
    pub fn is_degenerate(&self) -> bool {
        !self.weak.is_empty()
    }

    /// Whether the geometry itself leaves `w` free: its relative strength is below
    /// [`Degeneracy::free_below`], a bare plane's level.
    pub fn free_by_geometry(&self, w: &WeakDirection) -> bool {
        w.relative_strength < self.free_below
    }

    /// Whether `w` is unconstrained, as far as was measured: its strength is at a bare plane's level
    /// ([`Degeneracy::free_by_geometry`]) and, where the hold test ran, ICP started off along it came back
    /// no further than along a bare plane's free directions (its two ends at least [`PLANE_HOLD_FRACTION`]
    /// of the step apart). A direction as weak as a plane's along which ICP closed more of the distance is
    /// pulled back by something: weakly constrained, not free.
    pub fn is_free(&self, w: &WeakDirection) -> bool {
        self.free_by_geometry(w) && w.hold.is_none_or(|h| h.fraction() >= PLANE_HOLD_FRACTION)
    }

    /// A one-line human description, e.g. "translation along (0.00, 0.00, 1.00) is unconstrained".
    pub fn describe(&self) -> String {
        self.weak
            .iter()
            .map(WeakDirection::label)
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The map `[ω; v] = A [ω; v_c]` from increments about `center` to increments about the origin
/// (`v = v_c + c × ω`).
fn about(center: &Vector3<f64>) -> Matrix6<f64> {
    let mut a = Matrix6::identity();
    a.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&center.cross_matrix());
    a
}

/// Re-expresses an information matrix for increments `[ω, v]` about the origin as one for increments
/// about `center` (`v_c = v + ω × c`).
pub fn information_about(h: &Matrix6<f64>, center: &Vector3<f64>) -> Matrix6<f64> {
    let a = about(center);
    a.transpose() * h * a
}

/// Finds weak directions of an information matrix `h` (order ω then v, about the origin), using the
/// centre `center` and length scale `length` of the matched points to make rotation and translation
/// comparable. Directions weaker than `threshold` × the strongest are reported.
pub fn degeneracy(
    h: &Matrix6<f64>,
    center: &Vector3<f64>,
    length: f64,
    threshold: f64,
) -> Degeneracy {
    let hc = information_about(h, center);
    let l = length.max(1e-12);
    let mut s = Matrix6::identity();
    for k in 0..3 {
        s[(k, k)] = 1.0 / l;
    }
    let hs = s * hc * s;
    let eig = SymmetricEigen::new(hs);
    let max = eig.eigenvalues.max().max(1e-300);
    let min = eig.eigenvalues.min();
    let mut weak = Vec::new();
    for k in 0..6 {
        let rel = eig.eigenvalues[k] / max;
        if rel < threshold {
            let v = eig.eigenvectors.column(k);
            let rot = Vector3::new(v[0], v[1], v[2]);
            let tr = Vector3::new(v[3], v[4], v[5]);
            let (kind, axis) = if rot.norm() >= tr.norm() {
                ("rotation", rot.normalize())
            } else {
                ("translation", tr.normalize())
            };
            weak.push(WeakDirection {
                kind,
                axis: [axis.x, axis.y, axis.z],
                relative_strength: rel.max(0.0),
                motion_per_unit: [v[0] / l, v[1] / l, v[2] / l, v[3], v[4], v[5]],
                center: [center.x, center.y, center.z],
                radius: l,
                hold: None,
            });
        }
    }
    Degeneracy {
        condition: (min / max).max(0.0),
        weak,
        held: Vec::new(),
        free_below: threshold,
    }
}

/// The rigid motion along `w` that moves the points at its RMS radius by about `amount` (cloud units):
/// the eigenvector's rotation about [`WeakDirection::center`] and translation of the centre, together.
pub fn motion_along(w: &WeakDirection, amount: f64) -> Isometry3<f64> {
    let m = w.motion_per_unit;
    let c = Vector3::from(w.center);
    let r = UnitQuaternion::from_scaled_axis(Vector3::new(m[0], m[1], m[2]) * amount);
    let v = Vector3::new(m[3], m[4], m[5]) * amount;
    // p ↦ R (p − c) + c + v
    Isometry3::from_parts(Translation3::from(c - r * c + v), r)
}

/// How far apart along `w` two results `a` and `b` (target frame) lie, in the units of [`motion_along`]:
/// the relative motion `a · b⁻¹` about the centre, its rotation scaled by the RMS radius, projected on the
/// unit eigenvector. Two ICP runs started `±δ` along a direction the geometry holds end with a gap near 0;
/// along a free direction they stay about `2δ` apart.
pub fn slide_gap(w: &WeakDirection, a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let m = w.motion_per_unit;
    let c = Vector3::from(w.center);
    let d = a * b.inverse();
    let omega = d.rotation.scaled_axis() * w.radius;
    let v = (d * nalgebra::Point3::from(c)).coords - c;
    // The unit eigenvector: [m_rot · radius, m_trans].
    let e_rot = Vector3::new(m[0], m[1], m[2]) * w.radius;
    let e_tr = Vector3::new(m[3], m[4], m[5]);
    (omega.dot(&e_rot) + v.dot(&e_tr)).abs()
}

/// Covariance `σ² H⁻¹` of an estimate with information `h` and residual variance `sigma2`
/// (pseudo-inverse when `h` is singular: unconstrained directions then get zero instead of infinity, and
/// the degeneracy report says so).
pub fn covariance(h: &Matrix6<f64>, sigma2: f64) -> Matrix6<f64> {
    let eig = SymmetricEigen::new(*h);
    let max = eig.eigenvalues.max().max(1e-300);
    let mut inv = Matrix6::zeros();
    for k in 0..6 {
        let l = eig.eigenvalues[k];
        if l > 1e-12 * max {
            let v = eig.eigenvectors.column(k);
            inv += v * v.transpose() / l;
        }
    }
    inv * sigma2
}

/// The map `ξ = B s` from scaled coordinates about `center` (rotations times `length`, then translations of
/// the centre, all in cloud units) to increments `ξ = [ω, v]` about the origin.
fn scaled_about(center: &Vector3<f64>, length: f64) -> Matrix6<f64> {
    let a = about(center);
    let l = length.max(1e-12);
    let mut s = Matrix6::identity();
    for k in 0..3 {
        s[(k, k)] = 1.0 / l;
    }
    a * s
}

/// Relative floor of the curvature's eigenvalues in [`sandwich_covariance`].
const CURVATURE_FLOOR: f64 = 1e-6;

/// The cluster-robust ("sandwich") covariance `K⁻¹ M K⁻¹ · G/(G−1)` of an M-estimate with increments
/// `[ω, v]` about the origin: `curvature` `K` is the derivative of its estimating equation `Σ w J r = 0`
/// (with correspondences found anew, see [`crate::registration::icp::reassociated_information`]),
/// `scores` `M` the sum over `clusters` spatial blocks `G` of each block's `Σ w J r` outer product
/// ([`crate::registration::icp::IcpResult::block_scores`]). Inverted in coordinates scaled by `length`
/// about `center` (the matched points' centroid and RMS radius, cloud units), where every eigenvalue of
/// `K` below 1e-6 of the largest (or negative: the answer is no minimum along it) is raised to that floor,
/// giving such a direction a large, finite variance.
pub fn sandwich_covariance(
    curvature: &Matrix6<f64>,
    scores: &Matrix6<f64>,
    clusters: usize,
    center: &Vector3<f64>,
    length: f64,
) -> Matrix6<f64> {
    let b = scaled_about(center, length);
    let k = b.transpose() * curvature * b;
    let eig = SymmetricEigen::new(0.5 * (k + k.transpose()));
    let floor = CURVATURE_FLOOR * eig.eigenvalues.max().max(1e-300);
    let ki = eig.eigenvectors
        * Matrix6::from_diagonal(&eig.eigenvalues.map(|l| 1.0 / l.max(floor)))
        * eig.eigenvectors.transpose();
    let g = clusters as f64;
    let small_sample = g / (g - 1.0).max(1.0);
    let c = ki * (b.transpose() * scores * b) * ki * small_sample;
    b * c * b.transpose()
}

/// The smallest covariance (in the ordering of positive semi-definite matrices, found by whitening with
/// `a`) that is at least `a` and at least `b` along every direction: each eigenvalue of `a^-½ b a^-½`
/// below 1 is raised to 1. `a` must be positive definite; otherwise `a + b` is returned.
pub fn covariance_envelope(a: &Matrix6<f64>, b: &Matrix6<f64>) -> Matrix6<f64> {
    let Some(ch) = a.cholesky() else {
        return a + b;
    };
    let l = ch.l();
    let Some(li) = l.try_inverse() else {
        return a + b;
    };
    let w = li * b * li.transpose();
    let eig = SymmetricEigen::new(0.5 * (w + w.transpose()));
    let raised = eig.eigenvectors
        * Matrix6::from_diagonal(&eig.eigenvalues.map(|x| x.max(1.0)))
        * eig.eigenvectors.transpose();
    l * raised * l.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector6};

    fn info_of(points: &[(Vector3<f64>, Vector3<f64>)]) -> Matrix6<f64> {
        let mut h = Matrix6::zeros();
        for (p, n) in points {
            let c = p.cross(n);
            let j = Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z);
            h += j * j.transpose();
        }
        h
    }

    #[test]
    fn plane_is_degenerate_box_is_not() {
        let mut plane = Vec::new();
        let mut boxy = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (a, b) = (i as f64 * 0.05, j as f64 * 0.05);
                // A plane far from the origin (the analysis is about the points' centre).
                plane.push((Vector3::new(a + 3.0, b - 7.0, 10.0), Vector3::z()));
                // The inside corner of a box.
                boxy.push((Vector3::new(a, b, 0.0), Vector3::z()));
                boxy.push((Vector3::new(a, 0.0, b), Vector3::y()));
                boxy.push((Vector3::new(0.0, a, b), Vector3::x()));
            }
        }
        let c = Vector3::new(3.5, -6.5, 10.0);
        let d = degeneracy(&info_of(&plane), &c, 0.3, 1e-3);
        assert_eq!(d.weak.len(), 3, "{d:?}");
        let kinds: Vec<_> = d.weak.iter().map(|w| w.kind).collect();
        assert_eq!(kinds.iter().filter(|k| **k == "translation").count(), 2);
        let d = degeneracy(&info_of(&boxy), &Vector3::new(0.3, 0.3, 0.3), 0.6, 1e-3);
        assert!(!d.is_degenerate(), "{d:?}");
    }

    #[test]
    fn a_step_along_a_weak_direction_is_measured_along_it_only() {
        // A plane's three free directions (two translations in it, the rotation about its normal), about a
        // centre away from the origin.
        let mut plane = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (a, b) = (i as f64 * 0.05, j as f64 * 0.05);
                plane.push((Vector3::new(a + 3.0, b - 7.0, 10.0), Vector3::z()));
            }
        }
        let d = degeneracy(&info_of(&plane), &Vector3::new(3.5, -6.5, 10.0), 0.3, 1e-3);
        assert_eq!(d.weak.len(), 3, "{d:?}");
        let start = Isometry3::new(Vector3::new(0.2, -0.1, 0.05), Vector3::new(0.1, 0.2, -0.3));
        for w in &d.weak {
            for v in &d.weak {
                let moved = motion_along(v, 0.02) * start;
                let gap = slide_gap(w, &moved, &start);
                let expect = if std::ptr::eq(w, v) { 0.02 } else { 0.0 };
                assert!((gap - expect).abs() < 1e-6, "{gap} != {expect}");
            }
            // A rotation moves the points at the RMS radius by the amount: 0.02 / 0.3 rad.
            let m = motion_along(w, 0.02);
            if w.kind == "rotation" {
                assert!((m.rotation.angle() - 0.02 / 0.3).abs() < 1e-9);
                // About the centre: the centre stays.
                let c = Point3::new(3.5, -6.5, 10.0);
                assert!(((m * c) - c).norm() < 1e-9);
            } else {
                assert!((m.translation.vector.norm() - 0.02).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn envelope_is_at_least_each_covariance() {
        let a = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 4.0, 4.0, 4.0));
        let mut b = Matrix6::from_diagonal(&Vector6::new(9.0, 0.25, 1.0, 1.0, 16.0, 0.0));
        b[(0, 3)] = 0.5;
        b[(3, 0)] = 0.5;
        let e = covariance_envelope(&a, &b);
        // e − a and e − b are positive semi-definite.
        for d in [e - a, e - b] {
            let min = SymmetricEigen::new(d).eigenvalues.min();
            assert!(min > -1e-9, "{min}");
        }
        // Diagonal inputs of one axis each: the larger of the two.
        let b2 = Matrix6::from_diagonal(&Vector6::new(9.0, 0.25, 1.0, 1.0, 16.0, 0.0));
        let e2 = covariance_envelope(&a, &b2);
        let want = [9.0, 1.0, 1.0, 4.0, 16.0, 4.0];
        for k in 0..6 {
            assert!((e2[(k, k)] - want[k]).abs() < 1e-9, "{k}: {}", e2[(k, k)]);
        }
    }

    #[test]
    fn sandwich_of_independent_scores_is_the_usual_covariance() {
        // Independent residuals (σ² = 0.01) in many clusters: M = σ² H and K = H give σ² H⁻¹, here for
        // points well away from the origin (the inversion runs about the centre).
        let c = Vector3::new(3.0, -2.0, 1.0);
        let pts: Vec<(Vector3<f64>, Vector3<f64>)> = (0..60)
            .map(|k| {
                let t = k as f64 * 0.37;
                let p = c + Vector3::new(t.sin(), (1.3 * t).cos(), (0.7 * t).sin());
                let n = Vector3::new(t.cos(), (2.1 * t).sin(), 1.0 + (0.3 * t).cos()).normalize();
                (p, n)
            })
            .collect();
        let h = info_of(&pts);
        let got = sandwich_covariance(&h, &(h * 0.01), 1_000_000, &c, 1.0);
        let want = covariance(&h, 0.01);
        assert!((got - want).norm() < 1e-5 * want.norm(), "{got}\n{want}");
        // Few clusters: the small-sample factor G/(G−1).
        let got = sandwich_covariance(&h, &(h * 0.01), 5, &c, 1.0);
        assert!((got - want * 1.25).norm() < 1e-6 * want.norm());
    }

    #[test]
    fn sandwich_gives_a_direction_without_curvature_a_large_variance() {
        // Curvature only in five directions, scores in all six: the sixth gets the floor's variance.
        let c = Vector3::zeros();
        let k = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 1.0, 1.0, 0.0));
        let m = Matrix6::identity() * 1e-6;
        let cov = sandwich_covariance(&k, &m, 1_000_000, &c, 1.0);
        assert!((cov[(0, 0)] - 1e-6).abs() < 1e-9);
        assert!(cov[(5, 5)] > 1e5, "{}", cov[(5, 5)]);
    }
}
