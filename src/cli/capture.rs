//! `depthcal capture`: take depth (and colour) frames from a connected RealSense camera and append them to a
//! robot of a cell dataset (cargo feature `realsense`).

use clap::Args as ClapArgs;
use std::path::PathBuf;

/// Arguments of `depthcal capture`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (created when it does not exist).
    pub cell_dir: PathBuf,
    /// The robot carrying the camera.
    #[arg(long)]
    pub robot: String,
    /// The flange pose T_base_ee for all frames taken: x_mm,y_mm,z_mm,a_deg,b_deg,c_deg (KUKA XYZ-ABC).
    #[arg(
        long,
        allow_hyphen_values = true,
        conflicts_with = "poses",
        required_unless_present = "poses"
    )]
    pub pose: Option<String>,
    /// A pose file: one frame per row, in file order. Before each row depthcal waits for Enter on stdin (move
    /// the robot to the row's pose first); the row's frame id becomes the cell's frame id.
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The pose file's format (default: from its header).
    #[arg(long)]
    pub pose_format: Option<depthcal::io::poses::PoseFormat>,
    /// With --pose: how many frames to take at that pose (ids continue the robot's numbering).
    #[arg(long, default_value_t = 1, conflicts_with = "poses")]
    pub frames: usize,
    /// Stream and store colour (RGB8) too.
    #[arg(long)]
    pub color: bool,
    /// T_ee_cam of a robot new to the cell: a JSON file (16 numbers row-major, 4 rows of 4, or
    /// {"T_ee_cam": ...}; metres), 16 comma-separated numbers, or `identity` (until it is calibrated).
    #[arg(long, allow_hyphen_values = true)]
    pub hand_eye: Option<String>,
    /// The camera's serial number (default: the only camera connected).
    #[arg(long)]
    pub serial: Option<String>,
    /// Stream width, pixels.
    #[arg(long, default_value_t = 848)]
    pub width: u32,
    /// Stream height, pixels.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Frames per second.
    #[arg(long, default_value_t = 30)]
    pub fps: u32,
    /// Frames dropped after the stream starts (auto-exposure settles).
    #[arg(long, default_value_t = 30)]
    pub warmup: usize,
    /// Frames dropped before each frame taken.
    #[arg(long, default_value_t = 5)]
    pub settle: usize,
    /// Print a JSON report on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Parses `--pose x_mm,y_mm,z_mm,a_deg,b_deg,c_deg` (KUKA XYZ-ABC) into `T_base_ee` (metres).
pub fn parse_kuka(s: &str) -> anyhow::Result<nalgebra::Isometry3<f64>> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            anyhow::anyhow!("--pose {s:?}: expected 6 numbers x_mm,y_mm,z_mm,a_deg,b_deg,c_deg")
        })?;
    let f = depthcal::io::poses::PoseFormat::Kuka;
    f.parse_values(&v)
        .map_err(|m| anyhow::anyhow!("--pose {s:?}: {m} (x_mm,y_mm,z_mm,a_deg,b_deg,c_deg)"))
}

/// Runs `depthcal capture`.
#[cfg(not(feature = "realsense"))]
pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(p) = &a.pose {
        parse_kuka(p)?;
    }
    anyhow::bail!(
        "live capture needs librealsense, and this depthcal was built without the `realsense` feature; rebuild \
         with `cargo build --release --features realsense` (librealsense 2.56 or newer, from Intel's packages)"
    )
}

/// Runs `depthcal capture`.
#[cfg(feature = "realsense")]
pub fn run(a: Args) -> anyhow::Result<()> {
    use anyhow::Context;
    use depthcal::capture::realsense::{Camera, CaptureConfig};
    use depthcal::capture::{
        append_frames, existing_frame_ids, next_frame_ids, AppendReport, NewFrame, PoseRows,
        RobotSetup,
    };
    use depthcal::io::poses::PoseFormat;
    use std::io::BufRead;

    if a.frames == 0 {
        anyhow::bail!("--frames must be at least 1");
    }
    let pose = a.pose.as_deref().map(parse_kuka).transpose()?;
    let hand_eye = a
        .hand_eye
        .as_deref()
        .map(super::import::parse_hand_eye)
        .transpose()?;
    // Everything about the poses is checked before the camera is opened.
    let rows = a
        .poses
        .as_ref()
        .map(|p| PoseRows::read(p, a.pose_format))
        .transpose()?;
    let pose_format = rows.as_ref().map(|r| r.format).unwrap_or(PoseFormat::Kuka);
    let setup = RobotSetup {
        name: a.robot.clone(),
        hand_eye,
        pose_format,
    };
    let cfg = CaptureConfig {
        serial: a.serial.clone(),
        width: a.width,
        height: a.height,
        fps: a.fps,
        color: a.color,
        warmup_frames: a.warmup,
        settle_frames: a.settle,
        ..Default::default()
    };
    let mut cam = Camera::open(&cfg)?;
    let intr = cam.intrinsics().clone();
    eprintln!(
        "camera {} ({}): depth {}x{} fx {:.2} fy {:.2} ppx {:.2} ppy {:.2} {}, depth scale {} m",
        cam.name,
        cam.serial,
        intr.width,
        intr.height,
        intr.fx,
        intr.fy,
        intr.ppx,
        intr.ppy,
        intr.model,
        intr.depth_scale
    );
    let serial = cam.serial.clone();
    let source = |n: u64, t: f64| format!("camera {serial} frame {n} (t = {t:.6} s)");
    let mut reports: Vec<AppendReport> = Vec::new();
    match (pose, &rows) {
        (Some(pose), None) => {
            let ids = next_frame_ids(&existing_frame_ids(&a.cell_dir, &a.robot)?, a.frames);
            let mut frames = Vec::with_capacity(a.frames);
            for id in ids {
                let f = cam.grab()?;
                frames.push(NewFrame {
                    id,
                    t_base_ee: pose,
                    source: source(f.frame_number, f.t_s),
                    depth: f.depth,
                    color: f.color,
                    pose_origin: "--pose".into(),
                });
            }
            reports.push(append_frames(&a.cell_dir, &setup, &intr, &frames)?);
        }
        (None, Some(rows)) => {
            let stdin = std::io::stdin();
            let mut lines = stdin.lock().lines();
            for (i, rec) in rows.records.iter().enumerate() {
                eprint!(
                    "[{}/{}] move robot {} to frame {} ({}) and press Enter: ",
                    i + 1,
                    rows.records.len(),
                    a.robot,
                    rec.frame,
                    rows.origin(i)
                );
                match lines.next() {
                    Some(Ok(_)) => {}
                    Some(Err(e)) => return Err(e).context("reading stdin"),
                    None => anyhow::bail!(
                        "stdin closed before {} (frame {}); {} of {} frames were taken",
                        rows.origin(i),
                        rec.frame,
                        i,
                        rows.records.len()
                    ),
                }
                let f = cam.grab()?;
                let frame = NewFrame {
                    id: rec.frame.clone(),
                    t_base_ee: rec.pose,
                    source: source(f.frame_number, f.t_s),
                    depth: f.depth,
                    color: f.color,
                    pose_origin: rows.origin(i),
                };
                // One append per row: each frame is in the cell as soon as it is taken.
                let setup_i = if i == 0 {
                    setup.clone()
                } else {
                    RobotSetup {
                        hand_eye: None,
                        ..setup.clone()
                    }
                };
                reports.push(append_frames(&a.cell_dir, &setup_i, &intr, &[frame])?);
                eprintln!("taken");
            }
        }
        _ => anyhow::bail!("give either --pose or --poses"),
    }
    let ids: Vec<&String> = reports.iter().flat_map(|r| &r.frames).collect();
    let last = reports.last().expect("at least one frame");
    if a.json {
        let out = depthcal::report::CaptureReport::new(&cam.name, &cam.serial, &intr, &reports)?;
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "captured {} frames ({}) into robot {} of {}; the robot has {} frames",
            ids.len(),
            ids.iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            a.robot,
            a.cell_dir.display(),
            last.frames_total
        );
    }
    Ok(())
}
