//! `depthcal compare CELL_DIR`: every calibration method the cell's data allows, on the same fused clouds,
//! in one table; on a cell of three or more robots, every route to each base (the joint solution, the
//! robot's pair with the reference, each chain of two pairs) side by side.

use super::methods::{CalibrateSettings, Method};
use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::cell::Cell;
use depthcal::methods::{compare_methods, Comparison, MethodOutcome};
use depthcal::report::{ComparisonReport, RoutesReport};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `depthcal compare`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (with cell.toml).
    cell: PathBuf,
    /// Only these methods (comma-separated: depth, checkerboard, marker, features); default: every method
    /// the cell's data allows.
    #[arg(long, value_delimiter = ',', value_enum)]
    methods: Vec<Method>,
    /// Compare the initialisers' estimates only (no trimmed ICP; the clouds are fused only if the depth
    /// method runs).
    #[arg(long)]
    no_refine: bool,
    #[command(flatten)]
    settings: CalibrateSettings,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Write a visual report into DIR (created if missing; also when no method is trusted): report.html
    /// (opens offline) and the PNG snapshots overview.png, initial.png, residual.png (docs/report.md).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = a.settings.config()?;
    let cell = Cell::open(&a.cell)?;
    // A malformed optional ground_truth.json is reported before any work.
    cell.ground_truth()?;
    if let Some(dir) = &a.report {
        let mut inputs = super::guard::Inputs::default();
        inputs.add_cell(&cell);
        inputs.add_opt("--config", a.settings.config_path());
        super::guard::check_owned_dir(
            &inputs,
            "--report",
            dir,
            &depthcal::viz::REPORT_FILES,
            "compare",
        )?;
    }
    if cell.robots.len() > 2 {
        return run_robots(&a, &cell, &cfg, start);
    }
    let quiet = a.json;
    let (cmp, fused) = compare_methods(&cell, &a.methods, &cfg, !a.no_refine, &mut |s| {
        if !quiet {
            eprintln!("{s} ...");
        }
    })?;
    if let Some(dir) = &a.report {
        let runs: Vec<depthcal::viz::MethodRun> = cmp
            .rows
            .iter()
            .map(|r| depthcal::viz::MethodRun {
                method: r.method.name(),
                outcome: match &r.outcome {
                    MethodOutcome::Ran(c, _) => Ok(c.as_ref()),
                    MethodOutcome::Skipped(e) | MethodOutcome::Failed(e) => Err(e.as_str()),
                },
                skipped: matches!(r.outcome, MethodOutcome::Skipped(_)),
                time_ms: match &r.outcome {
                    MethodOutcome::Ran(_, ms) => *ms,
                    _ => 0.0,
                },
            })
            .collect();
        super::visual::write(dir, cmp.any_trusted(), || {
            depthcal::viz::comparison_report(&cell, &fused, &runs)
        })?;
    }
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    if a.json {
        let report = ComparisonReport::new(&cmp, &a.cell.display().to_string(), total_ms);
        println!("{}", serde_json::to_string_pretty(&report)?);
        return verdict(&cmp);
    }
    let truth = cmp.has_truth;
    let fmt = |e: Option<(f64, f64)>| {
        e.map_or("-".to_string(), |(r, t)| {
            format!("{r:.3}° / {:.2} mm", t * 1e3)
        })
    };
    println!(
        "{:<13} {:>22} {:>22} {:>22} {:>9}",
        "method",
        if truth { "initial vs truth" } else { "initial" },
        if a.no_refine {
            "(not refined)"
        } else if truth {
            "refined vs truth"
        } else {
            "refined"
        },
        "max disagreement",
        "time (s)"
    );
    for r in &cmp.rows {
        match &r.outcome {
            MethodOutcome::Ran(c, ms) => println!(
                "{:<13} {:>22} {:>22} {:>22} {:>9.2}",
                r.method.name(),
                fmt(c.initial_error_vs_truth),
                if c.refined {
                    fmt(c.error_vs_truth)
                } else {
                    "-".into()
                },
                fmt(r.disagreement),
                ms / 1e3
            ),
            MethodOutcome::Skipped(e) | MethodOutcome::Failed(e) => println!(
                "{:<13} {}: {}",
                r.method.name(),
                if matches!(r.outcome, MethodOutcome::Skipped(_)) {
                    "skipped"
                } else {
                    "FAILED"
                },
                e.lines().next().unwrap_or("")
            ),
        }
    }
    println!(
        "fusing both robots once: {:.2} s; total {:.2} s{}",
        cmp.fuse_ms / 1e3,
        total_ms / 1e3,
        if truth {
            ""
        } else {
            " (no ground_truth.json: no errors)"
        }
    );
    for r in &cmp.rows {
        if let MethodOutcome::Ran(c, _) = &r.outcome {
            if !c.trust.trusted {
                println!(
                    "{} not trusted: {}",
                    r.method.name(),
                    c.trust.reasons.join("; ")
                );
            }
        }
    }
    verdict(&cmp)
}

/// A cell of three or more robots: the depth method's routes to each base side by side (the joint
/// solution, the robot's pair with the reference, each chain of two pairs; `calibration::routes`).
fn run_robots(
    a: &Args,
    cell: &Cell,
    cfg: &depthcal::calibration::robot_to_robot::CalibrateConfig,
    start: Instant,
) -> Result<()> {
    let n = cell.robots.len();
    if a.methods.iter().any(|m| *m != Method::Depth) {
        anyhow::bail!(
            "the cell names {n} robots: compare on such a cell sets the depth method's routes to each base side by side (--methods depth); the image methods calibrate one pair"
        );
    }
    if a.no_refine {
        anyhow::bail!("the cell names {n} robots: --no-refine is for cells of two robots");
    }
    let init = depthcal::methods::build(
        Method::Depth,
        cell,
        &depthcal::methods::MethodInputs::default(),
        cfg,
    )?
    .0;
    let quiet = a.json;
    let (c, fused) =
        depthcal::calibration::multi_robot::calibrate_robots(cell, init.as_ref(), cfg, &mut |s| {
            if !quiet {
                eprintln!("{s} ...");
            }
        })
        .with_context(|| format!("calibrating {}", a.cell.display()))?;
    let truths = depthcal::calibration::routes::true_bases(cell, &c)?;
    let routes = depthcal::calibration::routes::robot_routes(&c, &truths);
    if let Some(dir) = &a.report {
        let frames = depthcal::geometry::robot_formats::Frames {
            parent: cell.frame_id(&c.reference),
            child: cell.frame_id(&c.robots[0].name),
        };
        let ids = cell.other_frame_ids(&frames.child);
        let report = depthcal::report::CalibrationReport::with_robots(
            &c,
            &a.cell.display().to_string(),
            &frames,
            &ids,
            start.elapsed().as_secs_f64() * 1e3,
        );
        super::visual::write(dir, c.trust.trusted, || {
            depthcal::viz::robots_report(cell, &c, &fused, &report, &frames)
        })?;
    }
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let report = RoutesReport::new(&c, &routes, &a.cell.display().to_string(), total_ms);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return super::gate(&c.trust);
    }
    let fmt = |e: Option<&depthcal::report::ErrorReport>| {
        e.map_or("-".to_string(), |e| {
            format!("{:.3}° / {:.2} mm", e.rotation_deg, e.translation_m * 1e3)
        })
    };
    let truth = truths.iter().any(Option::is_some);
    println!(
        "every route to each base (reference {}); a route's 1-sigma is propagated from its pairs'",
        c.reference
    );
    for r in &report.robots {
        println!();
        println!(
            "{}{}",
            r.name,
            if r.trusted {
                ""
            } else {
                " (NOT calibrated or NOT trusted in the joint solution)"
            }
        );
        println!(
            "  {:<28} {:>8} {:>22} {:>24} {:>22}",
            "route",
            "trusted",
            "off the joint solution",
            "1-sigma (max deg / mm)",
            if truth { "vs ground truth" } else { "" }
        );
        for x in &r.routes {
            let s = &x.sigma;
            println!(
                "  {:<28} {:>8} {:>22} {:>24} {:>22}",
                x.route,
                if x.trusted { "yes" } else { "no" },
                fmt(x.from_joint.as_ref()),
                format!(
                    "{:.3}° / {:.2} mm",
                    s.rotation_deg.iter().fold(0.0f64, |m, v| m.max(*v)),
                    s.translation_m.iter().fold(0.0f64, |m, v| m.max(*v)) * 1e3
                ),
                fmt(x.error_vs_truth.as_ref())
            );
        }
        if let Some(b) = &r.best_vs_truth {
            println!("  closest to the truth: {b}");
        }
    }
    println!();
    println!(
        "total {:.2} s{}",
        total_ms / 1e3,
        if truth {
            ""
        } else {
            " (no ground_truth.json: no errors)"
        }
    );
    for w in &c.warnings {
        println!("warning: {w}");
    }
    super::gate(&c.trust)
}

/// Exit status of the comparison: an error when every requested method failed, untrusted when none gave a
/// trusted result.
fn verdict(c: &Comparison) -> Result<()> {
    if c.ran().next().is_none() {
        anyhow::bail!("every method failed or was skipped");
    }
    if c.any_trusted() {
        Ok(())
    } else {
        Err(super::Untrusted(vec!["no method gave a trusted result".into()]).into())
    }
}
