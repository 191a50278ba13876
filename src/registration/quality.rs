//! Quality of an estimate: covariance from the information matrix, and degeneracy detection.

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3};
use serde::Serialize;

/// One poorly constrained direction of the estimate.
#[derive(Clone, Debug, Serialize)]
pub struct WeakDirection {
    /// `"rotation"` or `"translation"` (the dominant part of the eigenvector).
    pub kind: &'static str,
    /// Unit axis in the target frame.
    pub axis: [f64; 3],
    /// Eigenvalue relative to the largest (0 = unconstrained).
    pub relative_strength: f64,
}

/// Degeneracy analysis of an information matrix.
#[derive(Clone, Debug, Serialize)]
pub struct Degeneracy {
    /// Smallest over largest eigenvalue of the normalised information matrix.
    pub condition: f64,
    /// Directions whose relative strength is below the threshold.
    pub weak: Vec<WeakDirection>,
}

impl Degeneracy {
    /// True when some direction is unconstrained.
    pub fn is_degenerate(&self) -> bool {
        !self.weak.is_empty()
    }

    /// A one-line human description, e.g. "translation along (0.00, 0.00, 1.00) is unconstrained".
    pub fn describe(&self) -> String {
        self.weak
            .iter()
            .map(|w| {
                let prep = if w.kind == "rotation" {
                    "about"
                } else {
                    "along"
                };
                format!(
                    "{} {prep} ({:.2}, {:.2}, {:.2})",
                    w.kind, w.axis[0], w.axis[1], w.axis[2]
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Re-expresses an information matrix for increments `[ω, v]` about the origin as one for increments
/// about `center` (`v_c = v + ω × c`).
pub fn information_about(h: &Matrix6<f64>, center: &Vector3<f64>) -> Matrix6<f64> {
    let mut a = Matrix6::identity();
    let cx = Matrix3::new(
        0.0, -center.z, center.y, center.z, 0.0, -center.x, -center.y, center.x, 0.0,
    );
    // [ω; v] = A [ω; v_c] with v = v_c + c × ω.
    a.fixed_view_mut::<3, 3>(3, 0).copy_from(&cx);
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
            });
        }
    }
    Degeneracy {
        condition: (min / max).max(0.0),
        weak,
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;

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
}
