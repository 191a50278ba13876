//! The marker and the 2D-feature initialisers on simulated cells with exact ground truth (cargo feature
//! `vision`): marker method within 0.5° and 5 mm before ICP, features method within 1° and 1 cm before ICP,
//! both within the depth-only accuracy (0.1° / 1 mm) after ICP; the depth-only method on the same cells
//! for comparison. Also the bad-input cases: no marker visible, a marker seen by one robot only, no depth
//! under the keypoints, colour and depth of different sizes; and `depthcal compare`.
//!
//! `cargo test --release --features vision --test vision_marker_feature_cells -- --nocapture` prints the
//! table; `DEPTHCAL_SIM_SEEDS=N` runs N cells (default 2).
#![cfg(feature = "vision")]

mod common;
use common::{depthcal, scratch};
use depthcal::calibration::initializer::{GlobalRegistration, Initializer};
use depthcal::calibration::robot_to_robot::{
    calibrate_request, fuse_cell, refine_cell, CalibrateConfig, CalibrateRequest,
};
use depthcal::cell::Cell;
use depthcal::sim::{SimCell, SimConfig, SimMarkersConfig};
use depthcal::vision::initializers::feature_initializer;
use depthcal::vision::initializers::marker_initializer;
use std::path::{Path, PathBuf};

/// A cell with three 4x4_50 markers near the table centre and textured objects and table, 12 frames per
/// robot; the robots share about 70% of what they see (the simulator's default).
fn marker_cell(seed: u64) -> SimConfig {
    let mut c = SimConfig {
        seed,
        frames: 12,
        ..SimConfig::default()
    };
    c.scene.markers = Some(SimMarkersConfig::default());
    c.scene.textured = true;
    c
}

fn write(cfg: &SimConfig, name: &str) -> PathBuf {
    let dir = scratch(name);
    SimCell::generate(cfg)
        .unwrap()
        .write(&dir, &|_| {})
        .unwrap();
    dir
}

fn seeds() -> u64 {
    std::env::var("DEPTHCAL_SIM_SEEDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2)
}

#[test]
fn marker_and_feature_methods_meet_their_bounds_on_simulated_cells() {
    let cfg = CalibrateConfig::default();
    println!("seed  method    initial deg / mm      refined deg / mm     (depth-only refined)");
    for seed in 1..=seeds() {
        let dir = write(&marker_cell(seed + 20), &format!("mf-cell-{seed}"));
        let cell = Cell::open(&dir).unwrap();
        let fused = fuse_cell(&cell, &cfg).unwrap();
        let depth = refine_cell(
            &cell,
            &fused,
            &GlobalRegistration::default(),
            &cfg,
            true,
            &mut |_| {},
        )
        .unwrap();
        let (dr, dt) = depth.error_vs_truth.unwrap();
        let (marker, notes) = marker_initializer(&cell, &cfg.marker).unwrap();
        for n in &notes {
            eprintln!("  note: {n}");
        }
        let (features, _) = feature_initializer(&cell, &cfg.features).unwrap();
        let methods: [(&dyn Initializer, f64, f64); 2] =
            [(&marker, 0.5, 5e-3), (&features, 1.0, 1e-2)];
        for (init, bound_deg, bound_m) in methods {
            let c = refine_cell(&cell, &fused, init, &cfg, true, &mut |_| {}).unwrap();
            let (ir, it) = c.initial_error_vs_truth.unwrap();
            let (r, t) = c.error_vs_truth.unwrap();
            println!(
                "{seed:>4}  {:<9} {ir:>7.3} / {:>6.2}     {r:>7.4} / {:>6.3}     ({dr:.4} / {:.3})",
                init.name(),
                it * 1e3,
                t * 1e3,
                dt * 1e3
            );
            println!("      {}", c.initial.detail);
            assert!(
                ir < bound_deg && it < bound_m,
                "seed {seed} {}: initial {ir}° / {} mm",
                init.name(),
                it * 1e3
            );
            assert!(
                r < 0.1 && t < 1e-3,
                "seed {seed} {}: refined {r}° / {} mm",
                init.name(),
                t * 1e3
            );
            // The stated uncertainty is not wildly off: the error within 5 σ (and σ not absurdly large).
            assert!(
                it < 5.0 * c.initial.sigma_translation_m + 1e-3,
                "seed {seed} {}: {} mm vs σ {} mm",
                init.name(),
                it * 1e3,
                c.initial.sigma_translation_m * 1e3
            );
            assert!(c.initial.sigma_translation_m < bound_m);
        }
        // Without refinement the marker method gives its own estimate unchanged, and fuses nothing.
        let (only, _) = calibrate_request(CalibrateRequest {
            refine: false,
            ..CalibrateRequest::new(&cell, &marker, &cfg)
        })
        .unwrap();
        assert!(!only.refined && only.fused_points == [0, 0]);
        assert_eq!(only.transform, only.initial.transform);
    }
}

/// Rewrites `cell.toml` of `dir` through `edit`.
fn edit_manifest(dir: &Path, edit: &dyn Fn(&str) -> String) {
    let p = dir.join("cell.toml");
    let s = std::fs::read_to_string(&p).unwrap();
    std::fs::write(&p, edit(&s)).unwrap();
}

#[test]
fn bad_inputs_get_errors_naming_the_robot_and_frames() {
    let cfg = CalibrateConfig::default();
    let mut sim = marker_cell(3);
    sim.frames = 4;
    let dir = write(&sim, "mf-bad");
    // No [markers] table.
    edit_manifest(&dir, &|s| s.replace("[markers]", "[markers_unused]"));
    let e = marker_initializer(&Cell::open(&dir).unwrap(), &cfg.marker)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("cell.toml") && e.contains("[markers]"), "{e}");
    edit_manifest(&dir, &|s| s.replace("[markers_unused]", "[markers]"));
    // No marker visible: a dictionary whose markers are not in the images.
    edit_manifest(&dir, &|s| s.replace("\"DICT_4X4_50\"", "\"DICT_6X6_250\""));
    let e = marker_initializer(&Cell::open(&dir).unwrap(), &cfg.marker)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no marker") && e.contains("left"), "{e}");
    edit_manifest(&dir, &|s| s.replace("\"DICT_6X6_250\"", "\"DICT_4X4_50\""));
    // A marker seen by one robot only: the other robot's colour images show none.
    let blind = scratch("mf-bad-blind");
    copy_dir(&dir, &blind);
    for f in std::fs::read_dir(blind.join("right/color")).unwrap() {
        let p = f.unwrap().path();
        let g = depthcal::vision::read_grey_image(&p).unwrap();
        write_grey_png(&p, g.width, g.height);
    }
    let e = marker_initializer(&Cell::open(&blind).unwrap(), &cfg.marker)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("robot \"right\" saw no marker") && e.contains("robot \"left\" saw ids"),
        "{e}"
    );
    // No depth under the keypoints: blank the other robot's depth images.
    let blank = scratch("mf-bad-nodepth");
    copy_dir(&dir, &blank);
    for f in std::fs::read_dir(blank.join("right/depth")).unwrap() {
        let p = f.unwrap().path();
        let d = depthcal::camera::read_depth_png(&p).unwrap();
        depthcal::camera::depth::write_depth_png(
            &p,
            &depthcal::camera::DepthImage::zeros(d.width, d.height),
        )
        .unwrap();
    }
    let e = feature_initializer(&Cell::open(&blank).unwrap(), &cfg.features)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("right") && e.contains("depth"), "{e}");
    // Colour and depth of different sizes.
    let c0 = std::fs::read_dir(dir.join("left/color"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let full = depthcal::vision::read_grey_image(&c0).unwrap();
    write_grey_png(&c0, full.width / 2, full.height / 2);
    for e in [
        marker_initializer(&Cell::open(&dir).unwrap(), &cfg.marker)
            .err()
            .unwrap()
            .to_string(),
        feature_initializer(&Cell::open(&dir).unwrap(), &cfg.features)
            .err()
            .unwrap()
            .to_string(),
    ] {
        let name = c0.file_name().unwrap().to_string_lossy().to_string();
        assert!(e.contains(&name) && e.contains("aligned"), "{e}");
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// Overwrites `path` with a mid-grey 8-bit PNG of `w x h` pixels.
fn write_grey_png(path: &Path, w: u32, h: u32) {
    let f = std::fs::File::create(path).unwrap();
    let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w, h);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()
        .unwrap()
        .write_image_data(&vec![128u8; (w * h) as usize])
        .unwrap();
}

#[test]
fn compare_prints_every_method_the_cell_allows() {
    let mut sim = marker_cell(4);
    sim.frames = 8;
    let dir = write(&sim, "mf-compare");
    let (code, out, err) =
        depthcal(&["compare", dir.to_str().unwrap(), "--json", "--threads", "2"]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let methods = v["methods"].as_array().unwrap();
    let by = |m: &str| methods.iter().find(|x| x["method"] == m).unwrap().clone();
    assert_eq!(by("checkerboard")["status"], "skipped");
    for m in ["depth", "marker", "features"] {
        let x = by(m);
        assert_eq!(x["status"], "ok", "{m}: {x}");
        assert!(
            x["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 0.2,
            "{m}: {x}"
        );
        assert!(
            x["disagreement"]["translation_m"].as_f64().unwrap() < 3e-3,
            "{m}: {x}"
        );
        assert!(x["time_ms"].as_f64().unwrap() > 0.0);
    }
    let (code, out, _) = depthcal(&[
        "compare",
        dir.to_str().unwrap(),
        "--methods",
        "marker",
        "--no-refine",
    ]);
    assert_eq!(code, 0);
    assert!(out.contains("marker") && !out.contains("features"), "{out}");
}
