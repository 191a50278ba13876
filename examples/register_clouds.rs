//! Registers the two sample clouds shipped in `clouds/` with the library API and prints the transform,
//! its quality and whether it can be trusted: `cargo run --release --example register_clouds`.
//!
//! The library equivalent of `depthcal register clouds/demo_source.ply clouds/demo_target.ply
//! --truth clouds/demo_truth.txt`. Exits with status 1 on an error and 3 on an untrusted result, as the
//! command does.
use depthcal::geometry::transform::pose_error;
use depthcal::registration::{register, RegisterConfig};
use std::path::Path;

fn main() -> depthcal::Result<()> {
    let clouds = Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds");
    let source = depthcal::io::read_cloud(clouds.join("demo_source.ply"))?;
    let target = depthcal::io::read_cloud(clouds.join("demo_target.ply"))?;
    // No initial guess: FPFH + RANSAC find one; every scale-dependent setting is chosen from the data.
    let reg = register(&source, &target, None, &RegisterConfig::default())?;

    println!("transform (maps source points into the target frame):");
    println!("{:.6}", reg.transform.to_homogeneous());
    println!(
        "fitness {:.3}, inlier RMSE {:.4}, overlap {:.3}, converged {}",
        reg.fitness, reg.inlier_rmse, reg.overlap, reg.converged
    );
    let truth = depthcal::io::read_matrix_file(clouds.join("demo_truth.txt"))?;
    let (rot_deg, trans) = pose_error(&reg.transform, &truth);
    println!("error against the truth: {rot_deg:.4} deg, {trans:.6} (cloud units)");
    println!("trusted {}", reg.trust.trusted);
    for reason in &reg.trust.reasons {
        println!("  reason: {reason}");
    }
    if !reg.trust.trusted {
        std::process::exit(3);
    }
    Ok(())
}
