//! Accuracy and uncertainty sweep of `calibrate` over seeded simulated cells:
//! `cargo run --release --example cell_sweep -- FIRST_SEED COUNT [FRAMES] [OVERLAP]`, optionally with
//! `DEPTHCAL_SIM_JSON='{...}'` (a SimConfig to start from), `DEPTHCAL_CALIBRATE_JSON='{...}'` (a partial
//! CalibrateConfig) and `DEPTHCAL_SWEEP_HANDEYE=DEG,MM` (every robot's hand-eye perturbed by a seeded
//! random rotation and translation of these 1-σ per axis before calibrating; the depth stays rendered with
//! the true hand-eyes).
//! Prints per-seed errors, the normalised error of the full pose (`sqrt(eᵀΣ⁻¹e/6)`), whether the result
//! was trusted, and the median, worst and share of normalised errors below 3.
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::Cell;
use depthcal::geometry::Rng;
use depthcal::sim::{simulate_cell, SimConfig};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A random rigid motion with `deg` / `mm` 1-σ per axis.
fn perturbation(rng: &mut Rng, deg: f64, mm: f64) -> Isometry3<f64> {
    let mut v = || rng.normal();
    let r = Vector3::new(v(), v(), v()) * deg.to_radians();
    let t = Vector3::new(v(), v(), v()) * mm * 1e-3;
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(r))
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let first: u64 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let n: u64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    let frames: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let overlap: Option<f64> = a.get(4).and_then(|s| s.parse().ok());
    let calibrate_cfg: CalibrateConfig = std::env::var("DEPTHCAL_CALIBRATE_JSON")
        .ok()
        .map(|j| serde_json::from_str(&j).expect("DEPTHCAL_CALIBRATE_JSON is a CalibrateConfig"))
        .unwrap_or_default();
    let handeye: Option<(f64, f64)> = std::env::var("DEPTHCAL_SWEEP_HANDEYE").ok().map(|s| {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse().expect("DEG,MM"))
            .collect();
        (v[0], v[1])
    });
    let (mut rs, mut ts, mut zs) = (Vec::new(), Vec::new(), Vec::new());
    let mut untrusted = 0;
    for seed in first..first + n {
        let dir = std::env::temp_dir().join(format!("depthcal-sweep-{seed}"));
        let _ = std::fs::remove_dir_all(&dir);
        // DEPTHCAL_SIM_JSON: a JSON SimConfig to start from (e.g. a wider workspace and closer views).
        let base: SimConfig = std::env::var("DEPTHCAL_SIM_JSON")
            .ok()
            .map(|j| serde_json::from_str(&j).expect("DEPTHCAL_SIM_JSON is a SimConfig"))
            .unwrap_or_default();
        let mut cfg = SimConfig {
            seed,
            frames,
            ..base
        };
        cfg.color = false;
        if let Some(o) = overlap {
            cfg.overlap = o;
        }
        simulate_cell(&cfg, &dir, &|_| {}).unwrap();
        let mut cell = Cell::open(&dir).unwrap();
        if let Some((deg, mm)) = handeye {
            let mut rng = Rng::new(seed ^ 0x0048_414e_4445_5945);
            for r in &mut cell.robots {
                r.t_ee_cam = perturbation(&mut rng, deg, mm) * r.t_ee_cam;
            }
        }
        let t0 = std::time::Instant::now();
        let c = calibrate(
            &cell,
            &GlobalRegistration::default(),
            &calibrate_cfg,
            &mut |_| {},
        );
        let _ = std::fs::remove_dir_all(&dir);
        match c {
            Ok(c) => {
                let (r, t) = c.error_vs_truth.unwrap();
                let z = c.normalised_error.as_ref().map_or(f64::NAN, |e| e.pose);
                untrusted += usize::from(!c.trust.trusted);
                println!(
                    "seed {seed:3}: {r:.4} deg {:.3} mm  normalised {z:.2}  overlap {:.2}  trusted {}  {:.2} s{}",
                    t * 1e3,
                    c.overlap.unwrap_or(f64::NAN),
                    c.trust.trusted,
                    t0.elapsed().as_secs_f64(),
                    if r < 0.1 && t < 2e-3 { "" } else { "  OVER" }
                );
                rs.push(r);
                ts.push(t * 1e3);
                zs.push(z);
            }
            Err(e) => println!("seed {seed:3}: FAILED {e}"),
        }
    }
    if zs.is_empty() {
        return;
    }
    let below3 = zs.iter().filter(|z| **z < 3.0).count();
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        (v[v.len() / 2], *v.last().unwrap())
    };
    let (rm, rw) = med(&mut rs);
    let (tm, tw) = med(&mut ts);
    let (zm, zw) = med(&mut zs);
    println!(
        "median {rm:.4} deg {tm:.3} mm; worst {rw:.4} deg {tw:.3} mm; normalised error median {zm:.2} worst {zw:.2}, {below3} of {} below 3; {untrusted} untrusted",
        zs.len()
    );
}
