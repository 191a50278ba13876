//! Command-line parsing and dispatch. Each subcommand lives in its own file; no algorithm lives here.

use clap::{Parser, Subcommand};

mod calibrate;
mod capture;
mod compare;
mod convert;
mod fuse;
mod guard;
mod handeye;
mod handeye_depth;
mod import;
mod intrinsics;
mod markers;
mod match_cmd;
mod methods;
mod output;
mod plan;
mod profile;
mod register;
mod signals;
mod simulate;
mod vision_args;
mod visual;

/// depthcal: depth-only calibration of multi-robot cells, and point-cloud registration.
#[derive(Parser)]
#[command(name = "depthcal", version, about, long_about = None)]
struct Cli {
    /// Worker threads (default: all cores; at most 8 per core). Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// More log output on stderr (-v info, -vv debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Register SOURCE onto TARGET (FPFH + RANSAC, then trimmed robust ICP).
    Register(register::Args),
    /// Robot-to-robot calibration of a cell dataset: T_base1_base2 with its uncertainty.
    Calibrate(calibrate::Args),
    /// Run every calibration method the cell's data allows and compare them in one table.
    Compare(compare::Args),
    /// Fuse one robot's depth frames of a cell dataset into a cloud in its base frame.
    Fuse(fuse::Args),
    /// Convert a pose file between kuka (XYZ-ABC), matrix (4x4), xyzquat, ur, abb and fanuc formats.
    Convert(convert::Args),
    /// Hand-eye calibration: T_ee_cam and T_base_board from robot poses and camera-to-board poses.
    Handeye(handeye::Args),
    /// Camera intrinsics from checkerboard images (Zhang's method; needs the `vision` feature).
    Intrinsics(intrinsics::Args),
    /// Keypoint matches between two images and the homography between them (needs the `vision` feature).
    Match(match_cmd::Args),
    /// Find ArUco / AprilTag markers in images: ids and sub-pixel corners (needs the `vision` feature).
    Markers(markers::Args),
    /// Write a simulated cell dataset of two or more robots (depth, colour, poses) with ground truth.
    Simulate(simulate::Args),
    /// Take frames from a connected RealSense camera into a cell dataset (cargo feature `realsense`).
    Capture(capture::Args),
    /// Import a recording (ROS1 .bag; RealSense .db3 with the `realsense` feature) into a cell dataset.
    Import(import::Args),
    /// Where registration spends its time: per-stage wall and CPU time, points in and out, throughput,
    /// each ICP iteration, peak memory (two clouds or a generated pair of any size).
    Profile(profile::Args),
    /// Which degrees of freedom of the hand-eyes and of T_base1_base2 the cell's frames leave weak, and
    /// which flange poses to capture next.
    Plan(plan::Args),
}

/// Parses the command line, runs the command, and returns the process exit code.
pub fn run() -> i32 {
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level))
        .format_timestamp(None)
        .init();
    // Checked before any work: a huge count would hang starting threads.
    let threads = match cli.threads {
        Some(n) => Some(("--threads", n)),
        None => match std::env::var("RAYON_NUM_THREADS") {
            Ok(v) if !v.trim().is_empty() => match v.trim().parse::<usize>() {
                Ok(0) => None,
                Ok(n) => Some(("RAYON_NUM_THREADS", n)),
                Err(_) => {
                    eprintln!("error: RAYON_NUM_THREADS={v:?} is not a thread count");
                    return EXIT_USAGE;
                }
            },
            _ => None,
        },
    };
    if let Some((what, n)) = threads {
        if let Err(e) = guard::check_threads(what, n) {
            eprintln!("error: {e}");
            return EXIT_USAGE;
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            eprintln!("error: cannot start {n} threads: {e}");
            return EXIT_USAGE;
        }
    }
    signals::install();
    let result = match cli.command {
        Command::Register(a) => register::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Compare(a) => compare::run(a),
        Command::Fuse(a) => fuse::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Handeye(a) => handeye::run(a),
        Command::Simulate(a) => simulate::run(a),
        Command::Intrinsics(a) => intrinsics::run(a),
        Command::Match(a) => match_cmd::run(a),
        Command::Markers(a) => markers::run(a),
        Command::Capture(a) => capture::run(a),
        Command::Import(a) => import::run(a),
        Command::Profile(a) => profile::run(a),
        Command::Plan(a) => plan::run(a),
    };
    match result {
        Ok(()) => 0,
        Err(e) if e.downcast_ref::<Untrusted>().is_some() => {
            eprintln!("{e}");
            EXIT_UNTRUSTED
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            EXIT_ERROR
        }
    }
}

/// Exit status of an error: bad input, a missing file, a failed computation.
pub const EXIT_ERROR: i32 = 1;
/// Exit status of a command-line usage error (clap's) or a bad global option.
pub const EXIT_USAGE: i32 = 2;
/// Exit status of a result that was computed and printed in full but did not pass the quality gate.
pub const EXIT_UNTRUSTED: i32 = 3;

/// The error a command returns after printing a result that is not trusted: the process exits with
/// [`EXIT_UNTRUSTED`] and prints the reasons on stderr.
#[derive(Debug)]
pub struct Untrusted(pub Vec<String>);

impl std::fmt::Display for Untrusted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "untrusted result (exit status {EXIT_UNTRUSTED}):")?;
        for r in &self.0 {
            write!(f, "\n  - {r}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Untrusted {}

/// `Ok` for a trusted result, else the [`Untrusted`] error carrying its reasons.
pub fn gate(trust: &depthcal::registration::Trust) -> anyhow::Result<()> {
    if trust.trusted {
        Ok(())
    } else {
        Err(Untrusted(trust.reasons.clone()).into())
    }
}
