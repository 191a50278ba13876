//! `depthcal register SOURCE TARGET`.

use super::guard::{check_output_file, Inputs};
use super::output::{matrix4_text, spinner};
use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::io::{read_cloud, read_matrix_file, write_cloud};
use depthcal::registration::{register_with_progress, RegisterConfig, Registration};
use depthcal::report::{RegistrationInputs, RegistrationReport};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `depthcal register`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cloud to move (.ply, .pcd, .xyz/.txt/.pts, .npy).
    source: PathBuf,
    /// The cloud to align to.
    target: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Write the source, transformed into the target frame, to this file (.ply or .xyz).
    #[arg(long, short)]
    output: Option<PathBuf>,
    /// Write a visual report into DIR (created if missing; also for an untrusted result): report.html (opens
    /// offline) and the PNG snapshots overview.png, initial.png, residual.png (docs/report.md).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// Initial guess (a 4x4 matrix file, or a previous --json output): skips the global stage.
    #[arg(long)]
    init: Option<PathBuf>,
    /// Seed of the randomised steps (results are identical for a seed at any thread count).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Global-stage voxel size in the clouds' unit (default: chosen from the data).
    #[arg(long)]
    voxel: Option<f64>,
    /// A JSON file with a (partial) registration configuration; see docs/register.md.
    #[arg(long)]
    config: Option<PathBuf>,
    /// A known true SOURCE→TARGET transform (4x4 matrix file): also print the error against it.
    #[arg(long)]
    truth: Option<PathBuf>,
}

/// Runs the command: settings and checks → read → register (writing `--output`) → `--report` → print.
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let cfg = settings(&a)?;
    check_outputs(&a)?;
    let init = a.init.as_ref().map(read_matrix_file).transpose()?;
    let truth = a.truth.as_ref().map(read_matrix_file).transpose()?;
    let pb = spinner("reading clouds");
    let t_read = Instant::now();
    let source = read_cloud(&a.source)?;
    let target = read_cloud(&a.target)?;
    let read_ms = t_read.elapsed().as_secs_f64() * 1e3;
    // The units warning now, before a registration that may take a while (the library adds it to the
    // result's warnings too; it is not printed twice).
    let early = depthcal::registration::extent::check_extents(&source, &target, cfg.voxel)?.units;
    if let Some(u) = &early {
        pb.suspend(|| eprintln!("warning: {u}"));
    }
    let mut reg = register_with_progress(&source, &target, init.as_ref(), &cfg, &mut |stage| {
        pb.set_message(stage.to_string())
    })
    .with_context(|| {
        format!(
            "registering {} onto {}",
            a.source.display(),
            a.target.display()
        )
    })?;
    reg.timings_ms.insert(0, ("read".into(), read_ms));
    if let Some(out) = a.output.as_ref().filter(|_| reg.trust.trusted) {
        pb.set_message("writing");
        let t_w = Instant::now();
        let moved = source.transformed(&reg.transform);
        write_cloud(out, &moved)?;
        reg.timings_ms
            .push(("write".into(), t_w.elapsed().as_secs_f64() * 1e3));
    }
    pb.finish_and_clear();
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    for w in reg.warnings.iter().filter(|w| Some(*w) != early.as_ref()) {
        eprintln!("warning: {w}");
    }
    if let (Some(out), false) = (&a.output, reg.trust.trusted) {
        eprintln!(
            "warning: {} not written: the result is not trusted",
            out.display()
        );
    }
    if let Some(dir) = &a.report {
        let name = |p: &std::path::Path| p.display().to_string();
        super::visual::write(dir, reg.trust.trusted, || {
            depthcal::viz::registration_report(
                &name(&a.source),
                &source,
                &name(&a.target),
                &target,
                &reg,
            )
        })?;
    }
    if a.json {
        let report = RegistrationReport::new(
            &reg,
            &RegistrationInputs {
                source: Some(a.source.display().to_string()),
                target: Some(a.target.display().to_string()),
                points: [source.len(), target.len()],
                seed: a.seed,
                truth,
                total_ms,
            },
        );
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let error = truth.map(|t| depthcal::geometry::transform::pose_error(&reg.transform, &t));
        print_text(&a, &reg, error, total_ms);
    }
    super::gate(&reg.trust)
}

/// The configuration: the `--config` file (or the defaults) with the flags applied, checked.
fn settings(a: &Args) -> Result<RegisterConfig> {
    let mut cfg: RegisterConfig =
        super::output::read_config(a.config.as_deref(), "registration configuration")?;
    cfg.seed = a.seed;
    if a.voxel.is_some() {
        cfg.voxel = a.voxel;
    }
    cfg.validate().with_context(|| {
        super::output::config_source(a.config.as_deref(), "the registration configuration")
    })?;
    Ok(cfg)
}

/// Everything checkable before any work: `--output` (not an input, its directory, its extension) and
/// `--report` (a directory register may write into).
fn check_outputs(a: &Args) -> Result<()> {
    let mut inputs = Inputs::default();
    inputs.add("SOURCE", &a.source);
    inputs.add("TARGET", &a.target);
    inputs.add_opt("--init", a.init.as_ref());
    inputs.add_opt("--truth", a.truth.as_ref());
    inputs.add_opt("--config", a.config.as_ref());
    if let Some(out) = &a.output {
        check_output_file("--output", out, &["ply", "xyz", "txt"])?;
        inputs.check_output("--output", out)?;
    }
    if let Some(dir) = &a.report {
        super::guard::check_owned_dir(
            &inputs,
            "--report",
            dir,
            &depthcal::viz::REPORT_FILES,
            "register",
        )?;
    }
    Ok(())
}

/// The human-readable result: the transform, quality, 1-σ, the global stage, the error against `--truth`,
/// timings, and whether it is trusted.
fn print_text(a: &Args, reg: &Registration, error: Option<(f64, f64)>, total_ms: f64) {
    println!("{} -> {}", a.source.display(), a.target.display());
    println!(
        "transform (maps source into target):\n{}",
        matrix4_text(&reg.transform)
    );
    let q = reg.transform.rotation;
    let tr = reg.transform.translation.vector;
    println!(
        "xyz {:.6} {:.6} {:.6}  quaternion (x y z w) {:.6} {:.6} {:.6} {:.6}  rotation {:.3} deg",
        tr.x,
        tr.y,
        tr.z,
        q.i,
        q.j,
        q.k,
        q.w,
        q.angle().to_degrees()
    );
    println!(
        "fitness {:.3}  inlier RMSE {:.5}  overlap {:.3}  converged {}  ICP iterations {}",
        reg.fitness, reg.inlier_rmse, reg.overlap, reg.converged, reg.iterations
    );
    let sd: Vec<String> = (0..6)
        .map(|k| format!("{:.2e}", reg.covariance[(k, k)].max(0.0).sqrt()))
        .collect();
    println!("1-sigma [rx ry rz (rad), tx ty tz]: {}", sd.join(" "));
    if let Some(g) = &reg.global {
        println!(
            "global stage: {} correspondences, {} inliers, {} RANSAC samples, voxel {:.4}",
            g.correspondences, g.inliers, g.iterations, reg.voxel
        );
    }
    if let Some((r, t)) = error {
        println!("error against the truth: rotation {r:.4} deg, translation {t:.6} (cloud units)");
    }
    let times: Vec<String> = reg
        .timings_ms
        .iter()
        .map(|(k, v)| format!("{k} {v:.1}"))
        .collect();
    println!("timings (ms): {}  total {total_ms:.1}", times.join(", "));
    println!(
        "surface agreement {:.3}  trusted {}",
        reg.surface_agreement, reg.trust.trusted
    );
    if let Some(x) = &reg.ambiguity {
        println!(
            "ambiguous: runner-up {:.2} deg / {:.4} away scores {:.0}% of the best:\n{}",
            x.rotation_deg,
            x.translation,
            x.score_ratio * 1e2,
            matrix4_text(&x.runner_up)
        );
    }
    for s in &reg.trust.suggestions {
        println!("try: {s}");
    }
}
