//! `calibrate` on seeded simulated cells with exact ground truth: accuracy at default noise over several
//! seeds, partial overlap, honesty of the reported covariance, and a featureless scene reported as
//! degenerate. `DEPTHCAL_SIM_SEEDS=N` runs N seeds (default 4).

mod common;
use common::scratch;
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig, Calibration};
use depthcal::cell::Cell;
use depthcal::sim::{simulate_cell, SimConfig};

fn run(name: &str, cfg: SimConfig) -> depthcal::Result<Calibration> {
    let dir = scratch(name);
    simulate_cell(&cfg, &dir, &|_| {})?;
    let cell = Cell::open(&dir)?;
    calibrate(
        &cell,
        &GlobalRegistration::default(),
        &CalibrateConfig::default(),
        &mut |_| {},
    )
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
            c.fitness,
            c.overlap,
            c.timings_ms
        );
        worst = (worst.0.max(r), worst.1.max(t), worst.2.max(z));
        assert!(
            !c.degeneracy.is_degenerate(),
            "seed {seed}: {:?}",
            c.degeneracy
        );
        // The issue asks for < 1 mm; at default noise we reach 1-2 mm (see the README).
        assert!(
            r < 0.1 && t < 0.003,
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

/// The simulator's `overlap` setting narrows each robot's swing of views; with the D435's wide field of view
/// the shared fraction stays high (the estimated overlap here is ~0.9). True 30-50% cells (wider workspace,
/// closer views) are not solved yet: see the README.
#[test]
fn narrow_view_swing_cell() {
    let mut cfg = sim(40);
    cfg.overlap = 0.4;
    let c = run("sim-overlap", cfg).unwrap();
    let (r, t) = c.error_vs_truth.unwrap();
    eprintln!(
        "overlap 0.4: {r:.4} deg, {:.3} mm, estimated overlap {:.2}",
        t * 1e3,
        c.overlap
    );
    assert!(r < 0.1 && t < 0.003, "{r:.4} deg, {:.3} mm", t * 1e3);
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
