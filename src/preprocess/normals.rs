//! Normal estimation by PCA over a neighbourhood, and normal orientation.

use crate::geometry::cloud::to_v64;
use crate::index::KdIndex;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of [`estimate_normals`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NormalConfig {
    /// Search radius in cloud units; `None` uses the `k` nearest neighbours with no radius limit.
    pub radius: Option<f64>,
    /// Largest number of neighbours used (default 30).
    pub max_neighbors: usize,
}

impl Default for NormalConfig {
    fn default() -> Self {
        NormalConfig {
            radius: None,
            max_neighbors: 30,
        }
    }
}

impl NormalConfig {
    /// Checks the ranges; the error names the field (`normals.…`).
    pub fn validate(&self) -> crate::Result<()> {
        use crate::error::check;
        if let Some(r) = self.radius {
            check::positive("normals.radius", r)?;
        }
        check::at_least("normals.max_neighbors", self.max_neighbors, 3)
    }
}

/// Where normals should point.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum Orientation {
    /// Toward the centroid of the cloud. Moves with the cloud under any rigid transform, so two clouds of
    /// the same scene get consistent normals whatever their poses (the default for `register`).
    TowardCentroid,
    /// Toward a fixed viewpoint (e.g. the sensor origin), in cloud coordinates.
    TowardPoint([f64; 3]),
    /// Toward the centroid of each point's neighbourhood of this radius (cloud units): the concave side
    /// of the local surface. It is decided locally, so two partially overlapping clouds of one scene get
    /// the same normals in their common part whatever their poses. Where the neighbourhood is flat
    /// (centroid within 2% of the radius from the tangent plane) the cloud centroid decides.
    LocalCentroid(f64),
}

/// Unit normal of each point (sign arbitrary; see [`orient_toward_point`]) from the smallest-eigenvalue
/// eigenvector of its neighbourhood covariance. Points with fewer than 3 neighbours get the normal of
/// their nearest neighbour's plane fallback `[0, 0, 1]`; the second value returned is the surface variation
/// `λ0 / (λ0 + λ1 + λ2)` of each point (0 on a plane).
pub fn estimate_normals(points: &[[f32; 3]], index: &KdIndex, cfg: &NormalConfig) -> Vec<[f32; 3]> {
    estimate_normals_with_curvature(points, index, cfg).0
}

/// As [`estimate_normals`], also returning the surface variation of each point.
pub fn estimate_normals_with_curvature(
    points: &[[f32; 3]],
    index: &KdIndex,
    cfg: &NormalConfig,
) -> (Vec<[f32; 3]>, Vec<f32>) {
    points
        .par_iter()
        .map(|p| match neighbourhood_covariance(points, index, p, cfg) {
            Some(c) => normal_from_covariance(&c),
            None => ([0.0, 0.0, 1.0], 0.0),
        })
        .unzip()
}

/// Scatter matrix (unnormalised covariance) of `p`'s neighbourhood: the neighbours within `cfg.radius`
/// (or the `cfg.max_neighbors` nearest), the 3 nearest when fewer; `None` with fewer than 3 points.
fn neighbourhood_covariance(
    points: &[[f32; 3]],
    index: &KdIndex,
    p: &[f32; 3],
    cfg: &NormalConfig,
) -> Option<Matrix3<f64>> {
    let nb = match cfg.radius {
        Some(r) => index.within(p, r as f32, cfg.max_neighbors),
        None => index.knn(p, cfg.max_neighbors),
    };
    let nb = if nb.len() < 3 { index.knn(p, 3) } else { nb };
    if nb.len() < 3 {
        return None;
    }
    let mut mean = Vector3::zeros();
    for &(i, _) in &nb {
        mean += to_v64(&points[i]);
    }
    mean /= nb.len() as f64;
    let mut c = Matrix3::zeros();
    for &(i, _) in &nb {
        let d = to_v64(&points[i]) - mean;
        c += d * d.transpose();
    }
    Some(c)
}

/// Regularised local covariance of each point for GICP, packed `[xx, xy, xz, yy, yz, zz]`, with its unit
/// normal: the covariance of the point's neighbourhood (as for [`estimate_normals`]) with its eigenvalues
/// divided by the largest and floored at ε = 1e-3 (a clean plane becomes GICP's `(ε, 1, 1)` disc, a noisy
/// blob stays round), so that the scale does not depend on the local density. Points with fewer than 3
/// neighbours get the identity and the normal `[0, 0, 1]`.
pub fn estimate_covariances(
    points: &[[f32; 3]],
    index: &KdIndex,
    cfg: &NormalConfig,
) -> (Vec<[f32; 6]>, Vec<[f32; 3]>) {
    const EPS: f64 = 1e-3;
    points
        .par_iter()
        .map(|p| {
            let Some(c) = neighbourhood_covariance(points, index, p, cfg) else {
                return ([1.0, 0.0, 0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0]);
            };
            let (n, _) = normal_from_covariance(&c);
            let eig = SymmetricEigen::new(c);
            let top = eig.eigenvalues.iter().fold(0f64, |a, &b| a.max(b));
            if !(top > 0.0 && top.is_finite()) {
                return ([1.0, 0.0, 0.0, 1.0, 0.0, 1.0], n);
            }
            // Eigenvalues relative to the largest, at least ε: a clean plane becomes (ε, ~1, 1), a noisy
            // blob stays round instead of pretending to be a confident plane.
            let mut r = Matrix3::zeros();
            for k in 0..3 {
                let v = eig.eigenvectors.column(k);
                r += (eig.eigenvalues[k] / top).max(EPS) * v * v.transpose();
            }
            (
                [
                    r[(0, 0)],
                    r[(0, 1)],
                    r[(0, 2)],
                    r[(1, 1)],
                    r[(1, 2)],
                    r[(2, 2)],
                ]
                .map(|x| x as f32),
                n,
            )
        })
        .unzip()
}

/// Normal (smallest-eigenvalue eigenvector) and surface variation of a 3x3 covariance.
pub fn normal_from_covariance(c: &Matrix3<f64>) -> ([f32; 3], f32) {
    let eig = SymmetricEigen::new(*c);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let n = eig.eigenvectors.column(order[0]);
    let sum: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
    let curv = if sum > 0.0 {
        eig.eigenvalues[order[0]].max(0.0) / sum
    } else {
        0.0
    };
    let norm = n.norm();
    if norm.is_nan() || norm <= 0.0 || !norm.is_finite() {
        return ([0.0, 0.0, 1.0], 0.0);
    }
    (
        [
            (n[0] / norm) as f32,
            (n[1] / norm) as f32,
            (n[2] / norm) as f32,
        ],
        curv as f32,
    )
}

/// Flips each normal so that it points toward `viewpoint`.
pub fn orient_toward_point(points: &[[f32; 3]], normals: &mut [[f32; 3]], viewpoint: [f32; 3]) {
    normals.par_iter_mut().zip(points).for_each(|(n, p)| {
        let d = [
            viewpoint[0] - p[0],
            viewpoint[1] - p[1],
            viewpoint[2] - p[2],
        ];
        if n[0] * d[0] + n[1] * d[1] + n[2] * d[2] < 0.0 {
            *n = [-n[0], -n[1], -n[2]];
        }
    });
}

/// Orients normals as `orientation` says.
pub fn orient(points: &[[f32; 3]], normals: &mut [[f32; 3]], orientation: Orientation) {
    let global = || {
        let c = crate::PointCloud::from_points(points.to_vec()).centroid();
        [c.x, c.y, c.z]
    };
    let vp = match orientation {
        Orientation::TowardPoint(v) => v,
        Orientation::TowardCentroid => global(),
        Orientation::LocalCentroid(radius) => {
            let index = KdIndex::new(points);
            let g = global();
            let g = [g[0] as f32, g[1] as f32, g[2] as f32];
            let r = radius as f32;
            normals.par_iter_mut().enumerate().for_each(|(i, n)| {
                let p = points[i];
                let nb = index.within(&p, r, 64);
                let mut c = [0f64; 3];
                for &(j, _) in &nb {
                    for k in 0..3 {
                        c[k] += points[j][k] as f64;
                    }
                }
                let m = nb.len().max(1) as f64;
                let d = [
                    (c[0] / m) as f32 - p[0],
                    (c[1] / m) as f32 - p[1],
                    (c[2] / m) as f32 - p[2],
                ];
                let mut s = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
                if s.abs() < 0.02 * r {
                    s = n[0] * (g[0] - p[0]) + n[1] * (g[1] - p[1]) + n[2] * (g[2] - p[2]);
                }
                if s < 0.0 {
                    *n = [-n[0], -n[1], -n[2]];
                }
            });
            return;
        }
    };
    orient_toward_point(points, normals, [vp[0] as f32, vp[1] as f32, vp[2] as f32]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    #[test]
    fn plane_and_sphere_normals() {
        let mut rng = Rng::new(2);
        // A tilted plane through the origin with normal (1, 1, 1)/√3.
        let n0 = Vector3::new(1.0, 1.0, 1.0).normalize();
        let u = Vector3::new(1.0, -1.0, 0.0).normalize();
        let v = n0.cross(&u);
        let pts: Vec<[f32; 3]> = (0..2000)
            .map(|_| {
                let p = u * rng.uniform(-1.0, 1.0) + v * rng.uniform(-1.0, 1.0);
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect();
        let idx = KdIndex::new(&pts);
        let mut ns = estimate_normals(&pts, &idx, &NormalConfig::default());
        orient_toward_point(&pts, &mut ns, [10.0, 10.0, 10.0]);
        for n in &ns {
            assert!(to_v64(n).dot(&n0) > 0.999);
        }
        // Sphere: normals radial, pointing inward toward the centroid.
        let pts: Vec<[f32; 3]> = (0..4000)
            .map(|_| {
                let d = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
                [d.x as f32, d.y as f32, d.z as f32]
            })
            .collect();
        let idx = KdIndex::new(&pts);
        let mut ns = estimate_normals(&pts, &idx, &NormalConfig::default());
        orient(&pts, &mut ns, Orientation::TowardCentroid);
        for (p, n) in pts.iter().zip(&ns) {
            assert!(to_v64(n).dot(&to_v64(p)) < -0.98);
        }
    }
}
