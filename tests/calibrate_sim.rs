//! `calibrate` on seeded simulated cells with exact ground truth: accuracy at default noise over several
//! seeds, cells whose robots share only 30-50% of the scene, honesty of the reported covariance, and a
//! featureless scene reported as degenerate. `DEPTHCAL_SIM_SEEDS=N` runs N seeds (default 4; the
//! figures of docs/accuracy.md come from `tools/cell_sweep.rs` over 20).

mod common;
use common::scratch;
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig, Calibration};
use depthcal::cell::Cell;
use depthcal::sim::{simulate_cell, SimConfig};

fn run(name: &str, cfg: SimConfig) -> depthcal::Result<Calibration> {
    run_shared(name, cfg).map(|(c, _)| c)
}

/// Simulates and calibrates; also returns the fractions of each robot's view the other robot saw too.
fn run_shared(name: &str, cfg: SimConfig) -> depthcal::Result<(Calibration, Vec<f64>)> {
    let dir = scratch(name);
    let (sim, _) = simulate_cell(&cfg, &dir, &|_| {})?;
    let cell = Cell::open(&dir)?;
    let c = calibrate(
        &cell,
        &GlobalRegistration::default(),
        &CalibrateConfig::default(),
        &mut |_| {},
    )?;
    Ok((c, sim.shared))
}

fn sim(seed: u64) -> SimConfig {
    let mut c = SimConfig {
        seed,
        frames: 12,
        ..SimConfig::default()
    };
    c.color = false;
    c
}

/// Normalised translation error: |e_t| over the 1-σ radius the covariance claims.
fn normalised(c: &Calibration, t_err_m: f64) -> f64 {
    let var: f64 = (3..6).map(|k| c.covariance[(k, k)]).sum();
    t_err_m / var.sqrt()
}

#[test]
fn seeded_cells_at_default_noise() {
    let n: u64 = std::env::var("DEPTHCAL_SIM_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4);
    let mut worst = (0f64, 0f64, 0f64);
    for seed in 1..=n {
        let c = run(&format!("sim-{seed}"), sim(seed)).unwrap();
        let (r, t) = c.error_vs_truth.unwrap();
        let z = normalised(&c, t);
        eprintln!(
            "seed {seed}: {r:.4} deg, {:.3} mm (normalised {z:.2}), fitness {:.3}, overlap {:.3}, {:?}",
            t * 1e3,
            c.fitness.unwrap(),
            c.overlap.unwrap(),
            c.timings_ms
        );
        worst = (worst.0.max(r), worst.1.max(t), worst.2.max(z));
        assert!(
            !c.degeneracy.is_degenerate(),
            "seed {seed}: {:?}",
            c.degeneracy
        );
        assert!(
            r < 0.1 && t < 0.001,
            "seed {seed}: {r:.4} deg, {:.3} mm",
            t * 1e3
        );
        assert!(
            z < 3.0,
            "seed {seed}: the covariance claims too much ({z:.2} sigma)"
        );
    }
    eprintln!(
        "worst: {:.4} deg, {:.3} mm, {:.2} sigma",
        worst.0,
        worst.1 * 1e3,
        worst.2
    );
}

/// Cells whose robots share only 30-50% of what they see (checked on the rendered frames): the global
/// stage must find the right basin and the refinement must land close to the truth. At these overlaps a
/// few cells keep a yaw bias of up to 0.8° (ICP started at the truth settles there too; see docs/accuracy.md),
/// hence the looser bound.
#[test]
fn cells_sharing_30_to_50_percent() {
    for (seed, overlap) in [(41u64, 0.3), (42, 0.4), (43, 0.5)] {
        let mut cfg = sim(seed);
        cfg.overlap = overlap;
        let (c, shared) = run_shared(&format!("sim-overlap-{seed}"), cfg).unwrap();
        let (r, t) = c.error_vs_truth.unwrap();
        eprintln!(
            "overlap {overlap}: shared {:.2} / {:.2}, {r:.4} deg, {:.3} mm, estimated overlap {:.2}",
            shared[0],
            shared[1],
            t * 1e3,
            c.overlap.unwrap()
        );
        let mean = 0.5 * (shared[0] + shared[1]);
        assert!(
            (mean - overlap).abs() < 0.08,
            "asked {overlap}, the robots share {shared:?}"
        );
        assert!(r < 1.0 && t < 0.01, "{r:.4} deg, {:.3} mm", t * 1e3);
    }
}

#[test]
fn featureless_scene_is_degenerate_not_silently_wrong() {
    // One plane: no objects on a table much larger than what the cameras see.
    let mut cfg = sim(50);
    cfg.scene.objects = 0;
    cfg.scene.table_size_m = [6.0, 6.0, 0.04];
    match run("sim-plane", cfg) {
        Ok(c) => {
            eprintln!(
                "plane: degeneracy {:?}, error {:?}",
                c.degeneracy, c.error_vs_truth
            );
            assert!(
                c.degeneracy.is_degenerate(),
                "a bare table must be reported as degenerate"
            );
            assert!(
                c.warnings.iter().any(|w| w.contains("unconstrained")),
                "{:?}",
                c.warnings
            );
        }
        Err(e) => {
            eprintln!("plane: error {e}");
            assert!(!e.to_string().is_empty());
        }
    }
}

/// Cells whose hand-eyes are off by the documented default 1-σ (0.05° / 0.5 mm per axis, seeded random
/// perturbations of both robots; the depth stays rendered with the true hand-eyes): the covariance
/// includes the hand-eye uncertainty, so the normalised error of the whole pose stays below 3, and a
/// result reported as trusted is within what the covariance allows. The README's distribution comes from
/// `cell_sweep` with `DEPTHCAL_SWEEP_HANDEYE=0.05,0.5` over 20 seeds.
#[test]
fn perturbed_hand_eyes_stay_within_the_reported_uncertainty() {
    use depthcal::geometry::Rng;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    for seed in [11u64, 12, 13] {
        let dir = scratch(&format!("sim-he-{seed}"));
        simulate_cell(&sim(seed), &dir, &|_| {}).unwrap();
        let mut cell = Cell::open(&dir).unwrap();
        let mut rng = Rng::new(seed);
        for r in &mut cell.robots {
            let mut g = || rng.normal();
            let w = Vector3::new(g(), g(), g()) * 0.05f64.to_radians();
            let t = Vector3::new(g(), g(), g()) * 0.5e-3;
            r.t_ee_cam =
                Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(w))
                    * r.t_ee_cam;
        }
        let c = calibrate(
            &cell,
            &GlobalRegistration::default(),
            &CalibrateConfig::default(),
            &mut |_| {},
        )
        .unwrap();
        let (r, t) = c.error_vs_truth.unwrap();
        let ne = c.normalised_error.as_ref().expect("ground truth is known");
        eprintln!(
            "seed {seed} (hand-eyes perturbed): {r:.4} deg, {:.3} mm, normalised {:.2}, trusted {}",
            t * 1e3,
            ne.pose,
            c.trust.trusted
        );
        assert!(
            ne.pose < 3.0,
            "seed {seed}: normalised error {:.2}",
            ne.pose
        );
        assert!(r < 1.0 && t < 0.01, "seed {seed}: {r} deg {t} m");
    }
}
