//! `depthcal compare CELL_DIR`: every calibration method the cell's data allows, on the same fused clouds,
//! in one table.

use super::methods::{available, build, CalibrateSettings, Method, MethodInputs};
use super::output::matrix4_json;
use anyhow::Result;
use clap::Args as ClapArgs;
use depthcal::calibration::robot_to_robot::{fuse_cell, refine_cell, Calibration, FusedCell};
use depthcal::cell::Cell;
use depthcal::geometry::transform::pose_error;
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

/// One row of the table.
struct Row {
    method: Method,
    outcome: std::result::Result<(Calibration, f64), String>,
    skipped: bool,
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
    let mut plan = available(&cell);
    if !a.methods.is_empty() {
        if let Some(m) = a.methods.iter().find(|m| **m == Method::Guess) {
            anyhow::bail!(
                "compare runs the methods that need no input file; {} is not one",
                m.name()
            );
        }
        plan.retain(|(m, _)| a.methods.contains(m));
        // Asked for explicitly: run it and report its error rather than skipping it.
        for (_, reason) in plan.iter_mut() {
            if reason.as_deref().is_some_and(|r| r.starts_with("no [")) {
                *reason = None;
            }
        }
    }
    let needs_fusion = !a.no_refine || plan.iter().any(|(m, r)| *m == Method::Depth && r.is_none());
    let fused = if needs_fusion {
        if !a.json {
            eprintln!("fusing both robots' frames ...");
        }
        fuse_cell(&cell, &cfg)?
    } else {
        FusedCell::without_clouds(&cell, &cfg)?
    };
    let mut rows = Vec::new();
    for (method, reason) in plan {
        if let Some(r) = reason {
            rows.push(Row {
                method,
                outcome: Err(r),
                skipped: true,
            });
            continue;
        }
        if !a.json {
            eprintln!("running {} ...", method.name());
        }
        let t0 = Instant::now();
        let outcome = (|| -> Result<Calibration> {
            let (init, _, _) = build(method, &cell, &MethodInputs::default(), &cfg)?;
            Ok(refine_cell(
                &cell,
                &fused,
                init.as_ref(),
                &cfg,
                !a.no_refine,
                &mut |_| {},
            )?)
        })();
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        rows.push(Row {
            method,
            outcome: outcome.map(|c| (c, ms)).map_err(|e| format!("{e:#}")),
            skipped: false,
        });
    }
    // Disagreement: the largest difference of each result from the other methods' results.
    let results: Vec<(Method, nalgebra::Isometry3<f64>)> = rows
        .iter()
        .filter_map(|r| {
            r.outcome
                .as_ref()
                .ok()
                .map(|(c, _)| (r.method, c.transform))
        })
        .collect();
    let disagreement = |m: Method, t: &nalgebra::Isometry3<f64>| -> Option<(f64, f64)> {
        results
            .iter()
            .filter(|(o, _)| *o != m)
            .map(|(_, u)| pose_error(t, u))
            .fold(None, |acc: Option<(f64, f64)>, (r, tr)| {
                Some(acc.map_or((r, tr), |(ar, at)| (ar.max(r), at.max(tr))))
            })
    };
    if let Some(dir) = &a.report {
        let runs: Vec<depthcal::viz::MethodRun> = rows
            .iter()
            .map(|r| depthcal::viz::MethodRun {
                method: r.method.name(),
                outcome: r.outcome.as_ref().map(|(c, _)| c).map_err(|e| e.as_str()),
                skipped: r.skipped,
                time_ms: r.outcome.as_ref().map_or(0.0, |(_, ms)| *ms),
            })
            .collect();
        let trusted = runs
            .iter()
            .any(|r| r.outcome.is_ok_and(|c| c.trust.trusted));
        super::visual::write(dir, trusted, || {
            depthcal::viz::comparison_report(&cell, &fused, &runs)
        })?;
    }
    let fuse_ms = fused.fuse_ms;
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    if a.json {
        let err = |e: Option<(f64, f64)>| {
            e.map(|(r, t)| serde_json::json!({"rotation_deg": r, "translation_mm": t * 1e3}))
        };
        let list: Vec<serde_json::Value> = rows
            .iter()
            .map(|r| match &r.outcome {
                Ok((c, ms)) => serde_json::json!({
                    "method": r.method.name(),
                    "status": "ok",
                    "refined": c.refined,
                    "transform": matrix4_json(&c.transform),
                    "error_vs_truth": err(c.error_vs_truth),
                    "initial": {"transform": matrix4_json(&c.initial.transform),
                                "error_vs_truth": err(c.initial_error_vs_truth),
                                "sigma_rotation_deg": c.initial.sigma_rotation_deg,
                                "sigma_translation_mm": c.initial.sigma_translation_m * 1e3,
                                "detail": c.initial.detail},
                    "disagreement": err(disagreement(r.method, &c.transform)),
                    "trusted": c.trust.trusted,
                    "reasons": c.trust.reasons,
                    "time_ms": ms,
                }),
                Err(e) => serde_json::json!({
                    "method": r.method.name(),
                    "status": if r.skipped { "skipped" } else { "failed" },
                    "reason": e,
                }),
            })
            .collect();
        let v = serde_json::json!({
            "cell": a.cell,
            "refined": !a.no_refine,
            "fuse_ms": fuse_ms,
            "methods": list,
            "total_ms": total_ms,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return verdict(&rows);
    }
    let truth = cell.ground_truth()?.and_then(|g| g.t_base1_base2).is_some();
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
    for r in &rows {
        match &r.outcome {
            Ok((c, ms)) => println!(
                "{:<13} {:>22} {:>22} {:>22} {:>9.2}",
                r.method.name(),
                fmt(c.initial_error_vs_truth),
                if c.refined {
                    fmt(c.error_vs_truth)
                } else {
                    "-".into()
                },
                fmt(disagreement(r.method, &c.transform)),
                ms / 1e3
            ),
            Err(e) => println!(
                "{:<13} {}: {}",
                r.method.name(),
                if r.skipped { "skipped" } else { "FAILED" },
                e.lines().next().unwrap_or("")
            ),
        }
    }
    println!(
        "fusing both robots once: {:.2} s; total {:.2} s{}",
        fuse_ms / 1e3,
        total_ms / 1e3,
        if truth {
            ""
        } else {
            " (no ground_truth.json: no errors)"
        }
    );
    for r in &rows {
        if let Ok((c, _)) = &r.outcome {
            if !c.trust.trusted {
                println!(
                    "{} not trusted: {}",
                    r.method.name(),
                    c.trust.reasons.join("; ")
                );
            }
        }
    }
    verdict(&rows)
}

/// Exit status of the comparison: an error when every requested method failed, untrusted when none gave a
/// trusted result.
fn verdict(rows: &[Row]) -> Result<()> {
    let ran: Vec<&Calibration> = rows
        .iter()
        .filter_map(|r| r.outcome.as_ref().ok().map(|(c, _)| c))
        .collect();
    if ran.is_empty() {
        anyhow::bail!("every method failed or was skipped");
    }
    if ran.iter().any(|c| c.trust.trusted) {
        Ok(())
    } else {
        Err(super::Untrusted(vec!["no method gave a trusted result".into()]).into())
    }
}
