//! `depthcal plan CELL_DIR`: which degrees of freedom of the hand-eyes and of `T_base1_base2` the cell's
//! frames leave weak, and which flange poses to capture next; on a cell of three or more robots, which base
//! is weakest, what the pairs touching it lack, and the poses that would strengthen it.

use super::methods::{CalibrateSettings, Method, MethodInputs};
use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::calibration::multi_robot::calibrate_robots;
use depthcal::calibration::plan::{plan_cell, PlanConfig};
use depthcal::calibration::plan_robots::{plan_robots, RobotsPlan};
use depthcal::cell::Cell;
use depthcal::methods::calibrate_with_method;
use depthcal::report::PlanReport;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `depthcal plan`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (with cell.toml).
    cell: PathBuf,
    /// Flange poses to propose for the base-to-base transform (default: the plan configuration's, 4).
    #[arg(long)]
    count: Option<usize>,
    /// A JSON file with a (partial) plan configuration (docs/plan.md).
    #[arg(long, value_name = "FILE")]
    plan_config: Option<PathBuf>,
    #[command(flatten)]
    settings: CalibrateSettings,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Runs the command: calibrates the cell (depth method), then plans. Exits 3 when the calibration the
/// plan rests on is untrusted (the plan is printed in full).
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = a.settings.config()?;
    let mut pcfg: PlanConfig =
        super::output::read_config(a.plan_config.as_deref(), "plan configuration")?;
    if let Some(n) = a.count {
        pcfg.base_poses = n;
    }
    pcfg.validate().with_context(|| {
        super::output::config_source(a.plan_config.as_deref(), "the plan configuration")
    })?;
    let calibrating = || format!("calibrating {}", a.cell.display());
    let cell = Cell::open(&a.cell)?;
    cell.ground_truth()?;
    if !a.json {
        eprintln!(
            "calibrating {} ({} robots, depth) ...",
            a.cell.display(),
            cell.robots.len()
        );
    }
    let planning = || {
        if !a.json {
            eprintln!("planning ...");
        }
    };
    let cell_name = a.cell.display().to_string();
    let planning_err = || format!("planning {}", a.cell.display());
    let ms = || start.elapsed().as_secs_f64() * 1e3;
    let (report, trust) = if cell.robots.len() > 2 {
        // Every pair and the pose graph; the weakest base and the pair that strengthens it.
        let init =
            depthcal::methods::build(Method::Depth, &cell, &MethodInputs::default(), &cfg)?.0;
        let (c, fused) =
            calibrate_robots(&cell, init.as_ref(), &cfg, &mut |_| {}).with_context(calibrating)?;
        planning();
        let plan = plan_robots(&c, &fused, &pcfg).with_context(planning_err)?;
        (PlanReport::with_robots(&c, plan, &cell_name, ms()), c.trust)
    } else {
        let (c, fused) = calibrate_with_method(
            &cell,
            Method::Depth,
            &MethodInputs::default(),
            &cfg,
            true,
            &mut |_| {},
        )
        .with_context(calibrating)?;
        planning();
        let plan = plan_cell(&cell, &c, &fused, &pcfg).with_context(planning_err)?;
        (PlanReport::new(&c, plan, &cell_name, ms()), c.trust)
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_text(&report);
    }
    super::gate(&trust)
}

/// The part of a plan of three or more robots: every base's strength, the weakest, the pairs touching it
/// and the pair whose poses follow.
fn print_robots(p: &RobotsPlan) {
    println!(
        "bases of {} robots (largest 1-sigma, rotations at the reference cloud's {:.2} m RMS radius):",
        p.bases.len() + 1,
        p.radius_m
    );
    for b in &p.bases {
        println!(
            "  {:<12} {}",
            b.robot,
            match b.sigma_mm {
                Some(s) => format!(
                    "{s:.3} mm from {} pair(s){}",
                    b.pairs_used,
                    if b.trusted { "" } else { " (NOT trusted)" }
                ),
                None => "NOT calibrated".to_string(),
            }
        );
    }
    println!("weakest base: {}", p.weakest);
    for q in &p.pairs {
        println!(
            "  pair {:<20} {:<11} overlap {}: {}",
            q.pair,
            q.verdict.name(),
            q.overlap.map_or("-".to_string(), |o| format!("{o:.2}")),
            q.advice
        );
    }
    println!(
        "poses for the pair {} - {} (the pair touching {} with the most overlap): its largest 1-sigma is {:.3} mm from its inputs (hand-eyes, poses: more views do not lower it) and {:.3} mm from the registration",
        p.planned_pair[0],
        p.planned_pair[1],
        p.weakest,
        p.pair_inputs_sigma_mm,
        p.pair_registration_sigma_mm
    );
}

fn kuka(k: &[f64; 6]) -> String {
    format!(
        "X {:.1} Y {:.1} Z {:.1} mm A {:.2} B {:.2} C {:.2} deg",
        k[0], k[1], k[2], k[3], k[4], k[5]
    )
}

fn print_text(r: &PlanReport) {
    if let Some(p) = &r.robots {
        print_robots(p);
    }
    println!(
        "plan for {} (reference {}, other {}); the calibration it rests on is {}",
        r.cell,
        r.reference,
        r.other,
        if r.calibration_trusted {
            "trusted"
        } else {
            "NOT trusted"
        }
    );
    for reason in &r.calibration_reasons {
        println!("  because       {reason}");
    }
    for h in &r.plan.hand_eyes {
        if let Some(n) = &h.note {
            println!("hand-eye {:<8} not planned: {n}", h.robot);
            continue;
        }
        let weak: Vec<&str> = h
            .dofs
            .iter()
            .filter(|d| d.status != "observable")
            .map(|d| d.dof)
            .collect();
        if weak.is_empty() {
            println!(
                "hand-eye {:<8} all six parameters observable from its frames",
                h.robot
            );
        } else {
            println!(
                "hand-eye {:<8} weak: {} (camera axes)",
                h.robot,
                weak.join(", ")
            );
        }
        for w in &h.weak_directions {
            println!(
                "  weak          {} is {} (1-sigma {:.2} mm)",
                w.description, w.status, w.sigma_mm
            );
        }
        for s in &h.suggested_poses {
            println!(
                "  capture       {} (frame {} turned {:+.0} deg about ({:.2}, {:.2}, {:.2}) in the flange frame, about the {}): {}",
                kuka(&s.kuka_xyzabc),
                s.from_frame,
                s.rotation_deg,
                s.axis_ee[0],
                s.axis_ee[1],
                s.axis_ee[2],
                if s.pivot == "flange" { "flange" } else { "point the camera looks at" },
                s.reason
            );
        }
    }
    println!(
        "base-to-base  largest 1-sigma of the registration {:.3} mm (rotations at the clouds' {:.2} m RMS radius)",
        r.plan.base_sigma_mm, r.plan.radius_m
    );
    if r.plan.base_weak_directions.is_empty() {
        println!("  no weak direction: more views of the shared scene would change little");
    }
    for w in &r.plan.base_weak_directions {
        println!(
            "  weak          {} (1-sigma {:.2} mm)",
            w.description, w.sigma_mm
        );
    }
    for s in &r.plan.base_suggested_poses {
        println!(
            "  capture {:<6}{} (frame {} turned {:+.0} deg about the camera's {} axis, about the point it looks at): sees {} points only the other robot saw; largest 1-sigma -> {:.3} mm",
            s.robot,
            kuka(&s.kuka_xyzabc),
            s.from_frame,
            s.rotation_deg,
            if s.axis_camera[0].abs() > 0.5 { "x" } else { "y" },
            s.new_shared_points,
            s.predicted_sigma_mm
        );
    }
    if !r.plan.base_weak_directions.is_empty() && r.plan.base_suggested_poses.is_empty() {
        println!(
            "  none of the {} candidate views (each existing camera turned about the point it looks at) would see more of the other robot's scene",
            r.plan.candidates
        );
    }
    println!("total (ms)    {:.0}", r.total_ms);
}
