//! Accuracy sweep of `calibrate` over seeded simulated cells:
//! `cargo run --release --example cell_sweep -- FIRST_SEED COUNT [FRAMES] [OVERLAP]` (optionally with
//! `DEPTHCAL_SIM_JSON='{...}'`, a SimConfig to start from).
//! Prints per-seed errors, the normalised translation error, and the median and worst.
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::Cell;
use depthcal::sim::{simulate_cell, SimConfig};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let first: u64 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let n: u64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    let frames: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(20);
    let overlap: Option<f64> = a.get(4).and_then(|s| s.parse().ok());
    let (mut rs, mut ts, mut zs) = (Vec::new(), Vec::new(), Vec::new());
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
        let cell = Cell::open(&dir).unwrap();
        let t0 = std::time::Instant::now();
        let c = calibrate(
            &cell,
            &GlobalRegistration::default(),
            &CalibrateConfig::default(),
            &mut |_| {},
        );
        let _ = std::fs::remove_dir_all(&dir);
        match c {
            Ok(c) => {
                let (r, t) = c.error_vs_truth.unwrap();
                let var: f64 = (3..6).map(|k| c.covariance[(k, k)]).sum();
                let z = t / var.sqrt();
                println!(
                    "seed {seed:3}: {r:.4} deg {:.3} mm  z {z:.2}  overlap {:.2}  {:.2} s{}",
                    t * 1e3,
                    c.overlap,
                    t0.elapsed().as_secs_f64(),
                    if r < 0.1 && t < 1e-3 { "" } else { "  OVER" }
                );
                rs.push(r);
                ts.push(t * 1e3);
                zs.push(z);
            }
            Err(e) => println!("seed {seed:3}: FAILED {e}"),
        }
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        (v[v.len() / 2], *v.last().unwrap())
    };
    let (rm, rw) = med(&mut rs);
    let (tm, tw) = med(&mut ts);
    let (zm, zw) = med(&mut zs);
    let rmsz = (zs.iter().map(|z| z * z).sum::<f64>() / zs.len() as f64).sqrt();
    println!("median {rm:.4} deg {tm:.3} mm; worst {rw:.4} deg {tw:.3} mm; normalised error median {zm:.2} worst {zw:.2} rms {rmsz:.2}");
}
