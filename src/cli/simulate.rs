//! `depthcal simulate`: write a simulated cell dataset of two or more robots with ground truth.

use clap::Args as ClapArgs;
use depthcal::sim::{NoiseLevel, Resolution};
use std::path::PathBuf;

/// Arguments of `depthcal simulate`.
#[derive(ClapArgs)]
pub struct Args {
    /// The directory to write the cell dataset into (created; must be empty unless --force).
    pub out_dir: PathBuf,
    /// Seed of everything random; the same seed and options give the same bytes.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Frames per robot.
    #[arg(long)]
    pub frames: Option<usize>,
    /// Depth noise: none, low, default, high, or a factor of the default magnitudes.
    #[arg(long)]
    pub noise: Option<NoiseLevel>,
    /// How much of the scene both robots see, 0-1 (default 0.7); with more robots, what two robots share
    /// on average over the pairs.
    #[arg(long)]
    pub overlap: Option<f64>,
    /// Number of robots, 2-8 (default 2): the reference at 180 degrees round the table, the others evenly
    /// spaced; named left, right, robot3, robot4, ... (the config's `robot_names` if it names as many).
    #[arg(long, value_name = "N")]
    pub robots: Option<usize>,
    /// Depth resolution: 640x480 or 1280x720.
    #[arg(long)]
    pub resolution: Option<Resolution>,
    /// Number of objects on the table.
    #[arg(long)]
    pub objects: Option<usize>,
    /// Tilt the robot bases by up to 2 degrees (bases_level = false).
    #[arg(long)]
    pub tilted_bases: bool,
    /// Do not render colour images.
    #[arg(long)]
    pub no_color: bool,
    /// Put a checkerboard (--board COLSxROWS inner corners, --square edge, default 9x6 of 0.03 m) or a
    /// ChArUco board (--charuco SQUARES_XxSQUARES_Y, --square, --charuco-marker, --charuco-dict, default
    /// 7x5 squares of 0.04 m, 0.03 m DICT_4X4_50 markers) on the table, clear of objects; written as
    /// [board] in cell.toml and its pose in ground_truth.json.
    #[command(flatten)]
    pub board: super::vision_args::BoardArgs,
    /// Put N square fiducial markers (ids 0..N) on the table near its centre, clear of objects and of the
    /// board; written as [markers] in cell.toml and their poses in ground_truth.json.
    #[arg(long, value_name = "N")]
    pub markers: Option<u32>,
    /// Marker dictionary for --markers (4x4_50, 5x5_100, 6x6_250, tag36h11; default 4x4_50).
    #[arg(long, value_name = "NAME")]
    pub marker_dict: Option<String>,
    /// Marker black-square edge for --markers: metres or with a unit (default 0.08).
    #[arg(long, value_name = "SIZE", value_parser = depthcal::cell::board::parse_length_m)]
    pub marker_size: Option<f64>,
    /// Give the objects and the table a distinctive texture (for the 2D-feature method).
    #[arg(long)]
    pub textured: bool,
    /// A JSON file with any fields of SimConfig (see `docs/simulate.md`); the flags above override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write into a non-empty directory, replacing files of the same names.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Runs `depthcal simulate`: without the `sim` feature, an error saying how to build it.
#[cfg(not(feature = "sim"))]
pub fn run(a: Args) -> anyhow::Result<()> {
    anyhow::bail!(
        "depthcal simulate {}: this depthcal was built without the simulator (cargo feature `sim`, on by \
         default); rebuild with `cargo build --release --features sim`",
        a.out_dir.display()
    )
}

/// Runs `depthcal simulate`: settings from --config and the flags, a check of the output directory, the cell
/// generated and written, then its summary.
#[cfg(feature = "sim")]
pub fn run(a: Args) -> anyhow::Result<()> {
    use anyhow::Context;
    use depthcal::sim::SimCell;
    use std::time::Instant;
    let cfg = settings(&a)?;
    check_out_dir(&a)?;
    let start = Instant::now();
    let cell = SimCell::generate(&cfg)?;
    let stats = write_cell(&cell, &a.out_dir)
        .with_context(|| format!("writing the cell into {}", a.out_dir.display()))?;
    let seconds = start.elapsed().as_secs_f64();
    if a.json {
        let out = depthcal::report::SimulationReport::new(&cell, &cfg, &stats, &a.out_dir, seconds);
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print_text(&a, &cfg, &cell, &stats, seconds);
    }
    Ok(())
}

/// The simulator's settings: --config (or the defaults), then each flag given over it.
#[cfg(feature = "sim")]
fn settings(a: &Args) -> anyhow::Result<depthcal::sim::SimConfig> {
    let mut cfg: depthcal::sim::SimConfig =
        super::output::read_config(a.config.as_deref(), "SimConfig")?;
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    if let Some(k) = a.frames {
        cfg.frames = k;
    }
    if let Some(n) = a.robots {
        cfg.set_robots(n)?;
    }
    if let Some(n) = a.noise {
        cfg.noise_level = n;
        cfg.noise = None;
    }
    if let Some(o) = a.overlap {
        cfg.overlap = o;
    }
    if let Some(r) = a.resolution {
        cfg.resolution = r;
    }
    if let Some(n) = a.objects {
        cfg.scene.objects = n;
    }
    if a.tilted_bases {
        cfg.bases_level = false;
    }
    if a.no_color {
        cfg.color = false;
    }
    if a.board.given() {
        cfg.scene.board = Some(board_settings(
            a,
            cfg.scene.board.clone().unwrap_or_default(),
        )?);
    }
    if a.markers.is_some() || a.marker_dict.is_some() || a.marker_size.is_some() {
        let mut m = cfg.scene.markers.clone().unwrap_or_default();
        if let Some(n) = a.markers {
            m.ids = (0..n).collect();
        }
        if let Some(d) = &a.marker_dict {
            m.dictionary = d.clone();
        }
        if let Some(s) = a.marker_size {
            m.size_m = s;
        }
        cfg.scene.markers = Some(m);
    }
    if a.textured {
        cfg.scene.textured = true;
    }
    Ok(cfg)
}

/// The board flags over `b`: `--board` makes it a checkerboard, `--charuco` a ChArUco board (the default
/// one unless the config already had one), and the size flags apply to whichever it is.
#[cfg(feature = "sim")]
fn board_settings(
    a: &Args,
    mut b: depthcal::sim::SimBoardConfig,
) -> anyhow::Result<depthcal::sim::SimBoardConfig> {
    use anyhow::Context;
    if a.board.board.is_some() {
        b.charuco = None;
    }
    if a.board.charuco.is_some() && b.charuco.is_none() {
        b.charuco = Some(depthcal::sim::board::DEFAULT_CHARUCO);
    }
    if let Some(c) = &mut b.charuco {
        if let Some((x, y)) = a.board.charuco {
            (c.squares_x, c.squares_y) = (x, y);
        }
        if let Some(sq) = a.board.square {
            c.square_m = sq;
        }
        if let Some(m) = a.board.charuco_marker {
            c.marker_m = m;
        }
        if let Some(d) = &a.board.charuco_dict {
            c.dictionary = d.parse().context("--charuco-dict")?;
        }
    } else {
        if let Some((c, r)) = a.board.board {
            (b.cols, b.rows) = (c, r);
        }
        if let Some(sq) = a.board.square {
            b.square_m = sq;
        }
    }
    Ok(b)
}

/// Refuses an output path that is a file, or a non-empty directory without --force.
#[cfg(feature = "sim")]
fn check_out_dir(a: &Args) -> anyhow::Result<()> {
    use anyhow::{bail, Context};
    if a.out_dir.exists() {
        if !a.out_dir.is_dir() {
            bail!("{}: exists and is not a directory", a.out_dir.display());
        }
        let non_empty = std::fs::read_dir(&a.out_dir)
            .with_context(|| format!("reading {}", a.out_dir.display()))?
            .next()
            .is_some();
        if non_empty && !a.force {
            bail!(
                "{}: the directory is not empty; choose an empty or new directory, or pass --force to \
                 replace the files of the same names",
                a.out_dir.display()
            );
        }
    }
    Ok(())
}

/// Writes the cell's files into `dir` with a progress bar on stderr.
#[cfg(feature = "sim")]
fn write_cell(
    cell: &depthcal::sim::SimCell,
    dir: &std::path::Path,
) -> depthcal::Result<depthcal::sim::WriteStats> {
    use indicatif::{ProgressBar, ProgressStyle};
    let total = cell.robots.iter().map(|r| r.poses.len()).sum::<usize>();
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message("simulating");
    let stats = cell.write(dir, &|done| bar.set_position(done as u64));
    bar.finish_and_clear();
    stats
}

/// The human-readable summary: what was written, the true base-to-base transform and the shared scene.
#[cfg(feature = "sim")]
fn print_text(
    a: &Args,
    cfg: &depthcal::sim::SimConfig,
    cell: &depthcal::sim::SimCell,
    stats: &depthcal::sim::WriteStats,
    seconds: f64,
) {
    let t = cell.t_base1_base2();
    let dist = t.translation.vector.norm();
    let (_, _, yaw) = t.rotation.euler_angles();
    let others: Vec<&str> = cell.robots[1..].iter().map(|r| r.name.as_str()).collect();
    println!(
        "wrote {}: robots {} (reference) and {}, {} frames each at {}, {} objects; {} files, {:.1} MB in {:.2} s",
        a.out_dir.display(),
        cell.robots[0].name,
        others.join(", "),
        cfg.frames,
        cfg.resolution,
        cell.scene.objects.len(),
        stats.files,
        stats.bytes as f64 / 1e6,
        seconds
    );
    println!(
        "true T_base1_base2: base distance {:.3} m, yaw {:.2} deg (ground_truth.json)",
        dist,
        yaw.to_degrees()
    );
    for r in &cell.robots[2..] {
        let t = cell.robots[0].t_world_base.inverse() * r.t_world_base;
        let (_, _, yaw) = t.rotation.euler_angles();
        println!(
            "true T_{}_{}: base distance {:.3} m, yaw {:.2} deg (ground_truth.json, robots)",
            cell.robots[0].name,
            r.name,
            t.translation.vector.norm(),
            yaw.to_degrees()
        );
    }
    let shared: Vec<String> = cell
        .robots
        .iter()
        .zip(&cell.shared)
        .map(|(r, f)| format!("{:.0}% of what {} sees", f * 100.0, r.name))
        .collect();
    let with = if cell.robots.len() > 2 {
        " (with any other robot)"
    } else {
        ""
    };
    println!(
        "shared scene{with}: {} (overlap asked: {:.0}%)",
        shared.join(", "),
        cfg.overlap * 100.0
    );
}
