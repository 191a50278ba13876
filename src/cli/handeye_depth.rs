//! `depthcal handeye --depth CELL_DIR --robot NAME`: one robot's hand-eye refined from its depth frames.

use super::output::matrix4_text;
use depthcal::calibration::handeye::depth::{refine_hand_eye_from_depth, HandEyeDepthConfig};
use depthcal::cell::Cell;
use depthcal::report::handeye_depth::true_hand_eye;
use depthcal::report::HandEyeDepthReport;
use std::path::Path;

/// Runs `handeye --depth`: prints the report (text or `--json`); an untrusted result exits 3.
pub fn run(dir: &Path, robot: &str, config: Option<&Path>, json: bool) -> anyhow::Result<()> {
    let cfg: HandEyeDepthConfig =
        super::output::read_config(config, "hand-eye from depth configuration")?;
    let cell = Cell::open(dir)?;
    let truth = cell.ground_truth()?.and_then(|g| true_hand_eye(&g, robot));
    let r = refine_hand_eye_from_depth(cell.robot(robot)?, None, &cfg)?;
    let report = HandEyeDepthReport::new(&r, &dir.display().to_string(), truth.as_ref());
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_text(&report);
    }
    let trust = depthcal::registration::Trust {
        trusted: r.trusted,
        reasons: r.reasons.clone(),
        suggestions: r.suggestions.clone(),
    };
    super::gate(&trust)
}

fn print_text(r: &HandEyeDepthReport) {
    let m = |p: &depthcal::report::PoseReport| {
        let rows: Vec<f64> = p.matrix.iter().flatten().copied().collect();
        let mut a = [0.0; 16];
        a.copy_from_slice(&rows);
        depthcal::geometry::transform::isometry_from_rows(&a, "T_ee_cam")
            .map(|t| matrix4_text(&t))
            .unwrap_or_default()
    };
    println!(
        "hand-eye of robot {} from its depth frames ({} frames, {} tests)",
        r.robot, r.frames_used, r.tests
    );
    println!("T_ee_cam (refined)\n{}", m(&r.t_ee_cam));
    let k = r.t_ee_cam.kuka_xyzabc;
    println!(
        "KUKA XYZ-ABC    X {:.3} Y {:.3} Z {:.3} mm   A {:.4} B {:.4} C {:.4} deg",
        k[0], k[1], k[2], k[3], k[4], k[5]
    );
    println!(
        "change          {:.4} deg / {:.3} mm from the cell's hand-eye (camera frame: xyz {:.3} {:.3} {:.3} mm)",
        r.change_size.rotation_deg,
        r.change_size.translation_m * 1e3,
        r.change.xyz_m[0] * 1e3,
        r.change.xyz_m[1] * 1e3,
        r.change.xyz_m[2] * 1e3
    );
    println!("observability   (1-sigma; camera axes)");
    for d in &r.dofs {
        let unit = if d.dof.starts_with('r') { "deg" } else { "mm" };
        println!("  {}  {:>10.4} {unit:<3}  {}", d.dof, d.sigma, d.status);
    }
    for w in &r.weak_directions {
        println!(
            "  {}: {} (1-sigma {:.2} mm)",
            w.status, w.description, w.sigma_mm
        );
    }
    for p in &r.suggested_poses {
        let k = p.kuka_xyzabc;
        println!(
            "  capture       X {:.1} Y {:.1} Z {:.1} mm A {:.2} B {:.2} C {:.2} deg (frame {} turned {:+.0} deg about ({:.2}, {:.2}, {:.2}) in the flange frame, about the {}): {}",
            k[0], k[1], k[2], k[3], k[4], k[5], p.from_frame, p.rotation_deg, p.axis_ee[0], p.axis_ee[1], p.axis_ee[2],
            if p.pivot == "flange" { "flange origin" } else { "point the camera looks at" },
            p.reason
        );
    }
    println!(
        "flange motion   largest rotation {:.1} deg, rotation axes spread {:.1} deg",
        r.flange_motion.max_rotation_deg, r.flange_motion.axis_spread_deg
    );
    println!(
        "residuals       median {:.3} mm -> {:.3} mm ({} Gauss-Newton iterations, converged {})",
        r.median_residual_before_m * 1e3,
        r.median_residual_after_m * 1e3,
        r.iterations,
        r.converged
    );
    println!("  frame        before (mm)  after (mm)  tests");
    for f in &r.frames {
        println!(
            "  {:<12} {:>10.3}  {:>10.3}  {}",
            f.id,
            f.before_m * 1e3,
            f.after_m * 1e3,
            f.tests_after
        );
    }
    if let Some(e) = &r.error_vs_truth {
        println!(
            "vs ground truth {:.4} deg / {:.3} mm -> {:.4} deg / {:.3} mm; normalised error {:.2} (largest |e|/sigma {:.2})",
            e.before.rotation_deg,
            e.before.translation_m * 1e3,
            e.after.rotation_deg,
            e.after.translation_m * 1e3,
            e.normalised_error,
            e.max_error_over_sigma
        );
    }
    if r.trusted {
        println!("trusted         yes");
    } else {
        println!("trusted         NO");
        for x in &r.reasons {
            println!("  because       {x}");
        }
        for s in &r.suggestions {
            println!("  try           {s}");
        }
    }
}
