//! Calibrates the sample cell `clouds/demo-cell` with the library API and prints `T_base1_base2`, its
//! 1-σ and whether it can be trusted: `cargo run --release --example calibrate_cell`.
//!
//! The library equivalent of `depthcal calibrate clouds/demo-cell` (depth-only initialiser: FPFH + RANSAC
//! under the cell's priors, then robust ICP). Exits with status 1 on an error and 3 on an untrusted
//! result, as the command does.
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::Cell;

fn main() -> depthcal::Result<()> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds/demo-cell");
    // Reads and checks cell.toml, the pose files, intrinsics and depth images before any work.
    let cell = Cell::open(&dir)?;
    let init = GlobalRegistration::default();
    let c = calibrate(&cell, &init, &CalibrateConfig::default(), &mut |stage| {
        eprintln!("{stage}")
    })?;

    println!("T_base1_base2 ({} base -> {} base):", c.other, c.reference);
    println!("{:.6}", c.transform.to_homogeneous());
    // Covariance order: [rx, ry, rz (rad), tx, ty, tz (m)], a left increment in the reference base.
    let s: Vec<f64> = (0..6).map(|i| c.covariance[(i, i)].sqrt()).collect();
    println!(
        "1-sigma: rotation {:.4} {:.4} {:.4} deg, translation {:.3} {:.3} {:.3} mm",
        s[0].to_degrees(),
        s[1].to_degrees(),
        s[2].to_degrees(),
        s[3] * 1e3,
        s[4] * 1e3,
        s[5] * 1e3
    );
    if let Some((rot_deg, t_m)) = c.error_vs_truth {
        println!(
            "error against ground_truth.json: {rot_deg:.4} deg, {:.3} mm",
            t_m * 1e3
        );
    }
    println!("trusted {}", c.trust.trusted);
    for reason in &c.trust.reasons {
        println!("  reason: {reason}");
    }
    for hint in &c.trust.suggestions {
        println!("  try: {hint}");
    }
    if !c.trust.trusted {
        std::process::exit(3);
    }
    Ok(())
}
