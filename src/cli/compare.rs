//! `depthcal compare CELL_DIR`: every calibration method the cell's data allows, on the same fused clouds,
//! in one table.

use super::methods::{CalibrateSettings, Method};
use anyhow::Result;
use clap::Args as ClapArgs;
use depthcal::cell::Cell;
use depthcal::methods::{compare_methods, Comparison, MethodOutcome};
use depthcal::report::ComparisonReport;
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
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = a.settings.config()?;
    let cell = Cell::open(&a.cell)?;
    // A malformed optional ground_truth.json is reported before any work.
    cell.ground_truth()?;
    let quiet = a.json;
    let cmp = compare_methods(&cell, &a.methods, &cfg, !a.no_refine, &mut |s| {
        if !quiet {
            eprintln!("{s} ...");
        }
    })?;
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
