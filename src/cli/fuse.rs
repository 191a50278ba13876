//! `depthcal fuse`: fuse one robot's depth frames of a cell dataset into a base-frame cloud.

use anyhow::Context;
use clap::Args as ClapArgs;
use depthcal::cell::Cell;
use depthcal::fusion::{fuse_robot, CropBox, FuseConfig};
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
    /// Workspace crop box in the base frame, metres: xmin,ymin,zmin,xmax,ymax,zmax.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 6,
        allow_negative_numbers = true
    )]
    pub crop: Option<Vec<f64>>,
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

/// Runs `depthcal fuse`.
pub fn run(a: Args) -> anyhow::Result<()> {
    let cell = Cell::open(&a.cell_dir)?;
    let name = a
        .robot
        .clone()
        .unwrap_or_else(|| cell.manifest.reference.clone());
    let robot = cell.robot(&name)?;
    let mut cfg = FuseConfig {
        voxel_size_m: a.voxel,
        ..Default::default()
    };
    cfg.deproject.min_depth_m = a.min_depth;
    cfg.deproject.max_depth_m = a.max_depth;
    if let Some(c) = &a.crop {
        cfg.crop = Some(CropBox {
            min: [c[0], c[1], c[2]],
            max: [c[3], c[4], c[5]],
        });
    }
    if a.no_outlier_removal {
        cfg.outlier = None;
    }
    if a.no_normals {
        cfg.normals = None;
    }
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
    depthcal::io::write_cloud(&a.output, &fused.cloud)?;
    let s = &fused.stats;
    if a.json {
        let out = serde_json::json!({
            "robot": name,
            "output": a.output,
            "frames": s.frames,
            "points_in": s.points_in,
            "points_cropped": s.points_cropped,
            "voxel_size_m": s.voxel_size_m,
            "voxels": s.voxels,
            "sparse_removed": s.sparse_removed,
            "outliers_removed": s.outliers_removed,
            "points": s.points_out,
            "normals": fused.cloud.normals.is_some(),
            "seconds": seconds,
        });
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
