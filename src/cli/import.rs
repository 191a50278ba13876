//! `depthcal import`: import a recording (ROS1 `.bag`; with the `realsense` feature also ROS2 `.db3` and `.bag`
//! through librealsense's playback) into a robot of a cell dataset.

use anyhow::{bail, Context};
use clap::{Args as ClapArgs, ValueEnum};
use depthcal::capture::{
    import_recording, ImportReport, MatchConfig, MatchMode, PoseRows, Recording, RobotSetup,
};
use depthcal::io::poses::PoseFormat;
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

/// How depth frames are paired with pose rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Match {
    /// The k-th depth frame (timestamp order) takes the k-th pose row; the counts must be equal.
    Order,
    /// Each pose row takes the depth frame nearest to its t_s column, within --tolerance-ms.
    Time,
}

/// Which library reads the recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Reader {
    /// .bag with the built-in ROS1 reader, .db3 with librealsense.
    Auto,
    /// The built-in pure-Rust ROS1 .bag reader.
    Rosbag,
    /// librealsense's own playback (needs the `realsense` feature).
    Librealsense,
}

/// Arguments of `depthcal import`.
#[derive(ClapArgs)]
pub struct Args {
    /// The recording: a ROS1 .bag (e.g. from ROS's realsense2_camera or librealsense < 2.59), or a RealSense
    /// .db3 (librealsense ≥ 2.59; needs the `realsense` feature).
    pub recording: PathBuf,
    /// The cell dataset directory (created when it does not exist). Not needed with --list.
    pub cell_dir: Option<PathBuf>,
    /// The robot that took the recording (its camera is the recording's camera).
    #[arg(long)]
    pub robot: Option<String>,
    /// The robot's pose file: one row per frame to import (T_base_ee), any pose format, optionally with a t_s
    /// column (seconds, the recording's clock) after `frame`. Its frame ids become the cell's frame ids.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The pose file's format (default: from its header). With --tf-base: the format of a new robot's pose
    /// file (default xyzquat).
    #[arg(long)]
    pub pose_format: Option<PoseFormat>,
    /// Take each depth frame's robot pose from the recording's /tf and /tf_static instead of a pose file:
    /// the robot's base frame (with --tf-flange). Every depth frame is imported, with new frame ids.
    #[arg(
        long,
        value_name = "FRAME",
        requires = "tf_flange",
        conflicts_with = "poses"
    )]
    pub tf_base: Option<String>,
    /// With --tf-base: the flange (end-effector) frame whose pose in the base frame is T_base_ee, e.g.
    /// tool0 or flange (the hand-eye is then T_ee_cam of this frame).
    #[arg(long, value_name = "FRAME", requires = "tf_base")]
    pub tf_flange: Option<String>,
    /// With --tf-base: how far before the first or after the last /tf sample of a transform a depth frame may
    /// be and still take that sample, milliseconds (nothing is extrapolated).
    #[arg(long, value_name = "MS", default_value_t = 20.0)]
    pub tf_tolerance_ms: f64,
    /// With --tf-base: the longest interval between two /tf samples that is interpolated across,
    /// milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 250.0)]
    pub tf_max_gap_ms: f64,
    /// How depth frames are paired with pose rows.
    #[arg(long = "match", value_enum, default_value_t = Match::Order)]
    pub match_mode: Match,
    /// With --match time: the largest distance between a row's t_s and its depth frame, milliseconds.
    #[arg(long, default_value_t = 20.0)]
    pub tolerance_ms: f64,
    /// Import the colour images too (paired with each depth frame by nearest timestamp).
    #[arg(long)]
    pub color: bool,
    /// The largest distance between a depth frame and its colour frame, milliseconds.
    #[arg(long, default_value_t = 20.0)]
    pub color_tolerance_ms: f64,
    /// The depth image topic (.bag; default: found automatically).
    #[arg(long)]
    pub topic: Option<String>,
    /// The camera info topic (.bag; default: the one nearest to the depth topic).
    #[arg(long)]
    pub camera_info_topic: Option<String>,
    /// The colour image topic (.bag; implies --color).
    #[arg(long)]
    pub color_topic: Option<String>,
    /// Metres per depth unit, overriding the recording's (.bag; default: its Depth Units option, else 0.001).
    #[arg(long)]
    pub depth_scale: Option<f64>,
    /// T_ee_cam of a robot new to the cell: a JSON file (16 numbers row-major, 4 rows of 4, or
    /// {"T_ee_cam": ...}; metres), 16 comma-separated numbers, or `identity` (until it is calibrated).
    #[arg(long, allow_hyphen_values = true)]
    pub hand_eye: Option<String>,
    /// Which library reads the recording.
    #[arg(long, value_enum, default_value_t = Reader::Auto)]
    pub reader: Reader,
    /// Only list the recording's streams (topics, frames, time span) and exit.
    #[arg(long)]
    pub list: bool,
    /// Print a JSON report on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Parses `--hand-eye`: `identity`, 16 comma-separated numbers, or a JSON file.
pub fn parse_hand_eye(spec: &str) -> anyhow::Result<Isometry3<f64>> {
    let s = spec.trim();
    if s.eq_ignore_ascii_case("identity") {
        return Ok(Isometry3::identity());
    }
    if s.contains(',') && !Path::new(s).exists() {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("--hand-eye {s:?}: expected 16 numbers"))?;
        if v.len() != 16 {
            bail!(
                "--hand-eye: expected 16 numbers (row-major 4x4, metres), found {}",
                v.len()
            );
        }
        let m: [f64; 16] = v.try_into().expect("16");
        return Ok(depthcal::geometry::transform::isometry_from_rows(
            &m,
            "--hand-eye",
        )?);
    }
    Ok(depthcal::cell::read_hand_eye_file(Path::new(s))?)
}

/// The recording opened, and its TF transforms (collected only with --tf-base or --list, from .bag files).
type Opened = (Box<dyn Recording>, depthcal::capture::tf::TfBuffer);

fn open_recording(a: &Args) -> anyhow::Result<Opened> {
    let ext = a
        .recording
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let reader = match (a.reader, ext.as_str()) {
        (Reader::Auto, "bag") => Reader::Rosbag,
        (Reader::Auto, "db3") => Reader::Librealsense,
        (Reader::Auto, _) => bail!(
            "{}: unknown recording type (expected .bag or .db3); choose a reader with --reader",
            a.recording.display()
        ),
        (r, _) => r,
    };
    match reader {
        Reader::Rosbag => open_rosbag(a),
        Reader::Librealsense => open_librealsense(a),
        Reader::Auto => unreachable!("resolved above"),
    }
}

#[cfg(feature = "rosbag")]
fn open_rosbag(a: &Args) -> anyhow::Result<Opened> {
    use depthcal::capture::rosbag::{BagImportConfig, BagRecording};
    let cfg = BagImportConfig {
        depth_topic: a.topic.clone(),
        camera_info_topic: a.camera_info_topic.clone(),
        color: a.color,
        color_topic: a.color_topic.clone(),
        depth_scale: a.depth_scale,
        tf: a.tf_base.is_some() || a.list,
    };
    let mut bag = BagRecording::open(&a.recording, &cfg)?;
    log::info!(
        "{}: depth {} ({} frames), intrinsics from {}, depth scale {} m ({})",
        a.recording.display(),
        bag.depth().name,
        bag.depth().frames.len(),
        bag.camera_info_topic,
        bag.intrinsics().depth_scale,
        bag.depth_scale_source
    );
    let tf = bag.take_tf();
    Ok((Box::new(bag), tf))
}

#[cfg(not(feature = "rosbag"))]
fn open_rosbag(a: &Args) -> anyhow::Result<Opened> {
    bail!(
        "{}: reading ROS1 .bag files needs the `rosbag` feature (on by default), and this depthcal was built \
         without it; rebuild with `cargo build --release --features rosbag`",
        a.recording.display()
    )
}

#[cfg(feature = "realsense")]
fn open_librealsense(a: &Args) -> anyhow::Result<Opened> {
    for (flag, given) in [
        ("--tf-base", a.tf_base.is_some()),
        ("--topic", a.topic.is_some()),
        ("--camera-info-topic", a.camera_info_topic.is_some()),
        ("--color-topic", a.color_topic.is_some()),
        ("--depth-scale", a.depth_scale.is_some()),
    ] {
        if given {
            bail!("{flag} applies to the built-in .bag reader, not to librealsense playback");
        }
    }
    let rec = depthcal::capture::realsense::PlaybackRecording::open(&a.recording, a.color)?;
    Ok((Box::new(rec), Default::default()))
}

#[cfg(not(feature = "realsense"))]
fn open_librealsense(a: &Args) -> anyhow::Result<Opened> {
    bail!(
        "{}: reading this recording needs librealsense's playback, and this depthcal was built without the \
         `realsense` feature; rebuild with `cargo build --release --features realsense` (ROS1 .bag files are \
         read without it: --reader rosbag)",
        a.recording.display()
    )
}

fn span(frames: &[depthcal::capture::FrameStamp]) -> String {
    match (frames.first(), frames.last()) {
        (Some(a), Some(b)) => format!("t = {:.6} .. {:.6} s", a.t_s, b.t_s),
        _ => "no frames".into(),
    }
}

/// Runs `depthcal import`.
pub fn run(a: Args) -> anyhow::Result<()> {
    if let (false, Some(cell_dir), Some(robot)) = (a.list, &a.cell_dir, &a.robot) {
        check_import_outputs(&a, cell_dir, robot)?;
    }
    if a.tf_base.is_some() && a.match_mode == Match::Time {
        bail!(
            "--match time pairs the rows of a pose file with frames by their t_s; with --tf-base every depth \
             frame takes its pose from /tf at its own stamp"
        );
    }
    let (mut rec, tf) = open_recording(&a)?;
    if a.list {
        let d = rec.depth();
        let i = rec.intrinsics();
        if a.json {
            let out = depthcal::report::RecordingReport::new(rec.info(), &tf);
            println!("{}", serde_json::to_string_pretty(&out)?);
        } else {
            println!("{}", a.recording.display());
            println!(
                "  depth  {}: {} frames, {}",
                d.name,
                d.frames.len(),
                span(&d.frames)
            );
            if let Some(c) = rec.color() {
                println!(
                    "  colour {}: {} frames, {}",
                    c.name,
                    c.frames.len(),
                    span(&c.frames)
                );
            }
            println!(
                "  intrinsics {}x{} fx {} fy {} ppx {} ppy {} model {} coeffs {:?}, depth scale {} m",
                i.width, i.height, i.fx, i.fy, i.ppx, i.ppy, i.model, i.coeffs, i.depth_scale
            );
            for e in tf.edges() {
                let when = match e.span_s {
                    Some((f, l)) => format!("{} /tf samples, t = {f:.6} .. {l:.6} s", e.samples),
                    None => String::new(),
                };
                let both = if e.is_static && e.samples > 0 {
                    ", "
                } else {
                    ""
                };
                let st = if e.is_static { "static" } else { "" };
                println!("  tf {} -> {}: {st}{both}{when}", e.parent, e.child);
            }
        }
        return Ok(());
    }
    let (Some(cell_dir), Some(robot)) = (&a.cell_dir, &a.robot) else {
        bail!(
            "import needs CELL_DIR, --robot and --poses or --tf-base/--tf-flange (or --list to look at the \
             recording)"
        );
    };
    let rows = match (&a.poses, &a.tf_base, &a.tf_flange) {
        (Some(poses), _, _) => PoseRows::read(poses, a.pose_format)?,
        (None, Some(base), Some(flange)) => {
            let existing = depthcal::capture::existing_frame_ids(cell_dir, robot)?;
            let ids = depthcal::capture::next_frame_ids(&existing, rec.depth().frames.len());
            let cfg = depthcal::capture::tf::TfConfig {
                tolerance_s: a.tf_tolerance_ms * 1e-3,
                max_gap_s: a.tf_max_gap_ms * 1e-3,
            };
            let source = depthcal::capture::tf::TfPoses {
                buffer: &tf,
                base,
                flange,
                cfg,
            };
            PoseRows::from_tf(
                &source,
                rec.depth(),
                &ids,
                rec.path(),
                a.pose_format.unwrap_or(PoseFormat::Xyzquat),
            )
            .context("--tf-base / --tf-flange")?
        }
        _ => bail!(
            "import needs the robot poses: --poses FILE, or --tf-base FRAME --tf-flange FRAME to take them from \
             the recording's /tf"
        ),
    };
    let mode = match a.match_mode {
        Match::Order => MatchMode::Order,
        Match::Time => MatchMode::Time {
            tolerance_s: a.tolerance_ms * 1e-3,
        },
    };
    let cfg = MatchConfig {
        mode,
        color_tolerance_s: a.color_tolerance_ms * 1e-3,
    };
    let hand_eye = a.hand_eye.as_deref().map(parse_hand_eye).transpose()?;
    let setup = RobotSetup {
        name: robot.clone(),
        hand_eye,
        pose_format: rows.format,
    };
    let start = std::time::Instant::now();
    let report =
        import_recording(rec.as_mut(), &rows, &cfg, &setup, cell_dir).with_context(|| {
            format!(
                "importing {} into robot {robot:?} of {}",
                a.recording.display(),
                cell_dir.display()
            )
        })?;
    let seconds = start.elapsed().as_secs_f64();
    print_report(&report, seconds, a.json)
}

fn print_report(r: &ImportReport, seconds: f64, json: bool) -> anyhow::Result<()> {
    let ap = &r.append;
    if json {
        let out = depthcal::report::ImportReport::new(r, seconds);
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    let what = match (ap.created_cell, ap.created_robot) {
        (true, _) => "new cell, new robot",
        (false, true) => "new robot",
        _ => "appended",
    };
    println!(
        "imported {} of {} depth frames from {} ({}{}) into robot {} of {} ({what}); the robot has {} frames",
        ap.frames.len(),
        r.depth_frames_in_recording,
        r.recording.display(),
        r.depth_stream,
        r.color_stream
            .as_ref()
            .map(|c| format!(" + colour {c}"))
            .unwrap_or_default(),
        ap.robot,
        ap.cell_dir.display(),
        ap.frames_total
    );
    if let (Some(first), Some(last)) = (ap.frames.first(), ap.frames.last()) {
        println!(
            "frames {first} .. {last}; {} files, {:.1} MB of images in {:.2} s",
            ap.files_written,
            ap.image_bytes as f64 / 1e6,
            seconds
        );
    }
    let i = &r.intrinsics;
    println!(
        "intrinsics {}x{} fx {:.3} fy {:.3} ppx {:.3} ppy {:.3} {}; depth scale {} m",
        i.width, i.height, i.fx, i.fy, i.ppx, i.ppy, i.model, i.depth_scale
    );
    Ok(())
}

/// Refuses, before any work, an import whose written files (cell.toml, the robot's pose file and
/// intrinsics) would be one of its inputs (the recording, --poses, a --hand-eye file).
fn check_import_outputs(a: &Args, cell_dir: &Path, robot: &str) -> anyhow::Result<()> {
    let mut inputs = super::guard::Inputs::default();
    inputs.add("the recording", &a.recording);
    inputs.add_opt("--poses", a.poses.as_ref());
    if let Some(h) = a.hand_eye.as_deref().map(Path::new).filter(|p| p.is_file()) {
        inputs.add("--hand-eye", h);
    }
    let existing = depthcal::cell::CellManifest::read(cell_dir)
        .ok()
        .and_then(|m| m.robots.into_iter().find(|r| r.name == robot));
    let entry = existing.unwrap_or_else(|| {
        depthcal::cell::RobotEntry::standard(robot, nalgebra::Isometry3::identity())
    });
    for out in [
        cell_dir.join(depthcal::cell::MANIFEST_FILE),
        cell_dir.join(&entry.poses),
        cell_dir.join(&entry.intrinsics),
    ] {
        inputs.check_output("CELL_DIR", &out)?;
    }
    Ok(())
}
