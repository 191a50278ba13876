//! The depth simulator: ray-cast depth against analytic geometry, deprojection onto the true surfaces, the
//! noise statistics, byte-identical datasets per seed (and thread count), and that a written cell opens,
//! fuses, and lines up under the true `T_base1_base2`.

mod common;
#[allow(unused_imports)]
use common::scratch as tmpdir;
use depthcal::camera::{deproject, DeprojectConfig, RayTable};
use depthcal::cell::{Cell, GroundTruth};
use depthcal::fusion::{fuse_robot, CropBox, FuseConfig, FusedCloud};
use depthcal::geometry::transform::pose_error;
use depthcal::index::KdIndex;
use depthcal::sim::{
    render_frame, Appearance, NoiseConfig, NoiseLevel, ObjectKind, ObjectShape, Resolution, Scene,
    SceneConfig, SceneObject, SimCamera, SimCell, SimConfig,
};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

fn plain() -> Appearance {
    Appearance {
        albedo: [[0.8, 0.2, 0.2], [0.2, 0.2, 0.8]],
        checker_m: 0.02,
        pattern_seed: 1,
        texture: false,
    }
}

/// A camera at `pos` looking at `target` (image x horizontal).
fn look_at(pos: Vector3<f64>, target: Vector3<f64>) -> Isometry3<f64> {
    let z = (target - pos).normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let r = nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[x, y, z]));
    Isometry3::from_parts(
        Translation3::from(pos),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

/// Entry parameter of a ray into an axis-aligned box, by slabs.
fn slab(o: &Vector3<f64>, d: &Vector3<f64>, lo: [f64; 3], hi: [f64; 3]) -> Option<f64> {
    let (mut tn, mut tf) = (f64::NEG_INFINITY, f64::INFINITY);
    for k in 0..3 {
        let (t1, t2) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
        tn = tn.max(t1.min(t2));
        tf = tf.min(t1.max(t2));
    }
    (tn <= tf && tn > 0.0).then_some(tn)
}

/// First hit of a ray with: the table (`[±x/2] × [±y/2] × [-0.04, 0]`), an axis-aligned box
/// `[bx0, bx1] × [by0, by1] × [0, bh]` and a sphere; computed independently of the simulator.
fn analytic_t(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    table: [f64; 2],
    bx: [f64; 5],
    sc: Vector3<f64>,
    r: f64,
) -> Option<f64> {
    let mut best = f64::INFINITY;
    let (tx, ty) = (table[0] / 2.0, table[1] / 2.0);
    if let Some(t) = slab(o, d, [-tx, -ty, -0.04], [tx, ty, 0.0]) {
        best = best.min(t);
    }
    if let Some(t) = slab(o, d, [bx[0], bx[2], 0.0], [bx[1], bx[3], bx[4]]) {
        best = best.min(t);
    }
    let oc = o - sc;
    let (b, c) = (oc.dot(d), oc.dot(&oc) - r * r);
    let disc = b * b - c;
    if disc >= 0.0 {
        let t = -b - disc.sqrt();
        if t > 0.0 {
            best = best.min(t);
        }
    }
    best.is_finite().then_some(best)
}

#[test]
fn ray_cast_depth_matches_analytic_geometry() {
    let table = [1.0, 0.8];
    let bx = [-0.15, -0.05, -0.1, 0.02, 0.07]; // x0, x1, y0, y1, height
    let sc = Vector3::new(0.1, 0.05, 0.06);
    let r = 0.06;
    let objects = vec![
        SceneObject {
            shape: ObjectShape::Box {
                size_m: [bx[1] - bx[0], bx[3] - bx[2], bx[4]],
            },
            t_world_object: Isometry3::translation(
                (bx[0] + bx[1]) / 2.0,
                (bx[2] + bx[3]) / 2.0,
                bx[4] / 2.0,
            ),
            appearance: plain(),
        },
        SceneObject {
            shape: ObjectShape::Sphere { radius_m: r },
            t_world_object: Isometry3::translation(sc.x, sc.y, sc.z),
            appearance: plain(),
        },
    ];
    let scene = Scene::new([table[0], table[1], 0.04], None, objects, plain()).unwrap();
    let cam = SimCamera::d435(Resolution::Vga);
    let intr = &cam.intrinsics;
    for (view, t_world_cam) in [
        look_at(Vector3::new(0.0, 0.0, 0.6), Vector3::new(0.001, 0.0, 0.0)),
        look_at(Vector3::new(-0.4, -0.5, 0.45), Vector3::new(0.0, 0.0, 0.03)),
    ]
    .iter()
    .enumerate()
    {
        let f = render_frame(&scene, &cam, t_world_cam, &NoiseConfig::none(), 1, false).unwrap();
        let o = t_world_cam.translation.vector;
        let (mut compared, mut bad, mut worst) = (0usize, 0usize, 0.0f64);
        for v in 0..intr.height as usize {
            for u in 0..intr.width as usize {
                let [x, y] = intr.pixel_ray([u as f64, v as f64]);
                let d_cam = Vector3::new(x, y, 1.0).normalize();
                let d = t_world_cam.rotation * d_cam;
                let truth = analytic_t(&o, &d, table, bx, sc, r).map(|t| t * d_cam.z);
                let got = f.ideal_z_m[v * intr.width as usize + u] as f64;
                match truth {
                    Some(z) if got > 0.0 => {
                        compared += 1;
                        let e = (got - z).abs();
                        // Rays through a silhouette edge may land on either side.
                        if e > 1e-4 {
                            bad += 1;
                        } else {
                            worst = worst.max(e);
                        }
                        // The quantised depth is the nearest millimetre.
                        let raw = f.depth.data[v * intr.width as usize + u] as f64 * 0.001;
                        assert!((raw - got).abs() <= 0.0005 + 1e-6 || raw == 0.0);
                    }
                    Some(_) | None => {
                        if got > 0.0 && truth.is_none() {
                            bad += 1;
                        }
                    }
                }
            }
        }
        println!(
            "view {view}: {compared} pixels compared, worst {:.2e} m, {bad} differ",
            worst
        );
        assert!(compared > 100_000, "{compared}");
        assert!(worst < 1e-4, "worst {worst}");
        assert!(bad * 1000 < compared, "{bad} of {compared} pixels disagree");
    }
}

/// Unsigned distance from a point (object frame) to the surface of a primitive, metres.
fn surface_distance(shape: &ObjectShape, p: &Point3<f64>) -> f64 {
    let seg = |q: [f64; 2], a: [f64; 2], b: [f64; 2]| {
        let (abx, aby) = (b[0] - a[0], b[1] - a[1]);
        let t =
            (((q[0] - a[0]) * abx + (q[1] - a[1]) * aby) / (abx * abx + aby * aby)).clamp(0.0, 1.0);
        (q[0] - a[0] - t * abx).hypot(q[1] - a[1] - t * aby)
    };
    match shape {
        ObjectShape::Box { size_m } => {
            let h = Vector3::new(size_m[0] / 2.0, size_m[1] / 2.0, size_m[2] / 2.0);
            let q = p.coords.abs() - h;
            let outside = q.map(|c| c.max(0.0)).norm();
            let inside = q.x.max(q.y).max(q.z).min(0.0);
            (outside + inside).abs()
        }
        ObjectShape::Sphere { radius_m } => (p.coords.norm() - radius_m).abs(),
        ObjectShape::Cylinder { radius_m, height_m } => {
            let (r, hh) = (*radius_m, height_m / 2.0);
            let q = [p.x.hypot(p.y), p.z];
            seg(q, [r, -hh], [r, hh])
                .min(seg(q, [0.0, hh], [r, hh]))
                .min(seg(q, [0.0, -hh], [r, -hh]))
        }
        ObjectShape::Cone { radius_m, height_m } => {
            let (r, hh) = (*radius_m, height_m / 2.0);
            let q = [p.x.hypot(p.y), p.z];
            seg(q, [0.0, hh], [r, -hh]).min(seg(q, [0.0, -hh], [r, -hh]))
        }
        ObjectShape::Mesh { .. } => f64::INFINITY,
    }
}

#[test]
fn noise_free_frames_deproject_onto_the_true_surfaces() {
    let cfg = SimConfig {
        seed: 21,
        frames: 4,
        noise_level: NoiseLevel::None,
        depth_scale: 0.0001,
        color: false,
        scene: SceneConfig {
            kinds: vec![
                ObjectKind::Box,
                ObjectKind::Cylinder,
                ObjectKind::Sphere,
                ObjectKind::Cone,
            ],
            ..Default::default()
        },
        ..Default::default()
    };
    let cell = SimCell::generate(&cfg).unwrap();
    let table = cell.scene.table_size_m;
    let inv: Vec<Isometry3<f64>> = cell
        .scene
        .objects
        .iter()
        .map(|o| o.t_world_object.inverse())
        .collect();
    let dcfg = DeprojectConfig {
        max_depth_jump: 0.0,
        ..Default::default()
    };
    let mut all = Vec::new();
    for (ri, robot) in cell.robots.iter().enumerate() {
        let rays = RayTable::new(&robot.camera.intrinsics);
        for k in 0..cfg.frames {
            let f = cell.render(ri, k).unwrap();
            let pts = deproject(&f.depth, &rays, &dcfg).unwrap();
            assert!(pts.len() > 100_000, "{}", pts.len());
            let t = robot.t_world_base * robot.t_base_cam(k);
            for p in &pts {
                let w = t * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                // The table box: top face z = 0.
                let tq = Vector3::new(
                    w.x.abs() - table[0] / 2.0,
                    w.y.abs() - table[1] / 2.0,
                    (w.z + table[2] / 2.0).abs() - table[2] / 2.0,
                );
                let mut d =
                    (tq.map(|c| c.max(0.0)).norm() + tq.x.max(tq.y).max(tq.z).min(0.0)).abs();
                for (o, iv) in cell.scene.objects.iter().zip(&inv) {
                    d = d.min(surface_distance(&o.shape, &(iv * w)));
                }
                all.push(d);
            }
        }
    }
    all.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| all[((all.len() - 1) as f64 * f) as usize];
    println!(
        "{} points: median {:.4} mm, 99.9% {:.4} mm, max {:.4} mm",
        all.len(),
        q(0.5) * 1e3,
        q(0.999) * 1e3,
        q(1.0) * 1e3
    );
    assert!(q(1.0) < 0.0005, "max distance {} m", q(1.0));
}

#[test]
fn default_noise_has_the_configured_axial_sigma() {
    let scene = Scene::random(
        &SceneConfig {
            objects: 0,
            ..Default::default()
        },
        3,
    )
    .unwrap();
    let cam = SimCamera::d435(Resolution::Vga);
    let noise = NoiseConfig::default();
    for z in [0.5, 1.0] {
        let t = look_at(Vector3::new(0.0, 0.0, z), Vector3::new(0.0005, 0.0, 0.0));
        let f = render_frame(&scene, &cam, &t, &noise, 7, false).unwrap();
        let mut errs = Vec::new();
        for (raw, ideal) in f.depth.data.iter().zip(&f.ideal_z_m) {
            if *raw != 0 && *ideal > 0.0 {
                errs.push(*raw as f64 * 0.001 - *ideal as f64);
            }
        }
        let n = errs.len() as f64;
        let mean = errs.iter().sum::<f64>() / n;
        let sd = (errs.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
        // Quantisation to 1 mm adds a uniform error of variance q²/12.
        let sigma = noise.axial_sigma(z);
        let expect = (sigma * sigma + 1e-6 / 12.0).sqrt();
        let hits = f.ideal_z_m.iter().filter(|&&z| z > 0.0).count();
        let valid = errs.len() as f64 / hits as f64;
        println!(
            "z = {z} m: σ measured {:.3} mm, expected {:.3} mm (model σ {:.3} mm + quantisation), mean {:.3} mm, {:.1}% of the hits valid",
            sd * 1e3,
            expect * 1e3,
            sigma * 1e3,
            mean * 1e3,
            valid * 100.0
        );
        assert!((sd / expect - 1.0).abs() < 0.2, "σ {sd} vs {expect}");
        assert!(mean.abs() < 0.2 * sigma);
        assert!(valid > 0.85 && valid < 0.999, "{valid}");
    }
}

fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    common::listing(dir)
        .into_iter()
        .map(|(p, bytes)| {
            let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
            (rel, bytes)
        })
        .collect()
}

#[test]
fn same_seed_same_bytes_at_any_thread_count() {
    let cfg = SimConfig {
        seed: 5,
        frames: 3,
        ..Default::default()
    };
    let write = |dir: &Path, cfg: &SimConfig, threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| SimCell::generate(cfg).unwrap().write(dir, &|_| {}).unwrap())
    };
    let (a, b, c) = (tmpdir("same-a"), tmpdir("same-b"), tmpdir("same-c"));
    let stats = write(&a, &cfg, 1);
    write(&b, &cfg, 2);
    write(
        &c,
        &SimConfig {
            seed: 6,
            ..cfg.clone()
        },
        2,
    );
    let (fa, fb, fc) = (files(&a), files(&b), files(&c));
    assert_eq!(fa.len(), stats.files);
    assert_eq!(fa.len(), 2 + 2 * 2 + 2 * 3 * 2, "{:?}", fa.keys());
    assert_eq!(fa.keys().collect::<Vec<_>>(), fb.keys().collect::<Vec<_>>());
    for (k, v) in &fa {
        assert!(
            v == &fb[k],
            "{k} differs between two runs with the same seed"
        );
    }
    let differing = fa.iter().filter(|(k, v)| fc.get(*k) != Some(*v)).count();
    assert!(
        differing >= fa.len() - 4,
        "only {differing} files differ for another seed"
    );
    for d in [a, b, c] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// Point-to-plane distances of `query` to `reference` (with normals) for pairs within `max_dist`:
/// (median, inlier fraction).
fn point_to_plane(reference: &FusedCloud, query: &[[f32; 3]], max_dist: f32) -> (f64, f64) {
    let index = KdIndex::new(&reference.cloud.points);
    let normals = reference.cloud.normals.as_ref().unwrap();
    let mut r: Vec<f64> = query
        .iter()
        .filter_map(|q| {
            let (i, d2) = index.nearest(q)?;
            (d2 <= max_dist * max_dist).then(|| {
                let (p, n) = (reference.cloud.points[i], normals[i]);
                (0..3)
                    .map(|k| n[k] as f64 * (q[k] - p[k]) as f64)
                    .sum::<f64>()
                    .abs()
            })
        })
        .collect();
    let frac = r.len() as f64 / query.len() as f64;
    r.sort_by(|a, b| a.total_cmp(b));
    (r[r.len() / 2], frac)
}

#[test]
fn written_cell_opens_fuses_and_lines_up_under_the_truth() {
    for (noise, overlap, bound_mm) in [
        (NoiseLevel::None, 0.7, 0.5),
        (NoiseLevel::Default, 0.7, 1.5),
        (NoiseLevel::Default, 0.3, 1.5),
    ] {
        let cfg = SimConfig {
            seed: 8,
            frames: 12,
            noise_level: noise,
            overlap,
            color: false,
            ..Default::default()
        };
        let dir = tmpdir(&format!("fuse-{:?}-{overlap}", noise));
        let cell_sim = SimCell::generate(&cfg).unwrap();
        cell_sim.write(&dir, &|_| {}).unwrap();
        let cell = Cell::open(&dir).unwrap();
        assert_eq!(cell.robots.len(), 2);
        assert_eq!(cell.manifest.reference, "left");
        let priors = cell.manifest.extra["priors"].as_table().unwrap();
        assert_eq!(priors["bases_level"].as_bool(), Some(true));
        let ws: Vec<f64> = priors["workspace"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_float().unwrap())
            .collect();
        let truth: GroundTruth = cell.ground_truth().unwrap().unwrap();
        let t = truth.t_base1_base2.unwrap();
        let (rot, tr) = pose_error(&t, &cell_sim.t_base1_base2());
        assert!(rot < 1e-9 && tr < 1e-12);
        let dist = priors["base_distance_m"].as_float().unwrap();
        assert!((dist - t.translation.vector.norm()).abs() <= 0.05 + 1e-9);
        // Hand-eyes and poses read back as simulated.
        for (r, s) in cell.robots.iter().zip(&cell_sim.robots) {
            assert_eq!(r.t_ee_cam, s.t_ee_cam);
            assert_eq!(r.frames.len(), cfg.frames);
            for (f, p) in r.frames.iter().zip(&s.poses) {
                assert_eq!(f.t_base_ee, p.pose);
            }
        }
        let fuse_cfg = FuseConfig {
            crop: Some(CropBox {
                min: [ws[0], ws[1], ws[2]],
                max: [ws[3], ws[4], ws[5]],
            }),
            ..Default::default()
        };
        let f1 = fuse_robot(&cell.robots[0], &fuse_cfg, &|_| {}).unwrap();
        // Robot 2's cloud is cropped in its own base frame by the same box mapped there (its AABB).
        let t21 = t.inverse();
        let mut lo = [f64::MAX; 3];
        let mut hi = [f64::MIN; 3];
        for c in 0..8 {
            let p = t21
                * Point3::new(
                    if c & 1 == 0 { ws[0] } else { ws[3] },
                    if c & 2 == 0 { ws[1] } else { ws[4] },
                    if c & 4 == 0 { ws[2] } else { ws[5] },
                );
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let f2 = fuse_robot(
            &cell.robots[1],
            &FuseConfig {
                crop: Some(CropBox { min: lo, max: hi }),
                ..Default::default()
            },
            &|_| {},
        )
        .unwrap();
        let moved: Vec<[f32; 3]> = f2
            .cloud
            .points
            .iter()
            .map(|p| depthcal::geometry::cloud::transform_point(&t, p))
            .collect();
        let voxel = f1.stats.voxel_size_m as f32;
        let (median, frac) = point_to_plane(&f1, &moved, 2.0 * voxel);
        println!(
            "noise {noise:?}, overlap {overlap}: {} + {} points, voxel {:.1} mm, robot 2 within 2 voxels of robot 1: {:.0}%, median point-to-plane {:.3} mm",
            f1.cloud.len(),
            f2.cloud.len(),
            voxel * 1e3,
            frac * 100.0,
            median * 1e3
        );
        assert!(median * 1e3 < bound_mm, "median {median}");
        assert!(frac > 0.2, "{frac}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}

#[test]
fn cli_writes_a_cell_and_refuses_a_non_empty_directory() {
    let dir = tmpdir("cli");
    let exe = env!("CARGO_BIN_EXE_depthcal");
    let out = std::process::Command::new(exe)
        .args(["simulate"])
        .arg(&dir)
        .args([
            "--seed",
            "4",
            "--frames",
            "2",
            "--noise",
            "low",
            "--objects",
            "5",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["schema"], "depthcal.simulation/1");
    common::assert_documented(&v);
    assert_eq!(v["frames_per_robot"], 2);
    assert_eq!(v["objects"], 5);
    assert!(Cell::open(&dir).is_ok());
    // The truth is a pose object, the one of ground_truth.json.
    let truth = GroundTruth::read(&dir)
        .unwrap()
        .unwrap()
        .t_base1_base2
        .unwrap();
    let m = &v["T_base1_base2"]["matrix"];
    for (r, c) in (0..3).flat_map(|r| (0..4).map(move |c| (r, c))) {
        let want = truth.to_homogeneous()[(r, c)];
        assert!((m[r][c].as_f64().unwrap() - want).abs() < 1e-12, "{m}");
    }
    let xyz: Vec<f64> = v["T_base1_base2"]["xyz_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let dist = v["base_distance_m"].as_f64().unwrap();
    assert!((xyz.iter().map(|x| x * x).sum::<f64>().sqrt() - dist).abs() < 1e-12);
    let again = std::process::Command::new(exe)
        .args(["simulate"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(!again.status.success());
    let msg = String::from_utf8_lossy(&again.stderr);
    assert!(
        msg.contains("not empty") && msg.contains("--force"),
        "{msg}"
    );
    let forced = std::process::Command::new(exe)
        .args(["simulate"])
        .arg(&dir)
        .args(["--frames", "2", "--force", "--no-color"])
        .output()
        .unwrap();
    assert!(
        forced.status.success(),
        "{}",
        String::from_utf8_lossy(&forced.stderr)
    );
    let bad = std::process::Command::new(exe)
        .args(["simulate"])
        .arg(dir.join("x"))
        .args(["--noise", "loud"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn overlap_setting_sets_the_shared_fraction_of_the_scene() {
    // `overlap` is what both robots see, measured on the rendered frames; several seeds and levels.
    let mut last = 0.0;
    for (seed, overlap) in [(11u64, 0.3), (12, 0.5), (13, 0.7)] {
        let mut cfg = SimConfig {
            seed,
            frames: 12,
            overlap,
            ..SimConfig::default()
        };
        cfg.color = false;
        let cell = SimCell::generate(&cfg).unwrap();
        let mean = 0.5 * (cell.shared[0] + cell.shared[1]);
        eprintln!(
            "overlap {overlap}: shared {:.3} / {:.3}, view spread {:.3}",
            cell.shared[0], cell.shared[1], cell.view_spread
        );
        assert!(
            (mean - overlap).abs() < 0.08,
            "asked {overlap}, shared {:?}",
            cell.shared
        );
        assert!(mean > last, "the shared fraction grows with the setting");
        last = mean;
    }
}

#[test]
fn markers_print_their_codes_in_the_colour_image_and_texture_leaves_depth_alone() {
    use depthcal::sim::{marker_code, SimMarkersConfig};
    let base = SimConfig {
        seed: 5,
        frames: 4,
        overlap: 1.0,
        noise_level: NoiseLevel::None,
        ..Default::default()
    };
    let mut cfg = base.clone();
    cfg.scene.markers = Some(SimMarkersConfig {
        ids: vec![3, 9],
        ..Default::default()
    });
    cfg.scene.textured = true;
    let cell = SimCell::generate(&cfg).unwrap();
    let markers = cell.scene.markers.as_ref().unwrap();
    let gt = cell.ground_truth();
    let list = gt.extra["markers"]["markers"].as_array().unwrap();
    assert_eq!(list.len(), 2);
    assert_eq!(gt.extra["markers"]["dictionary"], "DICT_4X4_50");
    assert_eq!(
        cell.manifest().extra["markers"]["size_m"].as_float(),
        Some(0.08)
    );
    // In every frame, the centre of each visible code cell has the code's colour and the border is black.
    let mut checked = 0;
    for k in 0..cfg.frames {
        let f = cell.render(0, k).unwrap();
        let rgb = f.color.as_ref().unwrap();
        let t_cam_world = cell.robots[0].t_world_cam(k).inverse();
        let intr = &cell.robots[0].camera.intrinsics;
        for m in &markers.markers {
            let (n, code) = marker_code("4x4_50", m.id).unwrap();
            let cell_m = 0.08 / (n + 2) as f64;
            for r in 0..n + 2 {
                for c in 0..n + 2 {
                    let x = -0.04 + (c as f64 + 0.5) * cell_m;
                    let y = 0.04 - (r as f64 + 0.5) * cell_m;
                    let p = t_cam_world * m.t_world_marker * Point3::new(x, y, 0.0);
                    if p.z <= 0.0 {
                        continue;
                    }
                    let [u, v] = intr.project([p.x, p.y, p.z]);
                    // Cells under 6 pixels across mix with their neighbours through the blur.
                    let q = t_cam_world * m.t_world_marker * Point3::new(x + cell_m, y, 0.0);
                    let [u2, v2] = intr.project([q.x, q.y, q.z]);
                    if (u2 - u).hypot(v2 - v) < 6.0 {
                        continue;
                    }
                    let (u, v) = (u.round() as i64, v.round() as i64);
                    if u < 0 || v < 0 || u >= intr.width as i64 || v >= intr.height as i64 {
                        continue;
                    }
                    let idx = (v as usize * intr.width as usize + u as usize) * 3;
                    // Only where the cell is seen (not behind an object): the depth there is the table's.
                    let z = f.ideal_z_m[v as usize * intr.width as usize + u as usize] as f64;
                    if (z - p.z).abs() > 0.002 {
                        continue;
                    }
                    let border = r == 0 || c == 0 || r == n + 1 || c == n + 1;
                    let white = !border && (code >> (n * n - 1 - ((r - 1) * n + (c - 1)))) & 1 == 1;
                    let g = rgb.data[idx + 1];
                    assert!(
                        if white { g > 150 } else { g < 100 },
                        "frame {k} marker {} cell {r},{c}: green {g}",
                        m.id
                    );
                    checked += 1;
                }
            }
        }
    }
    assert!(checked > 100, "{checked} cells checked");
    // The texture is colour only: the same scene untextured has the same depth, other colours.
    let mut untextured = cfg.clone();
    untextured.scene.textured = false;
    let plain = SimCell::generate(&untextured).unwrap();
    let (a, b) = (plain.render(1, 2).unwrap(), cell.render(1, 2).unwrap());
    assert_eq!(a.depth, b.depth);
    assert_ne!(a.color.unwrap().data, b.color.unwrap().data);
}
