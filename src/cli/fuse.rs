//! `depthcal fuse`: fuse one robot's depth frames of a cell dataset into a base-frame cloud.

use super::guard::{check_output_file, Inputs};
use anyhow::Context;
use clap::Args as ClapArgs;
use depthcal::cell::Cell;
use depthcal::fusion::{check_fused_size, fuse_robot, CropBox, FuseOptions};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `depthcal fuse`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (holding cell.toml).
    pub cell_dir: PathBuf,
    /// The robot whose frames are fused (default: the cell's reference robot).
    #[arg(long)]
    pub robot: Option<String>,
    /// Output cloud (.ply, or .xyz/.txt), in the robot's base frame, metres. Written atomically.
    #[arg(long, short)]
    pub output: PathBuf,
    /// Voxel edge in metres (default: 2x the median pixel footprint of the first frame).
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Nearest depth kept, metres.
    #[arg(long, default_value_t = 0.1)]
    pub min_depth: f64,
    /// Farthest depth kept, metres.
    #[arg(long, default_value_t = 10.0)]
    pub max_depth: f64,
    /// Workspace crop box in the base frame, metres: x0,y0,z0,x1,y1,z1 (one argument, comma separated;
    /// the corners in any order).
    #[arg(
        long,
        value_name = "x0,y0,z0,x1,y1,z1",
        allow_hyphen_values = true,
        value_parser = parse_crop
    )]
    pub crop: Option<CropBox>,
    /// Skip the statistical outlier removal.
    #[arg(long)]
    pub no_outlier_removal: bool,
    /// Skip normal estimation.
    #[arg(long)]
    pub no_normals: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Parses `x0,y0,z0,x1,y1,z1` (metres; commas, optionally with spaces) into a crop box.
pub fn parse_crop(s: &str) -> Result<CropBox, String> {
    let parts: Vec<&str> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .collect();
    if parts.len() != 6 {
        return Err(format!(
            "{s:?}: expected 6 numbers x0,y0,z0,x1,y1,z1 (metres, comma separated), got {}",
            parts.len()
        ));
    }
    let mut v = [0.0f64; 6];
    for (k, p) in parts.iter().enumerate() {
        v[k] = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{s:?}: {p:?} is not a finite number"))?;
    }
    CropBox::from_corners(&v).map_err(|e| format!("{s:?}: {e}"))
}

/// Runs `depthcal fuse`.
pub fn run(a: Args) -> anyhow::Result<()> {
    // Everything checkable before any work.
    check_output_file("--output", &a.output, &["ply", "xyz", "txt"])?;
    let cfg = FuseOptions {
        voxel_m: a.voxel,
        min_depth_m: a.min_depth,
        max_depth_m: a.max_depth,
        crop: a.crop,
        outlier_removal: !a.no_outlier_removal,
        normals: !a.no_normals,
    }
    .config()
    .context("--voxel, --min-depth, --max-depth, --crop")?;
    let cell = Cell::open(&a.cell_dir)?;
    let mut inputs = Inputs::default();
    inputs.add_cell(&cell);
    inputs.check_output("--output", &a.output)?;
    let name = a
        .robot
        .clone()
        .unwrap_or_else(|| cell.manifest.reference.clone());
    let robot = cell.robot(&name)?;
    let bar = ProgressBar::new(robot.frames.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(format!("fusing {name}"));
    let start = Instant::now();
    let fused = fuse_robot(robot, &cfg, &|done| bar.set_position(done as u64));
    bar.finish_and_clear();
    let fused =
        fused.with_context(|| format!("fusing robot {name:?} of {}", a.cell_dir.display()))?;
    let seconds = start.elapsed().as_secs_f64();
    let s = &fused.stats;
    let few = check_fused_size(&name, s)
        .with_context(|| format!("{} not written", a.output.display()))?;
    if let Some(w) = few {
        eprintln!("warning: {w}");
    }
    depthcal::io::write_cloud(&a.output, &fused.cloud)?;
    if a.json {
        let out = depthcal::report::FusionReport::new(
            &fused,
            &name,
            Some(a.output.display().to_string()),
            seconds,
        );
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "robot {name}: {} frames, {} samples -> {} points (voxel {:.1} mm, {} outliers removed) in {:.2} s",
            s.frames,
            s.points_in,
            s.points_out,
            s.voxel_size_m * 1e3,
            s.outliers_removed,
            seconds
        );
        println!("wrote {}", a.output.display());
    }
    Ok(())
}
