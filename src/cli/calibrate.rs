//! `depthcal calibrate CELL_DIR`: robot-to-robot calibration of a cell dataset.

use super::methods::{CalibrateSettings, Method, MethodInputs};
use super::output::{matrix4_text, spinner};
use anyhow::{Context, Result};
use clap::Args as ClapArgs;
use depthcal::calibration::robot_to_robot::{CalibrateConfig, Calibration, FusedCell};
use depthcal::cell::Cell;
use depthcal::geometry::pose::{isometry_to_xyzquat, KukaPose};
use depthcal::geometry::robot_formats::{
    robot_file_tokens, robot_transform_file_names, ros1_static_tf_command, ros2_static_tf_command,
    transform_files, Frames,
};
use depthcal::methods::run::HandEyeRefinement;
use depthcal::methods::{calibrate_refining_hand_eyes, calibrate_with_method};
use depthcal::report::handeye_depth::{true_hand_eye, HandEyeTruthReport};
use depthcal::report::CalibrationReport;
use depthcal::report::{HandEyeDepthReport, JointHandEyeReport};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `depthcal calibrate`.
#[derive(ClapArgs)]
pub struct Args {
    /// The cell dataset directory (with cell.toml).
    cell: PathBuf,
    /// How the first estimate is obtained.
    #[arg(long, value_enum, default_value_t = Method::Depth)]
    method: Method,
    /// An initial T_base1_base2 (4x4 matrix file or a previous --json output); implies --method guess.
    #[arg(long)]
    init: Option<PathBuf>,
    /// With --method checkerboard: a robot's board pose from an earlier `depthcal handeye --json` run,
    /// as ROBOT=FILE (repeatable); robots without one have the board found in their colour images.
    #[arg(long, value_name = "ROBOT=FILE", value_parser = parse_board_pose)]
    board_pose: Vec<(String, PathBuf)>,
    /// Report the initialiser's estimate without refining it with trimmed ICP (image methods then do not
    /// fuse the clouds at all).
    #[arg(long)]
    no_refine: bool,
    /// Keypoint detector of --method features: sift (default), orb or akaze.
    #[arg(long, value_name = "NAME")]
    detector: Option<String>,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Write the result into DIR (created if missing; only for a trusted result): both fused clouds in
    /// the reference base frame, T_base1_base2.txt, calibration.json (as --json), a ROS 2 launch file, a
    /// URDF joint, a TF YAML file and the KUKA, UR and ABB frames. A cell of three or more robots: every
    /// robot's cloud, one static transform (joint, TF entry) per robot, and per robot its matrix and frames.
    #[arg(long, value_name = "DIR")]
    output: Option<PathBuf>,
    /// Write a visual report into DIR (created if missing; also for an untrusted result): report.html (opens
    /// offline) and the PNG snapshots overview.png, initial.png, residual.png (docs/report.md).
    #[arg(long, value_name = "DIR")]
    report: Option<PathBuf>,
    /// The reference robot's base frame id in the ROS outputs (default: its `frame` in cell.toml, else
    /// ROBOT_base).
    #[arg(long, value_name = "ID")]
    frame_id: Option<String>,
    /// The other robot's base frame id in the ROS outputs (default: its `frame` in cell.toml, else
    /// ROBOT_base).
    #[arg(long, value_name = "ID")]
    child_frame_id: Option<String>,
    /// First refine each robot's hand-eye from its own depth frames (they must agree on one static
    /// scene), then calibrate with the refined hand-eyes, then refine both hand-eyes and the base-to-base
    /// transform together; settings in --config's `refine_hand_eye` (docs/handeye.md#hand-eye-from-depth).
    #[arg(long)]
    refine_hand_eye: bool,
    #[command(flatten)]
    settings: CalibrateSettings,
}

fn parse_board_pose(s: &str) -> Result<(String, PathBuf), String> {
    match s.split_once('=') {
        Some((r, f)) if !r.trim().is_empty() && !f.trim().is_empty() => {
            Ok((r.trim().to_string(), PathBuf::from(f.trim())))
        }
        _ => Err(format!(
            "{s:?}: expected ROBOT=FILE (a robot name of cell.toml and a handeye --json output)"
        )),
    }
}

/// The fused cloud of the reference robot in `--output DIR` (base1 frame).
pub const REFERENCE_CLOUD_FILE: &str = "cloud_reference.ply";
/// The fused cloud of the other robot in `--output DIR`, mapped into the reference base frame.
pub const OTHER_CLOUD_FILE: &str = "cloud_other.ply";
/// The JSON of `--json` in `--output DIR`.
pub const JSON_FILE: &str = "calibration.json";

/// Every file name `--output DIR` writes.
fn output_names() -> Vec<&'static str> {
    let mut v = vec![REFERENCE_CLOUD_FILE, OTHER_CLOUD_FILE, JSON_FILE];
    let t = nalgebra::Isometry3::identity();
    let f = Frames {
        parent: "a".into(),
        child: "b".into(),
    };
    v.extend(transform_files(&t, &f).into_iter().map(|(n, _)| n));
    v
}

/// Every file name `--output DIR` writes for a cell of three or more robots: the reference's cloud, each
/// other robot's cloud (`cloud_<robot>.ply`), the JSON and the transform files.
fn robots_output_names(cell: &Cell) -> Vec<String> {
    let reference = cell.reference().name.clone();
    let others: Vec<&str> = cell
        .robots
        .iter()
        .filter(|r| r.name != reference)
        .map(|r| r.name.as_str())
        .collect();
    let mut v = vec![REFERENCE_CLOUD_FILE.to_string(), JSON_FILE.to_string()];
    v.extend(
        robot_file_tokens(&reference, &others)
            .iter()
            .map(|t| format!("cloud_{t}.ply")),
    );
    v.extend(robot_transform_file_names(&reference, &others));
    v
}

/// Writes `--output DIR` of a cell of three or more robots (every robot trusted): each robot's fused cloud
/// in the reference base frame (one colour per robot), the JSON and the transform files, each atomically.
fn write_robot_outputs(
    dir: &Path,
    c: &depthcal::calibration::multi_robot::CellCalibration,
    fused: &depthcal::calibration::robot_to_robot::FusedRobots,
    frames: &Frames,
    frame_ids: &[String],
    json: &CalibrationReport,
) -> Result<()> {
    use depthcal::geometry::robot_formats::{robot_transform_files, RobotOutput};
    if !dir.exists() {
        std::fs::create_dir(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    // The report's colours: orange the reference robot, then blue, purple, green, yellow, cyan.
    let colours = depthcal::viz::scene::PALETTE;
    let names: Vec<&str> = c.robots.iter().map(|r| r.name.as_str()).collect();
    let tokens = robot_file_tokens(&c.reference, &names);
    let outs: Vec<RobotOutput> = c
        .robots
        .iter()
        .zip(frame_ids)
        .filter_map(|(r, id)| {
            Some(RobotOutput {
                name: r.name.clone(),
                transform: r.transform?,
                frames: Frames {
                    parent: frames.parent.clone(),
                    child: id.clone(),
                },
            })
        })
        .collect();
    for (k, cloud) in fused.clouds.iter().enumerate() {
        if cloud.cloud.is_empty() {
            continue;
        }
        let (name, t) = if k == 0 {
            (
                REFERENCE_CLOUD_FILE.to_string(),
                nalgebra::Isometry3::identity(),
            )
        } else {
            let Some(t) = c.robots[k - 1].transform else {
                continue;
            };
            (format!("cloud_{}.ply", tokens[k - 1]), t)
        };
        let mut out = cloud.cloud.transformed(&t);
        out.colors = Some(vec![colours[k % colours.len()]; out.len()]);
        depthcal::io::write_cloud(dir.join(name), &out)?;
    }
    let text = serde_json::to_string_pretty(json)? + "\n";
    depthcal::io::write_atomically(&dir.join(JSON_FILE), |w| w.write_all(text.as_bytes()))?;
    for (name, text) in robot_transform_files(&c.reference, &outs) {
        depthcal::io::write_atomically(&dir.join(name), |w| w.write_all(text.as_bytes()))?;
    }
    Ok(())
}

/// Checks `--output DIR` and `--report DIR` before any work: not a file, its parent exists, it is not and
/// holds no input, and when it exists it holds only files calibrate writes there.
fn check_output_dir(a: &Args, cell: &Cell) -> Result<()> {
    let mut inputs = super::guard::Inputs::default();
    inputs.add_cell(cell);
    inputs.add_opt("--init", a.init.as_ref());
    inputs.add_opt("--config", a.settings.config_path());
    for (r, f) in &a.board_pose {
        inputs.add(&format!("--board-pose of {r}"), f);
    }
    // One directory may take both.
    let robot_names = robots_output_names(cell);
    let mut names = if cell.robots.len() > 2 {
        robot_names.iter().map(String::as_str).collect()
    } else {
        output_names()
    };
    names.extend(depthcal::viz::REPORT_FILES);
    for (flag, dir) in [("--output", &a.output), ("--report", &a.report)] {
        if let Some(dir) = dir {
            super::guard::check_owned_dir(&inputs, flag, dir, &names, "calibrate")?;
        }
    }
    Ok(())
}

/// The frame ids of the ROS outputs: the flags, else the robots' `frame` in cell.toml, else ROBOT_base.
fn frames(a: &Args, cell: &Cell) -> Result<Frames> {
    let (r, o) = cell.robot_pair()?;
    let parent = a.frame_id.clone().unwrap_or_else(|| cell.frame_id(&r.name));
    let child = a
        .child_frame_id
        .clone()
        .unwrap_or_else(|| cell.frame_id(&o.name));
    match Frames::new(&parent, &child) {
        Ok(f) => Ok(f),
        // Only printed (the ROS command lines): a robot name that makes no valid frame id is kept as it
        // was before frame ids were checked.
        Err(_) if a.output.is_none() && a.frame_id.is_none() && a.child_frame_id.is_none() => {
            Ok(Frames { parent, child })
        }
        Err(e) => Err(anyhow::Error::new(e).context(
            "the frame ids of the ROS outputs (--frame-id, --child-frame-id, or `frame` in cell.toml)",
        )),
    }
}

/// Writes `--output DIR` (a trusted result): the clouds, the JSON and the transform files, each atomically.
fn write_outputs(
    dir: &Path,
    c: &Calibration,
    fused: &FusedCell,
    f: &Frames,
    json: &CalibrationReport,
) -> Result<()> {
    if !dir.exists() {
        std::fs::create_dir(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let colored = |cloud: &depthcal::geometry::PointCloud, rgb: [u8; 3]| {
        let mut c = cloud.clone();
        c.colors = Some(vec![rgb; c.len()]);
        c
    };
    if !fused.reference.cloud.is_empty() || !fused.other.cloud.is_empty() {
        // Orange: the reference robot; blue: the other robot.
        let r = colored(&fused.reference.cloud, depthcal::viz::scene::PALETTE[0]);
        depthcal::io::write_cloud(dir.join(REFERENCE_CLOUD_FILE), &r)?;
        let o = colored(
            &fused.other.cloud.transformed(&c.transform),
            depthcal::viz::scene::PALETTE[1],
        );
        depthcal::io::write_cloud(dir.join(OTHER_CLOUD_FILE), &o)?;
    }
    let text = serde_json::to_string_pretty(json)? + "\n";
    depthcal::io::write_atomically(&dir.join(JSON_FILE), |w| w.write_all(text.as_bytes()))?;
    for (name, text) in transform_files(&c.transform, f) {
        depthcal::io::write_atomically(&dir.join(name), |w| w.write_all(text.as_bytes()))?;
    }
    Ok(())
}

/// Runs the command: prepare the inputs → calibrate → the report → the files → print.
pub fn run(a: Args) -> Result<()> {
    let start = Instant::now();
    let job = prepare(&a)?;
    if job.cell.robots.len() > 2 {
        return run_robots(&a, &job, start);
    }
    let (c, fused, hand_eyes) = solve(&a, &job)?;
    for w in &c.warnings {
        eprintln!("warning: {w}");
    }
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let report = report(&a, &job, &c, hand_eyes.as_ref(), total_ms)?;
    write_files(&a, &job, &c, &fused, &report)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_text(&c, &report, &job.frames, total_ms);
    }
    super::gate(&c.trust)
}

/// What calibrate works on, checked before any work.
struct Job {
    /// The settings (`--config`, the flags).
    cfg: CalibrateConfig,
    /// The cell.
    cell: Cell,
    /// The frame ids of the ROS outputs.
    frames: Frames,
    /// The initialiser (`guess` with `--init`).
    method: Method,
    /// The initialiser's inputs from the command line.
    inputs: MethodInputs,
}

/// Reads the settings and the cell and checks the flags, the ground truth and the output directories.
fn prepare(a: &Args) -> Result<Job> {
    let mut cfg = a.settings.config()?;
    if let Some(d) = &a.detector {
        if a.method != Method::Features {
            anyhow::bail!("--detector is for --method features");
        }
        cfg.features.detector = d.clone();
    }
    let cell = Cell::open(&a.cell)?;
    // A malformed optional ground_truth.json is reported before any work.
    cell.ground_truth()?;
    let frames = frames(a, &cell)?;
    check_output_dir(a, &cell)?;
    if !a.board_pose.is_empty() && a.method != Method::Checkerboard {
        anyhow::bail!("--board-pose is for --method checkerboard");
    }
    let method = if a.init.is_some() {
        Method::Guess
    } else {
        a.method
    };
    let inputs = MethodInputs {
        init: a.init.clone(),
        board_pose: a.board_pose.clone(),
    };
    Ok(Job {
        cfg,
        cell,
        frames,
        method,
        inputs,
    })
}

/// Calibrates, with a spinner: the result, the fused clouds, and with `--refine-hand-eye` each robot's
/// hand-eye refinement.
fn solve(a: &Args, job: &Job) -> Result<(Calibration, FusedCell, Option<HandEyeRefinement>)> {
    let pb = spinner("opening the cell");
    let mut progress = |s: &str| pb.set_message(s.to_string());
    let refine = !a.no_refine;
    let out = if a.refine_hand_eye {
        calibrate_refining_hand_eyes(
            &job.cell,
            job.method,
            &job.inputs,
            &job.cfg,
            refine,
            &mut progress,
        )
        .map(|(c, f, h)| (c, f, Some(h)))
    } else {
        calibrate_with_method(
            &job.cell,
            job.method,
            &job.inputs,
            &job.cfg,
            refine,
            &mut progress,
        )
        .map(|(c, f)| (c, f, None))
    };
    pb.finish_and_clear();
    out.with_context(|| format!("calibrating {}", a.cell.display()))
}

/// The report `--json` prints and `--output` writes, with the hand-eye refinements against the cell's
/// ground truth when it has one.
fn report(
    a: &Args,
    job: &Job,
    c: &Calibration,
    hand_eyes: Option<&HandEyeRefinement>,
    total_ms: f64,
) -> Result<CalibrationReport> {
    let cell_name = a.cell.display().to_string();
    let mut report = CalibrationReport::new(c, &cell_name, &job.frames, total_ms);
    if let Some(h) = hand_eyes {
        let gt = job.cell.ground_truth()?;
        report.hand_eye_refinement = Some(
            h.robots
                .iter()
                .map(|r| {
                    let truth = gt.as_ref().and_then(|g| true_hand_eye(g, &r.robot));
                    HandEyeDepthReport::new(r, &cell_name, truth.as_ref())
                })
                .collect(),
        );
        report.joint_hand_eye = h
            .joint
            .as_ref()
            .map(|j| JointHandEyeReport::new(j, h.joint_base_adopted, gt.as_ref()));
    }
    Ok(report)
}

/// `--output DIR` (only for a trusted result) and `--report DIR` (always).
fn write_files(
    a: &Args,
    job: &Job,
    c: &Calibration,
    fused: &FusedCell,
    report: &CalibrationReport,
) -> Result<()> {
    if let Some(dir) = &a.output {
        if c.trust.trusted {
            write_outputs(dir, c, fused, &job.frames, report)?;
            eprintln!("wrote {}", dir.display());
        } else {
            eprintln!(
                "warning: {} not written: the result is not trusted",
                dir.display()
            );
        }
    }
    if let Some(dir) = &a.report {
        super::visual::write(dir, c.trust.trusted, || {
            depthcal::viz::calibration_report(&job.cell, c, fused, &job.frames)
        })?;
    }
    Ok(())
}

/// The human-readable result: the transform in every robot format, its 1-σ, quality, the initial estimate,
/// the errors against a ground truth, timings, and whether it is trusted and why.
fn print_text(c: &Calibration, report: &CalibrationReport, frames: &Frames, total_ms: f64) {
    let t = &c.transform;
    let xq = isometry_to_xyzquat(t);
    print_transform(c, frames);
    print_quality(c);
    for h in report.hand_eye_refinement.iter().flatten() {
        print_hand_eye(h);
    }
    if let Some(j) = &report.joint_hand_eye {
        print_joint(j);
    }
    println!("initial         {}", c.initial.detail);
    if c.refined {
        // The initialiser's estimate and the refined one side by side.
        let d = c.initial.transform.inverse() * c.transform;
        let xi = isometry_to_xyzquat(&c.initial.transform);
        println!(
            "initial -> refined  xyz {:.4} {:.4} {:.4} m -> {:.4} {:.4} {:.4} m; moved {:.3} deg / {:.2} mm \
             (initial 1-sigma {:.3} deg / {:.2} mm)",
            xi[0],
            xi[1],
            xi[2],
            xq[0],
            xq[1],
            xq[2],
            d.rotation.angle().to_degrees(),
            d.translation.vector.norm() * 1e3,
            c.initial.sigma_rotation_deg,
            c.initial.sigma_translation_m * 1e3
        );
    }
    print_truth(c);
    print_timings(&c.timings_ms, total_ms);
    print_checks(c);
}

/// The transform: matrix, xyz + quaternion, KUKA, the ROS commands and its 1-σ.
fn print_transform(c: &Calibration, frames: &Frames) {
    let t = &c.transform;
    println!(
        "T_base1_base2: {} base -> {} base ({} frames / {} frames, method {})",
        c.other, c.reference, c.frames[1], c.frames[0], c.method
    );
    print_pose_lines(t, &c.covariance, frames, true, "");
}

/// A pose's lines: the matrix, xyz + quaternion, KUKA, the ROS commands (ROS 1 with `ros1`) and its 1-σ
/// from `covariance` (`sigma_note` after it).
fn print_pose_lines(
    t: &nalgebra::Isometry3<f64>,
    covariance: &nalgebra::Matrix6<f64>,
    frames: &Frames,
    ros1: bool,
    sigma_note: &str,
) {
    let xq = isometry_to_xyzquat(t);
    let kuka = KukaPose::from_isometry(t);
    let sd: Vec<f64> = (0..6).map(|k| covariance[(k, k)].max(0.0).sqrt()).collect();
    println!("{}", matrix4_text(t));
    println!(
        "xyz (m)         {:.6} {:.6} {:.6}   quaternion (x y z w) {:.8} {:.8} {:.8} {:.8}",
        xq[0], xq[1], xq[2], xq[3], xq[4], xq[5], xq[6]
    );
    println!(
        "KUKA XYZ-ABC    X {:.3} Y {:.3} Z {:.3} mm   A {:.4} B {:.4} C {:.4} deg",
        kuka.x_mm, kuka.y_mm, kuka.z_mm, kuka.a_deg, kuka.b_deg, kuka.c_deg
    );
    println!("ROS 2           {}", ros2_static_tf_command(t, frames));
    if ros1 {
        println!("ROS 1           {}", ros1_static_tf_command(t, frames));
    }
    println!(
        "1-sigma         rotation {:.4} {:.4} {:.4} deg, translation {:.3} {:.3} {:.3} mm{sigma_note}",
        sd[0].to_degrees(),
        sd[1].to_degrees(),
        sd[2].to_degrees(),
        sd[3] * 1e3,
        sd[4] * 1e3,
        sd[5] * 1e3
    );
}

/// Each stage's wall time and the whole run's, milliseconds.
fn print_timings(timings_ms: &[(String, f64)], total_ms: f64) {
    let times: Vec<String> = timings_ms
        .iter()
        .map(|(k, v)| format!("{k} {v:.0}"))
        .collect();
    println!("timings (ms)    {}  total {total_ms:.0}", times.join(", "));
}

/// The trust verdict with its reasons and suggestions (`scope` after "yes").
fn print_verdict(trust: &depthcal::registration::Trust, scope: &str) {
    if trust.trusted {
        println!("trusted         yes{scope}");
    } else {
        println!("trusted         NO");
        for r in &trust.reasons {
            println!("  because       {r}");
        }
        for s in &trust.suggestions {
            println!("  try           {s}");
        }
    }
}

/// The refinement's quality figures and the priors used.
fn print_quality(c: &Calibration) {
    if let (Some(fitness), Some(rmse), Some(overlap)) = (c.fitness, c.inlier_rmse, c.overlap) {
        println!(
            "quality         fitness {fitness:.3}, inlier RMSE {:.2} mm, overlap {overlap:.3}, converged {}, degenerate {}",
            rmse * 1e3,
            c.converged,
            c.degeneracy.is_degenerate()
        );
    } else {
        println!(
            "quality         not refined (--no-refine): the initialiser's estimate and its 1-sigma"
        );
    }
    println!(
        "priors          {}",
        if c.priors_used.is_empty() {
            "none".to_string()
        } else {
            c.priors_used.join(", ")
        }
    );
}

/// One robot's hand-eye refinement from depth (`--refine-hand-eye`).
fn print_hand_eye(h: &HandEyeDepthReport) {
    println!(
        "hand-eye {:<7} refined from depth: moved {:.3} deg / {:.2} mm, residual median {:.2} -> {:.2} mm{}{}",
        h.robot,
        h.change_size.rotation_deg,
        h.change_size.translation_m * 1e3,
        h.median_residual_before_m * 1e3,
        h.median_residual_after_m * 1e3,
        h.error_vs_truth.as_ref().map(vs_truth).unwrap_or_default(),
        if h.trusted { "" } else { " (NOT trusted)" }
    );
}

/// A hand-eye's error against the cell's ground truth before and after its refinement, as a suffix.
fn vs_truth(e: &HandEyeTruthReport) -> String {
    format!(
        "; vs truth {:.3} deg / {:.2} mm -> {:.3} deg / {:.2} mm",
        e.before.rotation_deg,
        e.before.translation_m * 1e3,
        e.after.rotation_deg,
        e.after.translation_m * 1e3
    )
}

/// Both hand-eyes and the base-to-base transform refined together (`--refine-hand-eye`).
fn print_joint(j: &JointHandEyeReport) {
    for r in &j.robots {
        println!(
            "joint hand-eye {:<7} moved {:.3} deg / {:.2} mm, residual median {:.2} -> {:.2} mm{}",
            r.robot,
            r.change_size.rotation_deg,
            r.change_size.translation_m * 1e3,
            r.median_residual_before_m * 1e3,
            r.median_residual_after_m * 1e3,
            r.error_vs_truth.as_ref().map(vs_truth).unwrap_or_default()
        );
    }
    println!(
        "joint base      moved {:.3} deg / {:.2} mm from calibrate's ({}){}{}",
        j.base_change_size.rotation_deg,
        j.base_change_size.translation_m * 1e3,
        if j.base_adopted {
            "adopted"
        } else {
            "reported, not adopted"
        },
        j.base_error_vs_truth
            .as_ref()
            .map(|e| format!(
                "; vs truth calibrate {:.3} deg / {:.2} mm, joint {:.3} deg / {:.2} mm",
                e.calibrate.rotation_deg,
                e.calibrate.translation_m * 1e3,
                e.joint.rotation_deg,
                e.joint.translation_m * 1e3
            ))
            .unwrap_or_default(),
        if j.trusted { "" } else { " (NOT trusted)" }
    );
}

/// The errors against the cell's ground truth, when it has one, and the normalised error.
fn print_truth(c: &Calibration) {
    match (c.error_vs_truth, c.initial_error_vs_truth) {
        (Some((r, tr)), Some((ri, ti))) if c.refined => println!(
            "vs ground truth initial {ri:.3} deg / {:.2} mm  ->  refined {r:.4} deg / {:.3} mm",
            ti * 1e3,
            tr * 1e3
        ),
        (_, Some((ri, ti))) => println!(
            "vs ground truth initial {ri:.4} deg / {:.3} mm (not refined)",
            ti * 1e3
        ),
        _ => {}
    }
    if let Some(n) = &c.normalised_error {
        println!(
            "normalised error rotation {:.2}, translation {:.2}, pose {:.2} (error over the reported covariance; ~1 when honest)",
            n.rotation, n.translation, n.pose
        );
    }
}

/// The independent checks (hand-eyes, free space, ambiguity) and the trust verdict with its reasons.
fn print_checks(c: &Calibration) {
    for p in &c.pose_scatter {
        if p.estimated {
            println!(
                "poses   {:<7}scatter {:.2} mm / {:.3} deg per axis at the scene (at least the stated repeatability); corrections move the scene {:.2} mm{}{}{}",
                p.robot,
                p.scatter_mm,
                p.scatter_deg,
                p.displacement_mm,
                if p.applied {
                    "; frames moved to agree, 1-sigma widened"
                } else if p.widened {
                    "; 1-sigma widened"
                } else {
                    ""
                },
                p.note
                    .as_deref()
                    .map(|n| format!(" ({n})"))
                    .unwrap_or_default(),
                if p.outliers.is_empty() {
                    String::new()
                } else {
                    format!("; left as they are: frames {}", p.outliers.join(", "))
                }
            );
        } else {
            println!(
                "poses   {:<7}scatter not estimated: {}",
                p.robot,
                p.note.as_deref().unwrap_or("")
            );
        }
    }
    for h in &c.hand_eye_checks {
        if h.checked {
            println!(
                "hand-eye {:<7}{} with its depth{}: it asks for {:.3} deg / {:.2} mm, {:.1} sigma of 1-sigma {:.3} deg / {:.2} mm ({}) and the fit's (limit {:.1})",
                h.robot,
                if h.consistent { "agrees" } else { "DISAGREES" },
                if h.determined.len() < 6 {
                    format!(" (determined: {})", h.determined.join(" "))
                } else {
                    String::new()
                },
                h.change_deg,
                h.change_mm,
                h.distance_sigmas,
                h.sigma_deg,
                h.sigma_mm,
                if h.sigma_stated { "stated" } else { "default" },
                h.max_distance_sigmas
            );
        } else {
            println!(
                "hand-eye {:<7}not checked: {}",
                h.robot,
                h.note.as_deref().unwrap_or("")
            );
        }
    }
    if let Some(f) = &c.free_space {
        println!(
            "free space      {:.1}% of the surfaces violate the other robot's views (own frames {:.1}%, margin {:.0} mm)",
            f.violation * 1e2,
            f.own_violation * 1e2,
            f.margin_m * 1e3
        );
    }
    if let Some(x) = &c.ambiguity {
        println!(
            "ambiguous       a runner-up {:.2} deg / {:.1} mm away scores {:.0}% of the best:\n{}",
            x.rotation_deg,
            x.translation * 1e3,
            x.score_ratio * 1e2,
            matrix4_text(&x.runner_up)
        );
    }
    print_verdict(&c.trust, "");
}

/// A cell of three or more robots: every pair, then the pose graph (`calibration::multi_robot`). The
/// two-robot report shows the reference and the first other robot in the joint solution; `robots` and
/// `pairs` hold the rest.
fn run_robots(a: &Args, job: &Job, start: Instant) -> Result<()> {
    let n = job.cell.robots.len();
    if job.method != Method::Depth {
        anyhow::bail!(
            "the cell names {n} robots: calibrate solves cells of more than two robots from depth (--method depth); --init and the image methods give one pair"
        );
    }
    if a.no_refine || a.refine_hand_eye {
        anyhow::bail!(
            "the cell names {n} robots: --no-refine and --refine-hand-eye are for cells of two robots"
        );
    }
    // Each other robot's base frame id: the first other robot's is the one of the two-robot outputs
    // (--child-frame-id), the rest their `frame` in cell.toml, else ROBOT_base; checked before any work
    // when they go into files.
    let frame_ids = job.cell.other_frame_ids(&job.frames.child);
    if a.output.is_some() {
        for id in &frame_ids {
            Frames::new(&job.frames.parent, id).with_context(|| {
                "the frame ids of the ROS outputs (--frame-id, --child-frame-id, or `frame` in cell.toml)"
            })?;
        }
    }
    let init = depthcal::methods::build(Method::Depth, &job.cell, &job.inputs, &job.cfg)?.0;
    let pb = spinner("opening the cell");
    let mut progress = |s: &str| pb.set_message(s.to_string());
    let out = depthcal::calibration::multi_robot::calibrate_robots(
        &job.cell,
        init.as_ref(),
        &job.cfg,
        &mut progress,
    );
    pb.finish_and_clear();
    let (c, fused) = out.with_context(|| format!("calibrating {}", a.cell.display()))?;
    for w in &c.warnings {
        eprintln!("warning: {w}");
    }
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    let report = CalibrationReport::with_robots(
        &c,
        &a.cell.display().to_string(),
        &job.frames,
        &frame_ids,
        total_ms,
    );
    if let Some(dir) = &a.output {
        if c.trust.trusted {
            write_robot_outputs(dir, &c, &fused, &job.frames, &frame_ids, &report)?;
            eprintln!("wrote {}", dir.display());
        } else {
            eprintln!(
                "warning: {} not written: the result is not trusted for every robot",
                dir.display()
            );
        }
    }
    if let Some(dir) = &a.report {
        super::visual::write(dir, c.trust.trusted, || {
            depthcal::viz::robots_report(&job.cell, &c, &fused, &report, &job.frames)
        })?;
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_robots(&c, &report, &job.frames, total_ms);
    }
    super::gate(&c.trust)
}

/// The human-readable result of a cell of three or more robots: each robot's base, each pair against the
/// joint solution, and the verdict.
fn print_robots(
    c: &depthcal::calibration::multi_robot::CellCalibration,
    report: &CalibrationReport,
    frames: &Frames,
    total_ms: f64,
) {
    println!(
        "{} robots, reference {:?} (its base is the frame of every pose below)",
        c.robots.len() + 1,
        c.reference
    );
    for (r, rr) in c.robots.iter().zip(report.robots.iter().flatten()) {
        println!();
        match (&r.transform, &r.covariance) {
            (Some(t), Some(cov)) => {
                println!(
                    "T_{}_{}: {} base -> {} base{}",
                    c.reference,
                    r.name,
                    r.name,
                    c.reference,
                    if r.trust.trusted {
                        ""
                    } else {
                        " (NOT trusted)"
                    }
                );
                let f = Frames {
                    parent: frames.parent.clone(),
                    child: rr.frame_id.clone(),
                };
                print_pose_lines(t, cov, &f, false, " (joint solution)");
                println!("from pairs      {}", rr.pairs_used.join(", "));
                if let Some((deg, m)) = r.error_vs_truth {
                    println!(
                        "vs ground truth {deg:.4} deg / {:.3} mm{}",
                        m * 1e3,
                        r.normalised_error.map_or(String::new(), |z| format!(
                            " (normalised: rotation {:.2}, translation {:.2})",
                            z.rotation, z.translation
                        ))
                    );
                }
            }
            _ => {
                println!("T_{}_{}: NOT calibrated", c.reference, r.name);
                for why in &r.trust.reasons {
                    println!("  because       {why}");
                }
            }
        }
    }
    println!();
    println!("pairs (each its own two-robot calibration, against the joint solution):");
    for p in report.pairs.iter().flatten() {
        let residual = match (p.residual_deg, p.residual_m) {
            (Some(d), Some(m)) => format!("{d:.3} deg / {:.2} mm off the joint solution", m * 1e3),
            _ => "no joint pose to compare".to_string(),
        };
        println!(
            "  {} - {}: {}, fitness {}, {}, {residual}{}",
            p.reference,
            p.other,
            if p.trusted { "trusted" } else { "not trusted" },
            p.fitness.map_or("-".to_string(), |f| format!("{f:.3}")),
            p.verdict.name(),
            p.loop_error
                .map_or(String::new(), |z| format!(", loop error {z:.2}"))
        );
        if !p.trusted {
            for r in &p.reasons {
                println!("      because {r}");
            }
        }
    }
    print_timings(&c.timings_ms, total_ms);
    print_verdict(&c.trust, " (every robot)");
}
