//! `depthcal profile SOURCE TARGET` / `depthcal profile --synthetic N`: where the registration spends
//! its time.

use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::io::{read_cloud, read_matrix_file, write_cloud, write_matrix_file};
use depthcal::profile::{nearby_guess, profile, synthetic_pair, ProfileConfig, ProfileReport};
use depthcal::registration::RegisterConfig;
use std::path::PathBuf;

/// Arguments of `depthcal profile`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cloud to move (.ply, .pcd, .xyz/.txt/.pts, .npy); not with --synthetic.
    source: Option<PathBuf>,
    /// The cloud to align to.
    target: Option<PathBuf>,
    /// Profile a generated pair of about N points a side (planes, boxes, cylinders, 1 mm noise, partial
    /// overlap, a known transform) instead of two files.
    #[arg(long, value_name = "N")]
    synthetic: Option<usize>,
    /// With --synthetic: write the generated pair to this directory (`source.ply`, `target.ply`, the true
    /// transform `truth.txt` and the fine stage's starting guess `init.txt`, 3° / 5 cm off it) and stop,
    /// so other tools can be run on the same clouds.
    #[arg(long, value_name = "DIR", requires = "synthetic")]
    write_pair: Option<PathBuf>,
    /// Initial guess (a 4x4 matrix file or a previous --json output): skips the global stage.
    #[arg(long)]
    init: Option<PathBuf>,
    /// A known true SOURCE→TARGET transform: the error against it is reported.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Global-stage voxel size (cloud units; default chosen from the data).
    #[arg(long)]
    voxel: Option<f64>,
    /// The stages to report, comma-separated (read, scale, downsample_normals, fpfh, match, ransac,
    /// verify, icp, quality, total); without any global stage only the fine registration runs, from
    /// --init (synthetic pairs: from a guess 3° / 5 cm off the truth).
    #[arg(long, value_delimiter = ',')]
    stages: Vec<String>,
    /// Runs of the pipeline; the table gives the median and the fastest.
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Seed of the randomised steps (and of the synthetic pair).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// A JSON file with a (partial) registration configuration.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let mut cfg: RegisterConfig =
        super::output::read_config(a.config.as_deref(), "registration configuration")?;
    cfg.seed = a.seed;
    if a.voxel.is_some() {
        cfg.voxel = a.voxel;
    }
    cfg.validate()?;
    let pcfg = ProfileConfig {
        repeat: a.repeat,
        stages: a.stages.clone(),
    };
    pcfg.validate()?;
    let init = a.init.as_ref().map(read_matrix_file).transpose()?;
    let mut truth = a.truth.as_ref().map(read_matrix_file).transpose()?;
    let report = match (&a.synthetic, &a.source, &a.target) {
        (Some(n), None, None) => {
            let (s, t, pose) = synthetic_pair(*n, a.seed)?;
            if let Some(dir) = &a.write_pair {
                return write_pair(dir, &s, &t, &pose);
            }
            truth = truth.or(Some(pose));
            let init = init.or_else(|| pcfg.fine_only().then(|| nearby_guess(&pose)));
            let input = format!("synthetic {n} (seed {})", a.seed);
            profile(
                &input,
                &mut || Ok((s.clone(), t.clone())),
                init.as_ref(),
                truth.as_ref(),
                &cfg,
                &pcfg,
            )?
        }
        (None, Some(sp), Some(tp)) => {
            let input = format!("{} -> {}", sp.display(), tp.display());
            profile(
                &input,
                &mut || Ok((read_cloud(sp)?, read_cloud(tp)?)),
                init.as_ref(),
                truth.as_ref(),
                &cfg,
                &pcfg,
            )
            .with_context(|| format!("profiling {input}"))?
        }
        (Some(_), _, _) => {
            anyhow::bail!("--synthetic N replaces SOURCE and TARGET: give one or the other")
        }
        _ => anyhow::bail!("give SOURCE and TARGET, or --synthetic N"),
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_table(&report);
    }
    Ok(())
}

/// Writes a generated pair, its truth and the fine stage's guess into `dir` (created if missing).
fn write_pair(
    dir: &std::path::Path,
    source: &depthcal::PointCloud,
    target: &depthcal::PointCloud,
    truth: &nalgebra::Isometry3<f64>,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    write_cloud(dir.join("source.ply"), source)?;
    write_cloud(dir.join("target.ply"), target)?;
    write_matrix_file(dir.join("truth.txt"), truth)?;
    write_matrix_file(dir.join("init.txt"), &nearby_guess(truth))?;
    println!(
        "wrote {} + {} points, truth.txt and init.txt to {}",
        source.len(),
        target.len(),
        dir.display()
    );
    Ok(())
}

fn count(n: Option<usize>) -> String {
    n.map_or("-".into(), |n| n.to_string())
}

fn rate(r: Option<f64>) -> String {
    match r {
        Some(r) if r >= 1e6 => format!("{:.2} M/s", r / 1e6),
        Some(r) if r >= 1e3 => format!("{:.1} k/s", r / 1e3),
        Some(r) => format!("{r:.0} /s"),
        None => "-".into(),
    }
}

fn print_table(r: &ProfileReport) {
    println!(
        "{}: {} + {} points, {} threads, {} runs{}",
        r.input,
        r.points[0],
        r.points[1],
        r.threads,
        r.repeat,
        if r.fine_only { ", fine stage only" } else { "" }
    );
    println!(
        "{:<20} {:>10} {:>10} {:>10} {:>6} {:>12} {:>12} {:>12}",
        "stage", "wall ms", "min ms", "cpu ms", "cpu/w", "in", "out", "in/s"
    );
    for s in &r.stages {
        println!(
            "{:<20} {:>10.1} {:>10.1} {:>10} {:>6} {:>12} {:>12} {:>12}",
            s.name,
            s.wall_ms,
            s.wall_ms_min,
            s.cpu_ms.map_or("-".into(), |c| format!("{c:.1}")),
            s.parallelism.map_or("-".into(), |p| format!("{p:.2}")),
            count(s.items_in),
            count(s.items_out),
            rate(s.items_per_s)
        );
    }
    for (k, l) in r.icp_levels.iter().enumerate() {
        println!(
            "ICP level {k}: voxel {:.4}, {} source / {} target points, prepared in {:.1} ms, {} iterations in {:.1} ms, {}, {}",
            l.voxel,
            l.source_points,
            l.target_points,
            l.prepare_ms,
            l.iterations.len(),
            l.iterate_ms,
            if l.converged {
                "converged"
            } else {
                "NOT converged"
            },
            rate(Some(l.queries_per_s)).replace("/s", " queries/s")
        );
        for (i, it) in l.iterations.iter().enumerate() {
            let step = match (it.step_deg, it.step_translation) {
                (Some(r), Some(t)) => format!("  step {r:.2e} deg {t:.2e}"),
                _ => String::new(),
            };
            println!(
                "  {i:>3}  {:>8.2} ms  pairs {:>9}  kept {:>9}  residual {:.3e}{step}",
                it.time_ms, it.pairs, it.kept, it.residual
            );
        }
    }
    if let Some(b) = r.peak_memory_bytes {
        println!("peak memory {:.1} MB", b as f64 / 1e6);
    }
    if let Some(e) = &r.error_vs_truth {
        println!(
            "error vs truth {:.4} deg / {:.3} mm; converged {}, fitness {:.3}",
            e.rotation_deg,
            e.translation_m * 1e3,
            r.converged,
            r.fitness
        );
    }
    if !r.deterministic {
        println!("warning: the runs did not give bit-identical transforms");
    }
}
