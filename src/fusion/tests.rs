use super::*;
use crate::camera::Intrinsics;
use nalgebra::{Point3, Vector3};

/// A synthetic scene for tests: the plane z = 0 and a sphere, in the base frame (metres).
pub(crate) struct Scene {
    pub sphere_c: Vector3<f64>,
    pub sphere_r: f64,
}

impl Scene {
    pub fn new() -> Self {
        Scene {
            sphere_c: Vector3::new(0.05, -0.03, 0.12),
            sphere_r: 0.1,
        }
    }

    /// Renders the raw depth image of a camera at `t_base_cam`.
    pub fn render(&self, intr: &Intrinsics, t_base_cam: &Isometry3<f64>) -> DepthImage {
        let mut img = DepthImage::zeros(intr.width, intr.height);
        let c = t_base_cam.translation.vector;
        for v in 0..intr.height {
            for u in 0..intr.width {
                let [x, y] = intr.pixel_ray([u as f64, v as f64]);
                let d = t_base_cam.rotation * Vector3::new(x, y, 1.0);
                let mut best = f64::INFINITY;
                if d.z.abs() > 1e-12 {
                    let t = -c.z / d.z;
                    if t > 0.0 {
                        best = t;
                    }
                }
                let oc = c - self.sphere_c;
                let (a, b, cc) = (
                    d.dot(&d),
                    2.0 * oc.dot(&d),
                    oc.dot(&oc) - self.sphere_r * self.sphere_r,
                );
                let disc = b * b - 4.0 * a * cc;
                if disc > 0.0 {
                    let t = (-b - disc.sqrt()) / (2.0 * a);
                    if t > 0.0 && t < best {
                        best = t;
                    }
                }
                if best.is_finite() {
                    let raw = (best / intr.depth_scale).round();
                    if raw > 0.0 && raw < 65535.0 {
                        img.data[(v * intr.width + u) as usize] = raw as u16;
                    }
                }
            }
        }
        img
    }

    /// Distance of `p` from the scene surface.
    pub fn distance(&self, p: &[f32; 3]) -> f64 {
        let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let plane = q.z.abs();
        let sphere = ((q - self.sphere_c).norm() - self.sphere_r).abs();
        plane.min(sphere)
    }
}

pub(crate) fn test_camera() -> Intrinsics {
    let mut i = Intrinsics::pinhole(160, 120, 140.0, 141.0, 79.3, 60.1);
    i.depth_scale = 0.0001;
    i
}

/// Cameras on a ring 0.6 m above the plane looking at the sphere.
pub(crate) fn ring_poses(n: usize) -> Vec<Isometry3<f64>> {
    (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            let eye = Point3::new(0.35 * a.cos(), 0.35 * a.sin(), 0.6);
            Isometry3::face_towards(&eye, &Point3::new(0.0, 0.0, 0.05), &Vector3::z())
        })
        .collect()
}

fn fuse_scene(cfg: &FuseConfig) -> (FusedCloud, Scene) {
    let scene = Scene::new();
    let intr = test_camera();
    let poses = ring_poses(6);
    let imgs: Vec<DepthImage> = poses.iter().map(|t| scene.render(&intr, t)).collect();
    let frames: Vec<FrameInput> = imgs
        .iter()
        .zip(&poses)
        .map(|(d, t)| FrameInput {
            depth: d,
            t_base_cam: *t,
        })
        .collect();
    (fuse_frames(&frames, &intr, cfg).unwrap(), scene)
}

#[test]
fn fused_points_lie_on_the_surface_with_outward_normals() {
    let cfg = FuseConfig {
        voxel_size_m: Some(0.004),
        ..Default::default()
    };
    let (f, scene) = fuse_scene(&cfg);
    let n = f.cloud.len();
    assert!(n > 2000, "{n}");
    assert_eq!(f.counts.len(), n);
    let worst = f
        .cloud
        .points
        .iter()
        .map(|p| scene.distance(p))
        .fold(0.0, f64::max);
    assert!(worst < 0.0005, "worst distance from the surface {worst} m");
    let normals = f.cloud.normals.as_ref().unwrap();
    let mut wrong = 0;
    for (p, nrm) in f.cloud.points.iter().zip(normals) {
        let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        let expect = if q.z.abs() < 0.0005 && (q - scene.sphere_c).norm() > scene.sphere_r + 0.003 {
            Vector3::z()
        } else if ((q - scene.sphere_c).norm() - scene.sphere_r).abs() < 0.0005 && q.z > 0.01 {
            (q - scene.sphere_c).normalize()
        } else {
            continue;
        };
        let d = Vector3::new(nrm[0] as f64, nrm[1] as f64, nrm[2] as f64).dot(&expect);
        if d < 0.9 {
            wrong += 1;
        }
    }
    assert!(
        wrong * 100 < n,
        "{wrong} of {n} normals do not face the cameras"
    );
    // Every sample went into some voxel.
    let total: u64 = f.counts.iter().map(|&c| c as u64).sum();
    assert!(total <= f.stats.points_in as u64);
    assert_eq!(f.stats.frames, 6);
}

#[test]
fn output_is_identical_at_any_thread_count_and_sorted() {
    let cfg = FuseConfig {
        voxel_size_m: Some(0.003),
        ..Default::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| fuse_scene(&cfg).0)
    };
    let a = run(1);
    let b = run(3);
    assert_eq!(a.cloud, b.cloud);
    assert_eq!(a.counts, b.counts);
    assert_eq!(a.viewpoints, b.viewpoints);
    // Sorted by voxel key (x index first): x never drops by more than one voxel between neighbours, and
    // over the whole cloud it rises.
    let v = 0.003f32;
    assert!(a
        .cloud
        .points
        .windows(2)
        .all(|w| w[0][0] - w[1][0] < v + 1e-5));
    assert!(a.cloud.points[0][0] < a.cloud.points[a.cloud.len() - 1][0]);
}

#[test]
fn crop_box_and_min_count() {
    let crop = CropBox {
        min: [-1.0, -1.0, 0.005],
        max: [1.0, 1.0, 1.0],
    };
    let cfg = FuseConfig {
        voxel_size_m: Some(0.004),
        crop: Some(crop),
        outlier: None,
        ..Default::default()
    };
    let (f, scene) = fuse_scene(&cfg);
    assert!(f.stats.points_cropped > 0);
    assert!(f.cloud.points.iter().all(|p| p[2] >= 0.005));
    assert!(f
        .cloud
        .points
        .iter()
        .all(
            |p| ((Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - scene.sphere_c).norm()
                - scene.sphere_r)
                .abs()
                < 0.0005
        ));
    let strict = FuseConfig {
        min_points_per_voxel: 5,
        ..cfg.clone()
    };
    let (g, _) = fuse_scene(&strict);
    assert!(g.stats.sparse_removed > 0 && g.counts.iter().all(|&c| c >= 5));
    let bad = FuseConfig {
        crop: Some(CropBox {
            min: [0.0; 3],
            max: [0.0, 1.0, 1.0],
        }),
        ..cfg
    };
    assert!(bad.validate().is_err());
}

#[test]
fn auto_voxel_follows_the_pixel_footprint() {
    let intr = test_camera();
    let scene = Scene::new();
    let img = scene.render(&intr, &ring_poses(1)[0]);
    let v = auto_voxel_size(&img, &intr, &DeprojectConfig::default(), 2.0).unwrap();
    // Depths are ~0.5-0.75 m, focal ~140 px: footprint ~4-5 mm, voxel ~8-11 mm.
    assert!((0.006..0.012).contains(&v), "{v}");
    assert!(auto_voxel_size(
        &DepthImage::zeros(160, 120),
        &intr,
        &DeprojectConfig::default(),
        2.0
    )
    .is_none());
}

#[test]
fn the_automatic_voxel_is_bounded_by_its_largest_edge() {
    let cfg = FuseConfig {
        outlier: None,
        normals: None,
        surface: None,
        ..Default::default()
    };
    let (free, _) = fuse_scene(&cfg);
    let auto = free.stats.voxel_size_m;
    // A bound above the automatic voxel changes nothing; one below it is the voxel used.
    let (above, _) = fuse_scene(&FuseConfig {
        max_auto_voxel_m: Some(2.0 * auto),
        ..cfg.clone()
    });
    assert_eq!(above.stats.voxel_size_m, auto);
    assert_eq!(above.cloud.points, free.cloud.points);
    let (below, scene) = fuse_scene(&FuseConfig {
        max_auto_voxel_m: Some(0.5 * auto),
        ..cfg.clone()
    });
    assert_eq!(below.stats.voxel_size_m, 0.5 * auto);
    assert!(below.cloud.len() > 2 * free.cloud.len());
    assert!(below
        .cloud
        .points
        .iter()
        .all(|p| scene.distance(p) < 0.0015));
    // A voxel given outright is not bounded.
    let (given, _) = fuse_scene(&FuseConfig {
        voxel_size_m: Some(auto),
        max_auto_voxel_m: Some(0.5 * auto),
        ..cfg.clone()
    });
    assert_eq!(given.stats.voxel_size_m, auto);
    for bad in [0.0, -0.01, f64::INFINITY, f64::NAN] {
        let e = FuseConfig {
            max_auto_voxel_m: Some(bad),
            ..cfg.clone()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("fuse.max_auto_voxel_m"), "{e}");
    }
}

#[test]
fn the_range_cut_keeps_what_lies_within_the_sample_weighted_median() {
    // Oracle: every sample spelled out, sorted, the lower median.
    let mut rng = crate::geometry::Rng::new(7);
    for n in [1usize, 2, 7, 300] {
        let points: Vec<[f32; 3]> = (0..n)
            .map(|_| std::array::from_fn(|_| rng.uniform(-3.0, 3.0) as f32))
            .collect();
        let viewpoints: Vec<[f32; 3]> = (0..n)
            .map(|_| std::array::from_fn(|_| rng.uniform(-0.5, 0.5) as f32))
            .collect();
        let counts: Vec<u32> = (0..n).map(|_| rng.uniform(1.0, 40.0) as u32).collect();
        let range = |i: usize| {
            let d: [f32; 3] = std::array::from_fn(|k| viewpoints[i][k] - points[i][k]);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        };
        let mut samples: Vec<f32> = (0..n)
            .flat_map(|i| std::iter::repeat_n(range(i), counts[i] as usize))
            .collect();
        samples.sort_by(f32::total_cmp);
        let median = samples[samples.len().div_ceil(2) - 1];
        for factor in [0.5, 1.0, 2.5] {
            let limit = (factor * median as f64) as f32;
            let want: Vec<usize> = (0..n).filter(|&i| range(i) <= limit).collect();
            assert_eq!(
                within_median_range(&points, &viewpoints, &counts, factor),
                want,
                "{n} points, factor {factor}"
            );
        }
    }
    // Without one viewpoint or count per point nothing is cut.
    assert_eq!(
        within_median_range(&[[1.0; 3]; 3], &[[0.0; 3]; 2], &[1; 3], 0.1),
        vec![0, 1, 2]
    );
}

#[test]
fn the_range_cut_is_made_in_the_fusion() {
    let cfg = FuseConfig {
        outlier: None,
        normals: None,
        ..Default::default()
    };
    let (all, _) = fuse_scene(&cfg);
    assert_eq!(all.stats.range_cut, 0);
    let ranges = all.ranges();
    let (near, scene) = fuse_scene(&FuseConfig {
        max_range_factor: Some(1.0),
        ..cfg.clone()
    });
    // About half the samples lie beyond the median range; the far voxels are the sparse ones.
    assert!(near.stats.range_cut > 0);
    assert!(near.cloud.len() < all.cloud.len());
    // Every point kept lies within the median range of the samples, up to what the surface fit moves a
    // point (a few millimetres here).
    let mut samples: Vec<f32> = ranges
        .iter()
        .zip(&all.counts)
        .flat_map(|(&r, &c)| std::iter::repeat_n(r, c as usize))
        .collect();
    samples.sort_by(f32::total_cmp);
    let median = samples[samples.len().div_ceil(2) - 1];
    let farthest = near.ranges().into_iter().fold(0.0, f32::max);
    assert!(farthest <= median + 0.005, "{farthest} > {median}");
    assert!(farthest > 0.9 * median, "{farthest} against {median}");
    // What is kept is fused as before: on the scene's surface.
    assert!(near.cloud.points.iter().all(|p| scene.distance(p) < 0.0015));
    for bad in [0.0, -1.0, f64::NAN] {
        let e = FuseConfig {
            max_range_factor: Some(bad),
            ..cfg.clone()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("fuse.max_range_factor"), "{e}");
    }
}
