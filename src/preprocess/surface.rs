//! Count-weighted surface projection of fused voxels.
//!
//! Voxel fusion of noisy depth splits a surface that lies along a voxel layer (a level table in a level
//! robot base) into two or more sheets of voxel means: the layer holding most samples, and the neighbouring
//! layers holding the noise tails. Every voxel is one point whatever its sample count, so the thin tail
//! sheets weigh as much as the main one and the cloud's surface sits up to about one noise σ away from the
//! mean of the samples (measured: two sheets 1.75 mm apart on a simulated table, 6:1 in samples, 1:1 in
//! voxels). Registering two such clouds, whose grids cut the surfaces differently, is biased by up to a
//! millimetre.
//!
//! [`project_to_weighted_planes`] moves each point onto the surface fitted to its neighbourhood with the
//! sample counts as weights, which passes through the mean of the raw samples there; the sheets collapse
//! onto it. Points whose neighbourhood is not planar (edges, corners, small curved parts) stay where they
//! are.
//!
//! The surface is a quadric: a height field of second order over the weighted tangent plane (moving least
//! squares, as PCL's `MovingLeastSquares` fits it). A plane through a curved neighbourhood lies inside the
//! curve (its chord), so projecting onto it shrinks a cylinder or a sphere; two robots that see an object
//! from opposite sides then see it shrunk toward each other's side, which biases yaw and the translation
//! between them. Measured on foreign cells of cylinders and spheres only (refinement from the truth): the
//! plane 0.10-0.145° / 2.4-3.4 mm, the quadric (see `tools`/accuracy.md) far less.

use crate::geometry::cloud::to_v64;
use crate::index::KdIndex;
use crate::preprocess::normals::normal_from_covariance;
use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`project_to_weighted_planes`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SurfaceConfig {
    /// Neighbourhood radius in voxels (default 2).
    pub radius_voxels: f64,
    /// Neighbours used at most, closest first (default 48).
    pub max_neighbors: usize,
    /// A point is moved only when its weighted neighbourhood has a surface variation `λ0 / (λ0 + λ1 + λ2)`
    /// below this (default 0.1). A plane split into two sheets half a voxel apart measures ~0.01, a sheet
    /// as thick as a voxel (far, noisy depth) ~0.15 at the centre and less toward its weighted plane, a
    /// right-angled box edge 0.1-0.2. Measured on simulated cells (ICP from the truth, 10 seeds): 0.03
    /// leaves the thick sheets alone and one seed 0.29° off; 0.1 gives at most 0.028° / 0.34 mm; 0.2 (with
    /// a 2.5-voxel radius) rounds edges and shrinks curved objects (0.083° / 0.92 mm).
    pub max_surface_variation: f64,
    /// A point is moved by at most this many voxels (default 1.5).
    pub max_shift_voxels: f64,
    /// Fit a quadric (a second-order height field over the weighted tangent plane) instead of a plane
    /// (default true): a plane through a curved neighbourhood is its chord and moves the points inward.
    pub quadric: bool,
}

impl Default for SurfaceConfig {
    fn default() -> Self {
        SurfaceConfig {
            radius_voxels: 2.0,
            max_neighbors: 48,
            max_surface_variation: 0.1,
            max_shift_voxels: 1.5,
            quadric: true,
        }
    }
}

impl SurfaceConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> crate::Result<()> {
        let bad = |field: &str, msg: String| {
            Err(crate::Error::Config {
                field: format!("surface.{field}"),
                msg,
            })
        };
        if !(self.radius_voxels.is_finite() && self.radius_voxels > 0.0) {
            return bad(
                "radius_voxels",
                format!("must be positive, found {}", self.radius_voxels),
            );
        }
        if self.max_neighbors < 3 {
            return bad(
                "max_neighbors",
                format!("must be at least 3, found {}", self.max_neighbors),
            );
        }
        if !(self.max_surface_variation.is_finite() && self.max_surface_variation >= 0.0) {
            return bad(
                "max_surface_variation",
                format!("must be ≥ 0, found {}", self.max_surface_variation),
            );
        }
        if !(self.max_shift_voxels.is_finite() && self.max_shift_voxels >= 0.0) {
            return bad(
                "max_shift_voxels",
                format!("must be ≥ 0, found {}", self.max_shift_voxels),
            );
        }
        Ok(())
    }
}

/// Moves each point onto the plane fitted, with `weights` (e.g. sample counts), to its neighbours within
/// `cfg.radius_voxels · voxel` (cloud units), where that neighbourhood is planar; returns the new points and
/// how many were moved. Deterministic.
pub fn project_to_weighted_planes(
    points: &[[f32; 3]],
    weights: &[u32],
    index: &KdIndex,
    voxel: f64,
    cfg: &SurfaceConfig,
) -> (Vec<[f32; 3]>, usize) {
    assert_eq!(points.len(), weights.len(), "one weight per point");
    let radius = (cfg.radius_voxels * voxel) as f32;
    let max_shift = cfg.max_shift_voxels * voxel;
    let out: Vec<([f32; 3], bool)> = points
        .par_iter()
        .map_init(Vec::new, |nb, p| {
            index.within_into(p, radius, cfg.max_neighbors, nb);
            if nb.len() < 6 {
                return (*p, false);
            }
            let mut sw = 0f64;
            let mut mean = Vector3::zeros();
            for &(j, _) in nb.iter() {
                let w = weights[j].max(1) as f64;
                sw += w;
                mean += w * to_v64(&points[j]);
            }
            mean /= sw;
            let mut c = Matrix3::zeros();
            for &(j, _) in nb.iter() {
                let d = to_v64(&points[j]) - mean;
                c += (weights[j].max(1) as f64 / sw) * d * d.transpose();
            }
            let (n, variation) = normal_from_covariance(&c);
            if variation as f64 > cfg.max_surface_variation {
                return (*p, false);
            }
            let n = to_v64(&n);
            let q = to_v64(p);
            let height = if cfg.quadric {
                quadric_height(points, weights, nb, &mean, &n, &q, radius as f64)
            } else {
                0.0
            };
            let off = n.dot(&(q - mean)) - height;
            if off.abs() > max_shift {
                return (*p, false);
            }
            let moved = q - off * n;
            ([moved.x as f32, moved.y as f32, moved.z as f32], true)
        })
        .collect();
    let moved = out.iter().filter(|o| o.1).count();
    (out.into_iter().map(|o| o.0).collect(), moved)
}

/// The height over the tangent plane (through `mean`, normal `n`) at `q`'s place of the quadric
/// `h(u, v) = a + b u + c v + d u² + e u v + f v²` fitted by weighted least squares to the neighbours `nb`
/// of `points` (weights the sample counts; `u`, `v` in units of `radius`). The quadric is used only where
/// it explains the neighbourhood: its weighted squared residual must be at most
/// [`QUADRIC_RESIDUAL_RATIO`] of the plane's. Where the plane's misfit is noise or sheets of voxel means
/// rather than curvature, six parameters over a few dozen points would only fit that noise; there, and
/// where the fit is singular (neighbours on a line), the height is 0 (the plane).
fn quadric_height(
    points: &[[f32; 3]],
    weights: &[u32],
    nb: &[(usize, f32)],
    mean: &Vector3<f64>,
    n: &Vector3<f64>,
    q: &Vector3<f64>,
    radius: f64,
) -> f64 {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    let s = 1.0 / radius.max(f64::MIN_POSITIVE);
    let basis = |d: &Vector3<f64>| {
        let (u, v) = (d.dot(&e1) * s, d.dot(&e2) * s);
        Vector6::new(1.0, u, v, u * u, u * v, v * v)
    };
    let mut a = Matrix6::zeros();
    let mut b = Vector6::zeros();
    for &(j, _) in nb {
        let d = to_v64(&points[j]) - mean;
        let phi = basis(&d);
        let w = weights[j].max(1) as f64;
        a += w * phi * phi.transpose();
        b += w * d.dot(n) * phi;
    }
    // A tiny ridge keeps a nearly singular fit (neighbours close to a line) from blowing up.
    let ridge = 1e-9 * a.trace();
    for k in 0..6 {
        a[(k, k)] += ridge;
    }
    let Some(c) = a.cholesky() else {
        return 0.0;
    };
    let coef = c.solve(&b);
    let (mut sse_plane, mut sse_quadric) = (0.0, 0.0);
    for &(j, _) in nb {
        let d = to_v64(&points[j]) - mean;
        let w = weights[j].max(1) as f64;
        let h = d.dot(n);
        sse_plane += w * h * h;
        sse_quadric += w * (h - basis(&d).dot(&coef)).powi(2);
    }
    let h = basis(&(q - mean)).dot(&coef);
    if h.is_finite() && sse_quadric <= QUADRIC_RESIDUAL_RATIO * sse_plane {
        h
    } else {
        0.0
    }
}

/// The largest ratio of the quadric's weighted squared residual to the plane's at which
/// [`quadric_height`] uses the quadric: curvature must explain most of the plane's misfit. Measured in the
/// tests: a cylinder 8 voxels in radius 2.4e-5 at every point; two interleaved sheets of voxel means (the
/// misfit the plane projection exists for) 0.92-1.0 (10th to 90th percentile).
const QUADRIC_RESIDUAL_RATIO: f64 = 0.5;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    #[test]
    fn two_sheets_collapse_onto_the_weighted_mean_plane() {
        // A plane z = 0 split into a heavy sheet at z = -0.7 and a light one at z = +1.0 (1:6 in weight,
        // 1:1 in points), voxel 4: the weighted mean plane is at (6·-0.7 + 1·1.0)/7 = -0.457.
        let mut rng = Rng::new(3);
        let mut pts = Vec::new();
        let mut w = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 4.0, j as f32 * 4.0);
                pts.push([x + rng.uniform(-1.0, 1.0) as f32, y, -0.7]);
                w.push(6);
                pts.push([x, y + rng.uniform(-1.0, 1.0) as f32, 1.0]);
                w.push(1);
            }
        }
        let idx = KdIndex::new(&pts);
        let (out, moved) =
            project_to_weighted_planes(&pts, &w, &idx, 4.0, &SurfaceConfig::default());
        assert_eq!(moved, pts.len());
        let expect = (6.0 * -0.7 + 1.0) / 7.0;
        // Interior points (full neighbourhoods) land on the weighted plane: on average within 0.02, each
        // within what the varying neighbour counts of the two sheets allow (11-14 each within the radius:
        // ±0.1); the unweighted mean plane would be at +0.15, the sheets are 1.7 apart. Tangential motion
        // stays within a 2° tilt of the 1.5-unit moves.
        let (mut sum, mut n) = (0.0, 0);
        for (p, q) in pts.iter().zip(&out) {
            if (12.0..144.0).contains(&p[0]) && (12.0..144.0).contains(&p[1]) {
                assert!((q[2] as f64 - expect).abs() < 0.1, "{p:?} -> {q:?}");
                assert!(
                    (q[0] - p[0]).abs() < 0.05 && (q[1] - p[1]).abs() < 0.05,
                    "{p:?} -> {q:?}"
                );
                sum += q[2] as f64;
                n += 1;
            }
        }
        let mean = sum / n as f64;
        assert!(
            (mean - expect).abs() < 0.02,
            "mean plane {mean}, expected {expect}"
        );
    }

    #[test]
    fn edges_stay_sharp() {
        // Two faces of a box meeting at an edge along y (voxel 1): points two voxels or more from the edge lie
        // on their plane already and do not move; points next to it have a mixed neighbourhood and move at
        // most a third of a voxel (the edge is rounded that little, not pulled onto one face).
        let mut pts = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                pts.push([i as f32, j as f32, 0.0]);
                pts.push([0.0, j as f32, 1.0 + i as f32]);
            }
        }
        let w = vec![1; pts.len()];
        let idx = KdIndex::new(&pts);
        let (out, _) = project_to_weighted_planes(&pts, &w, &idx, 1.0, &SurfaceConfig::default());
        let mut worst_near = 0f32;
        for (p, q) in pts.iter().zip(&out) {
            let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
            if p[0].max(p[2]) >= 2.0 {
                assert!(d < 1e-4, "{p:?} moved to {q:?}");
            } else {
                worst_near = worst_near.max(d);
            }
        }
        assert!(worst_near < 0.34, "an edge point moved {worst_near} voxels");
    }

    #[test]
    fn a_cylinder_keeps_its_radius() {
        // A cylinder of radius 8 voxels about the z axis, sampled every ~0.5 voxel. Each neighbourhood (2
        // voxels) is nearly flat, so every point is moved: onto the chord (a plane) it sinks by about the
        // mean sagitta, r²/4 / (2R) ≈ 0.06 voxel; onto the fitted quadric it stays on the cylinder.
        let radius = 8.0f64;
        let mut pts = Vec::new();
        for i in 0..100 {
            let t = i as f64 * 0.5 / radius;
            for k in 0..40 {
                pts.push([
                    (radius * t.cos()) as f32,
                    (radius * t.sin()) as f32,
                    k as f32 * 0.5,
                ]);
            }
        }
        let w = vec![1; pts.len()];
        let idx = KdIndex::new(&pts);
        let mean_radial = |quadric: bool| {
            let cfg = SurfaceConfig {
                quadric,
                ..SurfaceConfig::default()
            };
            let (out, moved) = project_to_weighted_planes(&pts, &w, &idx, 1.0, &cfg);
            assert!(moved > pts.len() / 2, "{moved} of {} moved", pts.len());
            // Interior points only (full neighbourhoods).
            let (mut sum, mut n) = (0.0, 0);
            for (p, q) in pts.iter().zip(&out) {
                let t = (p[1] as f64).atan2(p[0] as f64) * radius;
                if (3.0..46.0).contains(&t) && (3.0..16.5).contains(&p[2]) {
                    sum += (q[0] as f64).hypot(q[1] as f64) - radius;
                    n += 1;
                }
            }
            sum / n as f64
        };
        let plane = mean_radial(false);
        let quadric = mean_radial(true);
        assert!(
            plane < -0.03,
            "the plane moved the points {plane} voxels outward"
        );
        assert!(
            quadric.abs() < 0.005,
            "the quadric moved the points {quadric} voxels"
        );
    }
}
