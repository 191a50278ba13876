//! `depthcal handeye`: hand-eye calibration (`T_ee_cam` and `T_base_board`) from robot poses and board
//! poses seen by the camera.

use super::output::matrix4_text;
use clap::Args as ClapArgs;
use depthcal::calibration::handeye::{
    calibrate_hand_eye, frames_from_records, HandEyeConfig, HandEyeMethod, HandEyeResult,
};
use depthcal::geometry::pose::{isometry_to_xyzquat, KukaPose};
use depthcal::io::poses::{format_from_header, read_poses, PoseFormat};
use depthcal::report::handeye::ResidualSummary;
use depthcal::report::{HandEyeInputs, HandEyeReport};
use nalgebra::Isometry3;
use std::path::PathBuf;

/// Arguments of `depthcal handeye`.
#[derive(ClapArgs)]
pub struct Args {
    /// Robot flange poses T_base_ee, CSV with a header, one row per frame id.
    #[arg(long, required_unless_present = "depth")]
    pub robot_poses: Option<PathBuf>,
    /// Board poses in the camera T_cam_board (from any tool), CSV with a header, rows matched by frame id.
    #[arg(
        long,
        required_unless_present_any = ["images", "depth"],
        conflicts_with = "images"
    )]
    pub target_poses: Option<PathBuf>,
    /// Instead of a board: refine the hand-eye of --robot in this cell directory from its depth frames
    /// (all frames must describe one static scene; docs/handeye.md#hand-eye-from-depth). --config then
    /// takes a HandEyeDepthConfig.
    #[arg(
        long,
        value_name = "CELL_DIR",
        requires = "robot",
        conflicts_with_all = ["robot_poses", "target_poses", "images", "eye_to_hand", "no_refine"]
    )]
    pub depth: Option<PathBuf>,
    /// With --depth: the robot (its name in cell.toml) whose hand-eye to refine.
    #[arg(long, value_name = "NAME", requires = "depth")]
    pub robot: Option<String>,
    /// Instead of --target-poses: a directory of board images named by frame id (<frame>.png, .jpg, ...);
    /// the board is found in each and its pose solved (needs --board or --charuco, --square, --intrinsics
    /// and the `vision` feature; a ChArUco board may be partly in view).
    #[arg(long, value_name = "DIR")]
    pub images: Option<PathBuf>,
    #[command(flatten)]
    pub board: super::vision_args::BoardArgs,
    /// Intrinsics JSON of the camera that took --images (e.g. from `depthcal intrinsics --output`).
    #[arg(long, value_name = "FILE", requires = "images")]
    pub intrinsics: Option<PathBuf>,
    /// With --images: also write the solved T_cam_board per frame to this pose file (matrix format).
    #[arg(long, value_name = "FILE", requires = "images")]
    pub save_target_poses: Option<PathBuf>,
    /// Format of --robot-poses: kuka (frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg), matrix (frame + 16
    /// numbers row-major, metres) or xyzquat (frame,x,y,z,qx,qy,qz,qw, metres).
    #[arg(long, default_value = "kuka")]
    pub robot_format: PoseFormat,
    /// Format of --target-poses (kuka, matrix, xyzquat, ur, abb or fanuc).
    #[arg(long, default_value = "matrix")]
    pub target_format: PoseFormat,
    /// Closed form to start from: auto (best fit, default), tsai, park, daniilidis, shah or li.
    #[arg(long, default_value = "auto")]
    pub method: HandEyeMethod,
    /// Report the closed form as it is: no joint refinement, no outlier rejection.
    #[arg(long)]
    pub no_refine: bool,
    /// The camera is fixed in the cell and the board is on the flange: the answer is then T_ee_board and
    /// T_base_cam (the target poses are still T_cam_board).
    #[arg(long)]
    pub eye_to_hand: bool,
    /// Seed of the least-median-of-squares search over frame triples.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// JSON file with any fields of HandEyeConfig (see src/calibration/handeye/mod.rs).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Runs `depthcal handeye`.
pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(dir) = &a.depth {
        return super::handeye_depth::run(
            dir,
            a.robot.as_deref().unwrap_or(""),
            a.config.as_deref(),
            a.json,
        );
    }
    let Some(robot_poses) = a.robot_poses.clone() else {
        anyhow::bail!("give --robot-poses FILE (or --depth CELL_DIR --robot NAME)");
    };
    let mut config: HandEyeConfig =
        super::output::read_config(a.config.as_deref(), "hand-eye configuration")?;
    config.method = a.method;
    config.refine = !a.no_refine;
    config.seed = a.seed;
    if let Some(out) = &a.save_target_poses {
        super::guard::check_output_file("--save-target-poses", out, &[])?;
        let mut inputs = super::guard::Inputs::default();
        inputs.add("--robot-poses", &robot_poses);
        inputs.add_opt("--intrinsics", a.intrinsics.as_ref());
        inputs.add_opt("--config", a.config.as_ref());
        if let Some(dir) = &a.images {
            if let Ok(entries) = std::fs::read_dir(dir) {
                for e in entries.flatten() {
                    inputs.add("an image of --images", &e.path());
                }
            }
        }
        inputs.check_output("--save-target-poses", out)?;
    }
    let robot = read_with_hint(&robot_poses, a.robot_format, "--robot-format")?;
    let (robot, target, target_path) = match (&a.target_poses, &a.images) {
        (Some(p), _) => (
            robot,
            read_with_hint(p, a.target_format, "--target-format")?,
            p.clone(),
        ),
        (None, Some(dir)) => {
            // Frames whose image shows no board are left out (and reported).
            let target = board_poses_from_images(&a, dir, &robot)?;
            let robot = robot
                .into_iter()
                .filter(|r| target.iter().any(|t| t.frame == r.frame))
                .collect();
            (robot, target, dir.clone())
        }
        (None, None) => anyhow::bail!("give --target-poses FILE or --images DIR"),
    };
    let mut frames = frames_from_records(&robot, &robot_poses, &target, &target_path)?;
    if a.eye_to_hand {
        for f in &mut frames {
            f.t_cam_board = f.t_cam_board.inverse();
        }
    }
    let r = calibrate_hand_eye(&frames, &config)?;
    let (x_name, z_name) = if a.eye_to_hand {
        ("T_ee_board", "T_base_cam")
    } else {
        ("T_ee_cam", "T_base_board")
    };
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    if a.json {
        let report = HandEyeReport::new(
            &r,
            &HandEyeInputs {
                eye_to_hand: a.eye_to_hand,
                robot_poses: robot_poses.display().to_string(),
                target_poses: a.target_poses.as_ref().map(|p| p.display().to_string()),
                images: a.images.as_ref().map(|p| p.display().to_string()),
            },
        );
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_text(&r, &a, x_name, z_name);
    }
    Ok(())
}

/// T_cam_board per frame from the images in `dir` (detection + PnP); frames without the board are
/// reported and left out.
#[cfg(feature = "vision")]
fn board_poses_from_images(
    a: &Args,
    dir: &std::path::Path,
    robot: &[depthcal::io::poses::PoseRecord],
) -> anyhow::Result<Vec<depthcal::io::poses::PoseRecord>> {
    use depthcal::camera::Intrinsics;
    use depthcal::io::poses::{write_poses, PoseRecord};
    use depthcal::vision::observe::{find_frame_images, observe_board, ObserveConfig};
    let board = a.board.board()?;
    let Some(ip) = &a.intrinsics else {
        anyhow::bail!("--images needs --intrinsics FILE (the camera's intrinsics JSON)");
    };
    let intr = Intrinsics::from_json_file(ip)?;
    let ids: Vec<String> = robot.iter().map(|r| r.frame.clone()).collect();
    let (images, extra) = find_frame_images(dir, &ids)?;
    for p in &extra {
        eprintln!(
            "warning: {} matches no frame of {} and is ignored",
            p.display(),
            a.robot_poses
                .as_deref()
                .unwrap_or(std::path::Path::new(""))
                .display()
        );
    }
    let obs = observe_board(&images, &board, &intr, &ObserveConfig::default())?;
    for line in obs.rejected_lines() {
        eprintln!("warning: {line}; frame left out");
    }
    let corners = match board {
        depthcal::cell::Board::Charuco(_) => format!(
            ", {}-{} corners per view",
            obs.found.iter().map(|o| o.corners).min().unwrap_or(0),
            obs.found.iter().map(|o| o.corners).max().unwrap_or(0)
        ),
        depthcal::cell::Board::Checkerboard(_) => String::new(),
    };
    eprintln!(
        "board ({board}) found in {} of {} images{corners}, PnP RMS {:.3} px (worst {:.3} px)",
        obs.found.len(),
        images.len(),
        (obs.found.iter().map(|o| o.rms_px * o.rms_px).sum::<f64>() / obs.found.len() as f64)
            .sqrt(),
        obs.found.iter().map(|o| o.rms_px).fold(0.0, f64::max)
    );
    let records: Vec<PoseRecord> = obs
        .found
        .iter()
        .map(|o| PoseRecord {
            frame: o.frame.clone(),
            pose: o.t_cam_board,
            line: 0,
        })
        .collect();
    if let Some(p) = &a.save_target_poses {
        write_poses(p, &records, PoseFormat::Matrix)?;
        eprintln!("wrote {}", p.display());
    }
    Ok(records)
}

#[cfg(not(feature = "vision"))]
fn board_poses_from_images(
    _a: &Args,
    _dir: &std::path::Path,
    _robot: &[depthcal::io::poses::PoseRecord],
) -> anyhow::Result<Vec<depthcal::io::poses::PoseRecord>> {
    anyhow::bail!(
        "depthcal handeye --images: {}",
        super::vision_args::WITHOUT_VISION
    )
}

/// Reads a pose file in `format`; when its header names another format, the error says which flag to pass.
fn read_with_hint(
    path: &std::path::Path,
    format: PoseFormat,
    flag: &str,
) -> anyhow::Result<Vec<depthcal::io::poses::PoseRecord>> {
    match read_poses(path, Some(format)) {
        Ok((_, r)) => Ok(r),
        Err(e) => {
            let header = std::fs::read_to_string(path).ok().and_then(|t| {
                t.lines()
                    .find(|l| !l.trim().is_empty() && !l.trim().starts_with('#'))
                    .map(String::from)
            });
            match header.and_then(|h| format_from_header(&h)) {
                Some(f) if f != format => Err(anyhow::anyhow!(
                    "{e} (the header is the {f} format: pass {flag} {f})"
                )),
                _ => Err(e.into()),
            }
        }
    }
}

fn pose_text(name: &str, t: &Isometry3<f64>) -> String {
    let k = KukaPose::from_isometry(t);
    let q = isometry_to_xyzquat(t);
    format!(
        "{name} (4x4, metres):\n{}\n  KUKA XYZ-ABC: X {:.3} Y {:.3} Z {:.3} mm, A {:.4} B {:.4} C {:.4} deg\n  \
         xyz+quat: x {:.6} y {:.6} z {:.6} m, qx {:.8} qy {:.8} qz {:.8} qw {:.8}\n",
        matrix4_text(t),
        k.x_mm,
        k.y_mm,
        k.z_mm,
        k.a_deg,
        k.b_deg,
        k.c_deg,
        q[0],
        q[1],
        q[2],
        q[3],
        q[4],
        q[5],
        q[6]
    )
}

fn print_text(r: &HandEyeResult, a: &Args, x_name: &str, z_name: &str) {
    let how = if r.refined {
        format!(
            "joint robust refinement from {}{} ({} iterations{})",
            r.method,
            if r.from_lmeds {
                " / LMedS frame triple"
            } else {
                ""
            },
            r.iterations,
            if r.converged { "" } else { ", NOT converged" }
        )
    } else {
        format!("closed form {}", r.method)
    };
    println!(
        "hand-eye ({}): {} frames, {}",
        if a.eye_to_hand {
            "eye-to-hand"
        } else {
            "eye-in-hand"
        },
        r.residuals.len(),
        how
    );
    println!();
    print!("{}", pose_text(x_name, &r.t_ee_cam));
    if let Some(s) = r.t_ee_cam_sigma {
        println!(
            "  1-sigma of {x_name} (per axis, statistical): rotation {:.4}°, translation {:.3} mm (hand_eye_sigma_deg / hand_eye_sigma_mm in --json)",
            s.rotation_deg, s.translation_mm
        );
    }
    println!();
    print!("{}", pose_text(z_name, &r.t_base_board));
    println!(
        "  spread of the per-frame {z_name} (inliers): rotation RMS {:.3}° max {:.3}°, translation RMS {:.2} mm max {:.2} mm",
        r.board.rotation_rms_deg, r.board.rotation_max_deg, r.board.translation_rms_mm, r.board.translation_max_mm
    );
    println!();
    println!(
        "motions: {} pairs, rotation-axis spread {:.1}°, largest rotation {:.1}°, robot/camera angle mismatch {:.3}° (median)",
        r.excitation.pairs, r.excitation.axis_spread_deg, r.excitation.max_rotation_deg, r.excitation.angle_mismatch_deg
    );
    println!();
    println!(
        "{:<16} {:>12} {:>14} {:>10}",
        "frame", "rotation [°]", "translation [mm]", ""
    );
    for f in &r.residuals {
        println!(
            "{:<16} {:>12.4} {:>14.3} {:>10}",
            f.frame,
            f.rotation_deg,
            f.translation_mm,
            if f.rejected { "REJECTED" } else { "" }
        );
    }
    let s = ResidualSummary::of(&r.residuals);
    println!(
        "inliers: {} frames, rotation RMS {:.4}° median {:.4}°, translation RMS {:.3} mm median {:.3} mm",
        s.frames,
        s.rotation_rms_deg,
        s.rotation_median_deg,
        s.translation_rms_mm,
        s.translation_median_mm
    );
    println!();
    println!("closed forms (residuals over all frames):");
    println!(
        "{:<12} {:>10} {:>10} {:>10} {:>10}   {x_name} KUKA XYZ-ABC (mm, deg)",
        "method", "rot med°", "rot RMS°", "tr med mm", "tr RMS mm"
    );
    for c in &r.closed_forms {
        match (&c.t_ee_cam, &c.error) {
            (Some(x), _) => {
                let k = KukaPose::from_isometry(x);
                println!(
                    "{:<12} {:>10.4} {:>10.4} {:>10.3} {:>10.3}   {:.2} {:.2} {:.2} {:.3} {:.3} {:.3}",
                    c.method.name(),
                    c.rotation_median_deg,
                    c.rotation_rms_deg,
                    c.translation_median_mm,
                    c.translation_rms_mm,
                    k.x_mm,
                    k.y_mm,
                    k.z_mm,
                    k.a_deg,
                    k.b_deg,
                    k.c_deg
                );
            }
            (None, e) => println!(
                "{:<12} failed: {}",
                c.method.name(),
                e.clone().unwrap_or_default()
            ),
        }
    }
    if !r.rejected.is_empty() {
        println!();
        println!("rejected frames: {}", r.rejected.join(", "));
    }
}
