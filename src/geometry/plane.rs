//! Least-squares planes through 3-D points, plain and with outlier rejection.

use nalgebra::{Matrix3, Point3, Vector3};

/// A plane `n · p = d` with unit normal `n`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vector3<f64>,
    /// Offset along the normal, metres (`n · p` for points on the plane).
    pub offset: f64,
}

impl Plane {
    /// Signed distance of `p` from the plane, metres (positive on the normal's side).
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }

    /// Where the ray `t · dir` from the origin meets the plane (`t > 0`), or `None` when it runs parallel
    /// to it or meets it behind the origin.
    pub fn intersect_ray(&self, dir: &Vector3<f64>) -> Option<Point3<f64>> {
        let den = self.normal.dot(dir);
        if den.abs() < 1e-12 {
            return None;
        }
        let t = self.offset / den;
        (t > 0.0).then(|| Point3::from(dir * t))
    }
}

/// The total-least-squares plane through `points` (the centroid and the covariance's smallest
/// eigenvector), or `None` for fewer than 3 points or points on a line.
pub fn fit_plane(points: &[Point3<f64>]) -> Option<Plane> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let c = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut m = Matrix3::zeros();
    for p in points {
        let d = p.coords - c;
        m += d * d.transpose();
    }
    let eig = m.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    // A line (or a point): the two smallest spreads both vanish.
    if eig.eigenvalues[idx[1]] <= 1e-12 * eig.eigenvalues[idx[2]].max(1e-300) {
        return None;
    }
    let normal = eig.eigenvectors.column(idx[0]).normalize();
    Some(Plane {
        normal,
        offset: normal.dot(&c),
    })
}

/// A plane fit with outlier rejection: the plane through all points, then `rounds` refits on the points
/// within `k_sigma` robust standard deviations (1.4826 · median absolute distance, at least `floor_m`).
/// Returns the plane, the inlier mask and the inliers' RMS distance (metres).
pub fn fit_plane_robust(
    points: &[Point3<f64>],
    rounds: usize,
    k_sigma: f64,
    floor_m: f64,
) -> Option<(Plane, Vec<bool>, f64)> {
    let mut plane = fit_plane(points)?;
    let mut keep = vec![true; points.len()];
    for _ in 0..rounds {
        let mut d: Vec<f64> = points.iter().map(|p| plane.distance(p).abs()).collect();
        let mut sorted = d.clone();
        sorted.sort_by(f64::total_cmp);
        let sigma = (1.4826 * sorted[sorted.len() / 2]).max(floor_m);
        for (k, v) in keep.iter_mut().zip(d.iter_mut()) {
            *k = *v <= k_sigma * sigma;
        }
        let inl: Vec<Point3<f64>> = points
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(p, _)| *p)
            .collect();
        plane = fit_plane(&inl)?;
    }
    let (mut s, mut n) = (0.0, 0usize);
    for (p, &k) in points.iter().zip(&keep) {
        if k {
            s += plane.distance(p).powi(2);
            n += 1;
        }
    }
    Some((plane, keep, (s / n.max(1) as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    #[test]
    fn recovers_a_noisy_plane_despite_outliers() {
        let mut rng = Rng::new(3);
        let n = Vector3::new(0.2, -0.3, 1.0).normalize();
        let (u, v) = (
            n.cross(&Vector3::x()).normalize(),
            n.cross(&Vector3::y()).normalize(),
        );
        let mut pts: Vec<Point3<f64>> = (0..500)
            .map(|_| {
                let p = n * 0.7 + u * rng.uniform(-0.1, 0.1) + v * rng.uniform(-0.1, 0.1);
                Point3::from(p + n * 0.001 * rng.normal())
            })
            .collect();
        for k in 0..50 {
            pts[k * 10].coords += n * 0.05;
        }
        let (p, keep, rms) = fit_plane_robust(&pts, 3, 3.0, 1e-4).unwrap();
        let sign = p.normal.dot(&n).signum();
        assert!((p.normal * sign - n).norm() < 2e-3, "{:?}", p.normal);
        assert!((p.offset * sign - 0.7).abs() < 3e-4, "{}", p.offset);
        assert_eq!(keep.iter().filter(|k| !**k).count(), 50);
        assert!(rms < 1.3e-3, "{rms}");
        let hit = p.intersect_ray(&Vector3::new(0.0, 0.0, 1.0)).unwrap();
        assert!(p.distance(&hit).abs() < 1e-12);
        assert!(fit_plane(&pts[..2]).is_none());
        let line: Vec<Point3<f64>> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
        assert!(fit_plane(&line).is_none());
    }
}
