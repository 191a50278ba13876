//! `depthcal calibrate CELL_DIR`: robot-to-robot calibration of a cell dataset.

use super::output::{matrix4_json, matrix4_text, matrix6_json, spinner, timings_json};
use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::calibration::board_init::checkerboard_initializer;
use depthcal::calibration::initializer::{GlobalRegistration, Initializer, UserGuess};
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::Cell;
use depthcal::geometry::pose::{isometry_to_xyzquat, KukaPose};
use depthcal::io::read_matrix_file;
use std::path::PathBuf;
use std::time::Instant;

/// Initialisation methods.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Method {
    /// Depth only: FPFH + RANSAC under the cell's priors, then trimmed robust ICP.
    Depth,
    /// Start from `--init` and refine with trimmed robust ICP.
    Guess,
    /// Both robots' board poses (colour images of the cell's [board], needs the `vision` feature; or
    /// --board-pose), T_base1_board · T_base2_board⁻¹, then trimmed robust ICP.
    Checkerboard,
}

/// Arguments of `depthcal calibrate`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (with cell.toml).
    cell: PathBuf,
    /// How the first estimate is obtained.
    #[arg(long, value_enum, default_value_t = Method::Depth)]
    method: Method,
    /// An initial T_base1_base2 (4x4 matrix file or a previous --json output); implies --method guess.
    #[arg(long)]
    init: Option<PathBuf>,
    /// With --method checkerboard: a robot's board pose from an earlier `depthcal handeye --json` run,
    /// as ROBOT=FILE (repeatable); robots without one have the board found in their colour images.
    #[arg(long, value_name = "ROBOT=FILE", value_parser = parse_board_pose)]
    board_pose: Vec<(String, PathBuf)>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Ignore the [priors] table of cell.toml.
    #[arg(long)]
    no_priors: bool,
    /// Seed of the randomised steps.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// A JSON file with a (partial) CalibrateConfig.
    #[arg(long)]
    config: Option<PathBuf>,
}

fn parse_board_pose(s: &str) -> Result<(String, PathBuf), String> {
    match s.split_once('=') {
        Some((r, f)) if !r.trim().is_empty() && !f.trim().is_empty() => {
            Ok((r.trim().to_string(), PathBuf::from(f.trim())))
        }
        _ => Err(format!(
            "{s:?}: expected ROBOT=FILE (a robot name of cell.toml and a handeye --json output)"
        )),
    }
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let mut cfg: CalibrateConfig =
        super::output::read_config(a.config.as_deref(), "calibrate configuration")?;
    cfg.seed = a.seed;
    cfg.use_priors = !a.no_priors;
    let cell = Cell::open(&a.cell)?;
    let mut board_ms = None;
    let init: Box<dyn Initializer> = match (&a.init, a.method) {
        (Some(p), _) => Box::new(UserGuess {
            transform: read_matrix_file(p)?,
            source: p.display().to_string(),
        }),
        (None, Method::Guess) => anyhow::bail!("--method guess needs --init FILE"),
        (None, Method::Depth) => Box::new(GlobalRegistration {
            config: cfg.register.clone(),
            ..GlobalRegistration::default()
        }),
        (None, Method::Checkerboard) => {
            let t0 = Instant::now();
            let (init, warnings) = checkerboard_initializer(&cell, &a.board_pose)?;
            board_ms = Some(t0.elapsed().as_secs_f64() * 1e3);
            for w in warnings {
                eprintln!("warning: {w}");
            }
            Box::new(init)
        }
    };
    if !a.board_pose.is_empty() && !matches!(a.method, Method::Checkerboard) {
        anyhow::bail!("--board-pose is for --method checkerboard");
    }
    let pb = spinner("opening the cell");
    let mut c = calibrate(&cell, init.as_ref(), &cfg, &mut |s| {
        pb.set_message(s.to_string())
    })
    .with_context(|| format!("calibrating {}", a.cell.display()))?;
    if let Some(ms) = board_ms {
        // The board poses are found before the clouds are fused.
        c.timings_ms.insert(0, ("board_poses".into(), ms));
    }
    pb.finish_and_clear();
    for w in &c.warnings {
        eprintln!("warning: {w}");
    }
    let t = &c.transform;
    let xq = isometry_to_xyzquat(t);
    let kuka = KukaPose::from_isometry(t);
    let sd: Vec<f64> = (0..6)
        .map(|k| c.covariance[(k, k)].max(0.0).sqrt())
        .collect();
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let (parent, child) = (format!("{}_base", c.reference), format!("{}_base", c.other));
    let ros2 = format!(
        "ros2 run tf2_ros static_transform_publisher --x {:.6} --y {:.6} --z {:.6} --qx {:.8} --qy {:.8} --qz {:.8} --qw {:.8} --frame-id {parent} --child-frame-id {child}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6]
    );
    let ros1 = format!(
        "rosrun tf2_ros static_transform_publisher {:.6} {:.6} {:.6} {:.8} {:.8} {:.8} {:.8} {parent} {child}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6]
    );
    if a.json {
        let err = |e: Option<(f64, f64)>| {
            e.map(|(r, t)| serde_json::json!({"rotation_deg": r, "translation_mm": t * 1e3}))
        };
        let v = serde_json::json!({
            "cell": a.cell,
            "reference": c.reference,
            "other": c.other,
            "method": c.method,
            "transform": matrix4_json(t),
            "xyz_quaternion": {"x": xq[0], "y": xq[1], "z": xq[2], "qx": xq[3], "qy": xq[4], "qz": xq[5], "qw": xq[6]},
            "kuka_xyzabc": {"x_mm": kuka.x_mm, "y_mm": kuka.y_mm, "z_mm": kuka.z_mm, "a_deg": kuka.a_deg, "b_deg": kuka.b_deg, "c_deg": kuka.c_deg},
            "covariance": matrix6_json(&c.covariance),
            "covariance_parameters": "[rx, ry, rz (rad), tx, ty, tz (m)], left increment in the reference base frame",
            "sigma": {"rotation_deg": [sd[0].to_degrees(), sd[1].to_degrees(), sd[2].to_degrees()], "translation_mm": [sd[3] * 1e3, sd[4] * 1e3, sd[5] * 1e3]},
            "fitness": c.fitness,
            "inlier_rmse": c.inlier_rmse,
            "overlap": c.overlap,
            "converged": c.converged,
            "degenerate": c.degeneracy.is_degenerate(),
            "degeneracy": c.degeneracy,
            "priors_used": c.priors_used,
            "initial": {"transform": matrix4_json(&c.initial.transform), "detail": c.initial.detail,
                        "sigma_rotation_deg": c.initial.sigma_rotation_deg, "sigma_translation_mm": c.initial.sigma_translation_m * 1e3,
                        "error_vs_truth": err(c.initial_error_vs_truth)},
            "error_vs_truth": err(c.error_vs_truth),
            "frames": {"reference": c.frames[0], "other": c.frames[1]},
            "fused_points": {"reference": c.fused_points[0], "other": c.fused_points[1]},
            "ros2": ros2,
            "warnings": c.warnings,
            "timings_ms": timings_json(&c.timings_ms),
            "total_ms": total_ms,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "T_base1_base2: {} base -> {} base ({} frames / {} frames, method {})",
        c.other, c.reference, c.frames[1], c.frames[0], c.method
    );
    println!("{}", matrix4_text(t));
    println!(
        "xyz (m)         {:.6} {:.6} {:.6}   quaternion (x y z w) {:.8} {:.8} {:.8} {:.8}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6]
    );
    println!(
        "KUKA XYZ-ABC    X {:.3} Y {:.3} Z {:.3} mm   A {:.4} B {:.4} C {:.4} deg",
        kuka.x_mm, kuka.y_mm, kuka.z_mm, kuka.a_deg, kuka.b_deg, kuka.c_deg
    );
    println!("ROS 2           {ros2}");
    println!("ROS 1           {ros1}");
    println!(
        "1-sigma         rotation {:.4} {:.4} {:.4} deg, translation {:.3} {:.3} {:.3} mm",
        sd[0].to_degrees(),
        sd[1].to_degrees(),
        sd[2].to_degrees(),
        sd[3] * 1e3,
        sd[4] * 1e3,
        sd[5] * 1e3
    );
    println!(
        "quality         fitness {:.3}, inlier RMSE {:.2} mm, overlap {:.3}, converged {}, degenerate {}",
        c.fitness,
        c.inlier_rmse * 1e3,
        c.overlap,
        c.converged,
        c.degeneracy.is_degenerate()
    );
    println!(
        "priors          {}",
        if c.priors_used.is_empty() {
            "none".to_string()
        } else {
            c.priors_used.join(", ")
        }
    );
    println!("initial         {}", c.initial.detail);
    if let (Some((r, tr)), Some((ri, ti))) = (c.error_vs_truth, c.initial_error_vs_truth) {
        println!(
            "vs ground truth initial {ri:.3} deg / {:.2} mm  ->  refined {r:.4} deg / {:.3} mm",
            ti * 1e3,
            tr * 1e3
        );
    }
    let times: Vec<String> = c
        .timings_ms
        .iter()
        .map(|(k, v)| format!("{k} {v:.0}"))
        .collect();
    println!("timings (ms)    {}  total {total_ms:.0}", times.join(", "));
    Ok(())
}
