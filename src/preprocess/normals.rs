//! Normal estimation by PCA over a neighbourhood, and normal orientation.

use crate::geometry::cloud::to_v64;
use crate::index::KdIndex;
use nalgebra::{Matrix3, Vector3};
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
        .map_init(Vec::new, |nb, p| {
            match neighbourhood_covariance(points, index, p, cfg, nb) {
                Some(c) => normal_from_covariance(&c),
                None => ([0.0, 0.0, 1.0], 0.0),
            }
        })
        .unzip()
}

/// Scatter matrix (unnormalised covariance) of `p`'s neighbourhood: the neighbours within `cfg.radius`
/// (or the `cfg.max_neighbors` nearest), the 3 nearest when fewer; `None` with fewer than 3 points. `nb`
/// is scratch space for the neighbours (reused across points).
fn neighbourhood_covariance(
    points: &[[f32; 3]],
    index: &KdIndex,
    p: &[f32; 3],
    cfg: &NormalConfig,
    nb: &mut Vec<(usize, f32)>,
) -> Option<Matrix3<f64>> {
    match cfg.radius {
        Some(r) => index.within_into(p, r as f32, cfg.max_neighbors, nb),
        None => index.knn_into(p, cfg.max_neighbors, nb),
    };
    if nb.len() < 3 {
        index.knn_into(p, 3, nb);
    }
    if nb.len() < 3 {
        return None;
    }
    let nb = &nb[..];
    let mut mean = Vector3::zeros();
    for &(i, _) in nb {
        mean += to_v64(&points[i]);
    }
    mean /= nb.len() as f64;
    let mut c = Matrix3::zeros();
    for &(i, _) in nb {
        let d = to_v64(&points[i]) - mean;
        c += d * d.transpose();
    }
    Some(c)
}

/// Normals computed on first use and kept: for a cloud of which only a few points will ever need one (the
/// target of a fine ICP level, where only the nearest neighbours of the source sample are paired: about
/// 11k of 225k points on a 1M-point pair). Each point's normal is the one [`estimate_normals`] gives it,
/// a function of its neighbourhood alone, so the results do not depend on which thread computed it first.
pub struct LazyNormals<'a> {
    points: &'a [[f32; 3]],
    index: &'a KdIndex,
    cfg: NormalConfig,
    cells: Vec<std::sync::OnceLock<[f32; 3]>>,
}

impl<'a> LazyNormals<'a> {
    /// Normals of `points` (indexed by `index`) as `cfg` says, none computed yet.
    pub fn new(points: &'a [[f32; 3]], index: &'a KdIndex, cfg: NormalConfig) -> Self {
        LazyNormals {
            points,
            index,
            cfg,
            cells: (0..points.len())
                .map(|_| std::sync::OnceLock::new())
                .collect(),
        }
    }

    /// The unit normal of point `i` (sign arbitrary), computed now if it has not been yet.
    #[inline]
    pub fn get(&self, i: usize) -> [f32; 3] {
        *self.cells[i].get_or_init(|| {
            let mut nb = Vec::with_capacity(self.cfg.max_neighbors);
            match neighbourhood_covariance(
                self.points,
                self.index,
                &self.points[i],
                &self.cfg,
                &mut nb,
            ) {
                Some(c) => normal_from_covariance(&c).0,
                None => [0.0, 0.0, 1.0],
            }
        })
    }

    /// How many normals have been computed so far.
    pub fn computed(&self) -> usize {
        self.cells.iter().filter(|c| c.get().is_some()).count()
    }
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
        .map_init(Vec::new, |nb, p| {
            let Some(c) = neighbourhood_covariance(points, index, p, cfg, nb) else {
                return ([1.0, 0.0, 0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0]);
            };
            let (val, vec) = symmetric_eigen3(&c);
            let (n, _) = normal_and_variation(&val, &vec);
            let top = val.iter().fold(0f64, |a, &b| a.max(b));
            if !(top > 0.0 && top.is_finite()) {
                return ([1.0, 0.0, 0.0, 1.0, 0.0, 1.0], n);
            }
            // Eigenvalues relative to the largest, at least ε: a clean plane becomes (ε, ~1, 1), a noisy
            // blob stays round instead of pretending to be a confident plane.
            let mut r = Matrix3::zeros();
            for (k, &lambda) in val.iter().enumerate() {
                let v = vec.column(k);
                r += (lambda / top).max(EPS) * v * v.transpose();
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

/// Normal (smallest-eigenvalue eigenvector) and surface variation of a 3x3 covariance
/// ([`symmetric_eigen3`]).
pub fn normal_from_covariance(c: &Matrix3<f64>) -> ([f32; 3], f32) {
    let (val, vec) = symmetric_eigen3(c);
    normal_and_variation(&val, &vec)
}

/// The normal (first column of `vec`, unit) and the surface variation `λ0 / (λ0 + λ1 + λ2)` (negative
/// eigenvalues counted as 0) of an eigen-decomposition with ascending eigenvalues `val`; `[0, 0, 1]` and
/// 0 when it is not finite.
fn normal_and_variation(val: &[f64; 3], vec: &Matrix3<f64>) -> ([f32; 3], f32) {
    let n = vec.column(0);
    let sum: f64 = val.iter().map(|v| v.max(0.0)).sum();
    let curv = if sum > 0.0 {
        val[0].max(0.0) / sum
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

/// Eigenvalues (ascending) and unit eigenvectors (as the columns, in the same order) of a symmetric 3x3
/// matrix, in closed form: Eberly's robust non-iterative solver ("A Robust Eigensolver for 3 × 3 Symmetric
/// Matrices", Geometric Tools 2014), the one Open3D uses for normals. The eigenvalues come from the
/// trigonometric solution of the characteristic cubic after scaling the matrix by its largest entry; the
/// eigenvector of the best-separated eigenvalue is the largest cross product of two rows of `A − λI`, the
/// second comes from the 2x2 problem in its orthogonal complement, the third is their cross product, so
/// the three are orthonormal even for repeated eigenvalues. About 10x faster than nalgebra's iterative
/// `SymmetricEigen` on 3x3 matrices; eigenvalues agree to about 1e-15 of the largest.
pub fn symmetric_eigen3(c: &Matrix3<f64>) -> ([f64; 3], Matrix3<f64>) {
    let (a00, a01, a02, a11, a12, a22) = (
        c[(0, 0)],
        c[(0, 1)],
        c[(0, 2)],
        c[(1, 1)],
        c[(1, 2)],
        c[(2, 2)],
    );
    let max_abs = [a00, a01, a02, a11, a12, a22]
        .iter()
        .fold(0f64, |m, v| m.max(v.abs()));
    if !(max_abs > 0.0 && max_abs.is_finite()) {
        return ([0.0; 3], Matrix3::identity());
    }
    let inv = 1.0 / max_abs;
    let (a00, a01, a02, a11, a12, a22) = (
        a00 * inv,
        a01 * inv,
        a02 * inv,
        a11 * inv,
        a12 * inv,
        a22 * inv,
    );
    let a = Matrix3::new(a00, a01, a02, a01, a11, a12, a02, a12, a22);
    let off = a01 * a01 + a02 * a02 + a12 * a12;
    let (eval, evec) = if off > 0.0 {
        let q = (a00 + a11 + a22) / 3.0;
        let (b00, b11, b22) = (a00 - q, a11 - q, a22 - q);
        let p = ((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * off) / 6.0).sqrt();
        let c00 = b11 * b22 - a12 * a12;
        let c01 = a01 * b22 - a12 * a02;
        let c02 = a01 * a12 - b11 * a02;
        let det = (b00 * c00 - a01 * c01 + a02 * c02) / (p * p * p);
        let half_det = (0.5 * det).clamp(-1.0, 1.0);
        let angle = half_det.acos() / 3.0;
        const TWO_THIRDS_PI: f64 = 2.094_395_102_393_195_5;
        let beta2 = angle.cos() * 2.0;
        let beta0 = (angle + TWO_THIRDS_PI).cos() * 2.0;
        let beta1 = -(beta0 + beta2);
        let eval = [q + p * beta0, q + p * beta1, q + p * beta2];
        let (e0, e1, e2) = if half_det >= 0.0 {
            let e2 = eigenvector0(&a, eval[2]);
            let e1 = eigenvector1(&a, &e2, eval[1]);
            (e1.cross(&e2), e1, e2)
        } else {
            let e0 = eigenvector0(&a, eval[0]);
            let e1 = eigenvector1(&a, &e0, eval[1]);
            (e0, e1, e0.cross(&e1))
        };
        (eval, Matrix3::from_columns(&[e0, e1, e2]))
    } else {
        // Diagonal: the axes, sorted by their entries.
        let d = [a00, a11, a22];
        let mut order = [0usize, 1, 2];
        order.sort_by(|&x, &y| d[x].total_cmp(&d[y]));
        let id = Matrix3::<f64>::identity();
        (
            order.map(|k| d[k]),
            Matrix3::from_columns(&order.map(|k| id.column(k).into_owned())),
        )
    };
    (eval.map(|v| v * max_abs), evec)
}

/// Unit eigenvector of `a` for the eigenvalue `eval` when it is simple: the largest cross product of two
/// rows of `a − eval·I`.
fn eigenvector0(a: &Matrix3<f64>, eval: f64) -> Vector3<f64> {
    let r0 = Vector3::new(a[(0, 0)] - eval, a[(0, 1)], a[(0, 2)]);
    let r1 = Vector3::new(a[(0, 1)], a[(1, 1)] - eval, a[(1, 2)]);
    let r2 = Vector3::new(a[(0, 2)], a[(1, 2)], a[(2, 2)] - eval);
    let (c01, c02, c12) = (r0.cross(&r1), r0.cross(&r2), r1.cross(&r2));
    let (d0, d1, d2) = (c01.norm_squared(), c02.norm_squared(), c12.norm_squared());
    if d0 >= d1 && d0 >= d2 {
        c01 / d0.sqrt()
    } else if d1 >= d2 {
        c02 / d1.sqrt()
    } else {
        c12 / d2.sqrt()
    }
}

/// Unit eigenvector of `a` for `eval1`, orthogonal to the unit eigenvector `e0`: the 2x2 problem in the
/// plane orthogonal to `e0`.
fn eigenvector1(a: &Matrix3<f64>, e0: &Vector3<f64>, eval1: f64) -> Vector3<f64> {
    let u = if e0.x.abs() > e0.y.abs() {
        Vector3::new(-e0.z, 0.0, e0.x) / (e0.x * e0.x + e0.z * e0.z).sqrt()
    } else {
        Vector3::new(0.0, e0.z, -e0.y) / (e0.y * e0.y + e0.z * e0.z).sqrt()
    };
    let v = e0.cross(&u);
    let (au, av) = (a * u, a * v);
    let mut m00 = u.dot(&au) - eval1;
    let mut m01 = u.dot(&av);
    let mut m11 = v.dot(&av) - eval1;
    let (abs00, abs01, abs11) = (m00.abs(), m01.abs(), m11.abs());
    if abs00 >= abs11 {
        if abs00.max(abs01) > 0.0 {
            if abs00 >= abs01 {
                m01 /= m00;
                m00 = 1.0 / (1.0 + m01 * m01).sqrt();
                m01 *= m00;
            } else {
                m00 /= m01;
                m01 = 1.0 / (1.0 + m00 * m00).sqrt();
                m00 *= m01;
            }
            u * m01 - v * m00
        } else {
            u
        }
    } else if abs11.max(abs01) > 0.0 {
        if abs11 >= abs01 {
            m01 /= m11;
            m11 = 1.0 / (1.0 + m01 * m01).sqrt();
            m01 *= m11;
        } else {
            m11 /= m01;
            m01 = 1.0 / (1.0 + m11 * m11).sqrt();
            m11 *= m01;
        }
        u * m11 - v * m01
    } else {
        u
    }
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
            normals
                .par_iter_mut()
                .enumerate()
                .for_each_init(Vec::new, |nb, (i, n)| {
                    let p = points[i];
                    index.within_into(&p, r, 64, nb);
                    let mut c = [0f64; 3];
                    for &(j, _) in nb.iter() {
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
    use nalgebra::SymmetricEigen;

    /// The closed-form solver against nalgebra's iterative one: eigenvalues to 1e-12 of the largest, and
    /// each eigenvector of a simple eigenvalue parallel to nalgebra's; orthonormal columns always. Random
    /// scatter matrices, flat ones (a plane's), diagonal ones, repeated eigenvalues and zero.
    #[test]
    fn closed_form_eigen_matches_nalgebra() {
        let mut rng = Rng::new(7);
        let mut cases: Vec<Matrix3<f64>> = Vec::new();
        for _ in 0..2000 {
            let pts: Vec<Vector3<f64>> = (0..12)
                .map(|_| {
                    let flat = rng.uniform(0.0, 1.0) < 0.3;
                    let z = if flat {
                        1e-4 * rng.normal()
                    } else {
                        rng.normal()
                    };
                    Vector3::new(rng.normal() * 3.0, rng.normal(), z)
                })
                .collect();
            let r =
                nalgebra::Rotation3::new(Vector3::new(rng.normal(), rng.normal(), rng.normal()));
            let mut c = Matrix3::zeros();
            for p in &pts {
                let q = r * p;
                c += q * q.transpose();
            }
            cases.push(c);
        }
        cases.push(Matrix3::from_diagonal(&Vector3::new(3.0, 1.0, 2.0)));
        cases.push(Matrix3::identity() * 2.0);
        cases.push(Matrix3::new(2.0, 1.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 3.0));
        cases.push(Matrix3::zeros());
        for c in &cases {
            let (val, vec) = symmetric_eigen3(c);
            let scale = c.abs().max().max(1e-300);
            assert!(val[0] <= val[1] && val[1] <= val[2], "{val:?}");
            assert!((vec.transpose() * vec - Matrix3::identity()).abs().max() < 1e-9);
            let eig = SymmetricEigen::new(*c);
            let mut want: Vec<(f64, Vector3<f64>)> = (0..3)
                .map(|k| (eig.eigenvalues[k], eig.eigenvectors.column(k).into_owned()))
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0));
            for k in 0..3 {
                assert!(
                    (val[k] - want[k].0).abs() <= 1e-12 * scale,
                    "{val:?} {want:?}"
                );
                // A simple eigenvalue's eigenvector is unique up to sign.
                let gap = (0..3)
                    .filter(|&j| j != k)
                    .map(|j| (want[j].0 - want[k].0).abs())
                    .fold(f64::INFINITY, f64::min);
                if gap > 1e-6 * scale {
                    let cos = vec.column(k).dot(&want[k].1).abs();
                    assert!(cos > 1.0 - 1e-9, "column {k}: cos {cos}, {c}");
                }
            }
        }
    }

    /// A lazy normal is the eager one, bit for bit, and only the asked-for ones are computed.
    #[test]
    fn lazy_normals_equal_the_eager_ones() {
        let mut rng = Rng::new(4);
        let pts: Vec<[f32; 3]> = (0..5000)
            .map(|_| {
                let d = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
                [d.x as f32, d.y as f32, (d.z * 0.3) as f32]
            })
            .collect();
        let idx = KdIndex::new(&pts);
        let cfg = NormalConfig {
            radius: Some(0.1),
            max_neighbors: 30,
        };
        let eager = estimate_normals(&pts, &idx, &cfg);
        let lazy = LazyNormals::new(&pts, &idx, cfg);
        for i in (0..pts.len()).step_by(7) {
            assert_eq!(lazy.get(i), eager[i]);
            assert_eq!(lazy.get(i), eager[i]);
        }
        assert_eq!(lazy.computed(), pts.len().div_ceil(7));
    }

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
