//! How much of the scene two sets of camera views share: a sparse, noise-free ray cast of every view, the
//! hit points binned into voxels, and for each set the fraction of its voxels that the other set also saw.
//!
//! The simulator uses it to place the views so that the shared fraction meets `SimConfig::overlap`, and
//! writes the achieved figures into `ground_truth.json`.

use super::camera::SimCamera;
use super::scene::Scene;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;
use std::collections::HashSet;

/// Settings of [`shared_fractions`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SharedConfig {
    /// Voxel edge, metres (default 0.01).
    pub voxel_m: f64,
    /// Rays per image row and column: every view is sampled on a `grid[0] x grid[1]` pixel grid (default
    /// 96 x 72).
    pub grid: [usize; 2],
}

impl Default for SharedConfig {
    fn default() -> Self {
        SharedConfig {
            voxel_m: 0.01,
            grid: [96, 72],
        }
    }
}

type Key = (i32, i32, i32);

/// The voxels (world frame) that the views see, by a sparse noise-free ray cast within the camera's range.
fn seen_voxels(
    scene: &Scene,
    cam: &SimCamera,
    views: &[Isometry3<f64>],
    cfg: &SharedConfig,
) -> HashSet<Key> {
    let intr = &cam.intrinsics;
    let [gu, gv] = cfg.grid;
    let rays: Vec<Vector3<f64>> = (0..gv)
        .flat_map(|j| (0..gu).map(move |i| (i, j)))
        .map(|(i, j)| {
            let u = (i as f64 + 0.5) * intr.width as f64 / gu as f64;
            let v = (j as f64 + 0.5) * intr.height as f64 / gv as f64;
            let [x, y] = intr.pixel_ray([u, v]);
            Vector3::new(x, y, 1.0)
        })
        .collect();
    let per_view: Vec<Vec<Key>> = views
        .par_iter()
        .map(|t| {
            let origin = Point3::from(t.translation.vector);
            rays.iter()
                .filter_map(|d| {
                    let hit = scene.cast_ray(&origin, &(t.rotation * d), cam.max_depth_m)?;
                    // `t` is the depth along the optical axis because the ray has z = 1 in the camera.
                    (hit.t >= cam.min_depth_m).then(|| {
                        let p = hit.point.coords / cfg.voxel_m;
                        (p.x.floor() as i32, p.y.floor() as i32, p.z.floor() as i32)
                    })
                })
                .collect()
        })
        .collect();
    per_view.into_iter().flatten().collect()
}

/// Fraction of `a`'s voxels with a voxel of `b` in their 3x3x3 neighbourhood.
fn fraction_near(a: &HashSet<Key>, b: &HashSet<Key>) -> f64 {
    if a.is_empty() {
        return 0.0;
    }
    let near = a
        .iter()
        .filter(|&&(x, y, z)| {
            (-1..=1).any(|dx| {
                (-1..=1).any(|dy| (-1..=1).any(|dz| b.contains(&(x + dx, y + dy, z + dz))))
            })
        })
        .count();
    near as f64 / a.len() as f64
}

/// For sets of camera poses (`T_world_cam`) of the same camera model, one set per robot: per set, the
/// fraction of the surface it sees (in voxels of `cfg.voxel_m`) that another set also sees within one voxel,
/// averaged over the other sets (each pair of robots is what a calibration registers). With two sets,
/// what each shares with the other. Deterministic.
pub fn shared_fractions(
    scene: &Scene,
    cam: &SimCamera,
    views: &[&[Isometry3<f64>]],
    cfg: &SharedConfig,
) -> Vec<f64> {
    let seen: Vec<HashSet<Key>> = views
        .iter()
        .map(|v| seen_voxels(scene, cam, v, cfg))
        .collect();
    let n = seen.len();
    (0..n)
        .map(|i| {
            let sum: f64 = (0..n)
                .filter(|&j| j != i)
                .map(|j| fraction_near(&seen[i], &seen[j]))
                .sum();
            sum / (n.max(2) - 1) as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::camera::Resolution;
    use crate::sim::scene::SceneConfig;
    use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion};

    fn looking_down(x: f64, y: f64, h: f64) -> Isometry3<f64> {
        // Camera z down (-world z), x along world x.
        let r = Rotation3::from_matrix_unchecked(Matrix3::new(
            1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0,
        ));
        Isometry3::from_parts(
            Translation3::new(x, y, h),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    #[test]
    fn same_views_share_everything_and_disjoint_views_nothing() {
        let scene = Scene::random(
            &SceneConfig {
                objects: 0,
                table_size_m: [4.0, 4.0, 0.04],
                ..SceneConfig::default()
            },
            1,
        )
        .unwrap();
        let cam = SimCamera::d435(Resolution::Vga);
        let cfg = SharedConfig::default();
        let a = [looking_down(-1.0, 0.0, 0.5)];
        let s = shared_fractions(&scene, &cam, &[&a, &a], &cfg);
        assert_eq!(s, [1.0, 1.0]);
        // Footprint at 0.5 m: about 0.84 m x 0.63 m; 1.5 m apart: disjoint.
        let b = [looking_down(0.5, 0.0, 0.5)];
        let s = shared_fractions(&scene, &cam, &[&a, &b], &cfg);
        assert_eq!(s, [0.0, 0.0]);
        // Half a footprint apart along x: about half shared.
        let c = [looking_down(-1.0 + 0.42, 0.0, 0.5)];
        let s = shared_fractions(&scene, &cam, &[&a, &c], &cfg);
        for f in &s {
            assert!((f - 0.5).abs() < 0.06, "{s:?}");
        }
        // Three robots: each the mean over the other two. `b` shares nothing with `a` or `c`.
        let s = shared_fractions(&scene, &cam, &[&a, &b, &c], &cfg);
        assert_eq!(s.len(), 3);
        assert!((s[0] - 0.25).abs() < 0.04, "{s:?}");
        assert_eq!(s[1], 0.0, "{s:?}");
        assert!((s[2] - 0.25).abs() < 0.04, "{s:?}");
    }
}
