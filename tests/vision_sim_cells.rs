//! The whole checkerboard chain on simulated cells with exact ground truth (cargo feature `vision`):
//! board images rendered by the simulator → corners → PnP → hand-eye (`T_ee_cam` within 0.1° and 1 mm),
//! and robot-to-robot by checkerboard (`T_base1_base2` within 0.2° and 2 mm before ICP), from the
//! images with the cell's hand-eye and from the hand-eye runs' board poses; then ICP from that start and
//! the depth-only method on the same cells for comparison. Also the bad-input cases of the image
//! workflow.
//!
//! `cargo test --release --features vision --test vision_sim_cells -- --nocapture` prints the table;
//! `DEPTHCAL_SIM_SEEDS=N` runs N cells (default 3).
#![cfg(feature = "vision")]

mod common;
use common::scratch;
use depthcal::calibration::board_init::{BoardInBase, CheckerboardInitializer};
use depthcal::calibration::handeye::{calibrate_hand_eye, HandEyeConfig, HandEyeFrame};
use depthcal::calibration::initializer::GlobalRegistration;
use depthcal::calibration::robot_to_robot::{calibrate, CalibrateConfig};
use depthcal::cell::{Board, Cell, CellRobot, Checkerboard, GroundTruth};
use depthcal::geometry::transform::{isometry_from_rows, pose_error};
use depthcal::sim::{SimBoardConfig, SimCell, SimConfig};
use depthcal::vision::initializers::checkerboard_initializer;
use depthcal::vision::observe::{
    board_in_robot_base, observe_board, BoardObservations, ObserveConfig,
};
use nalgebra::Isometry3;
use std::path::PathBuf;

/// A cell with a 9x6 board of 30 mm squares at the table centre and objects around it; views from
/// above (40–80° elevation) so that most frames see the whole board, swinging the full ±145° around the
/// workspace (`overlap` 1: the configured ranges in full) so that the hand-eye motions are well excited.
fn board_cell(seed: u64) -> SimConfig {
    let mut c = SimConfig {
        seed,
        frames: 16,
        overlap: 1.0,
        view_elevation_deg: [40.0, 80.0],
        view_distance_m: [0.4, 0.75],
        ..SimConfig::default()
    };
    c.scene.objects = 6;
    c.scene.workspace_radius_m = 0.34;
    c.scene.board = Some(SimBoardConfig::default());
    c
}

fn nested(v: &serde_json::Value) -> Isometry3<f64> {
    let rows: Vec<f64> = v
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect();
    isometry_from_rows(&rows.try_into().unwrap(), "truth").unwrap()
}

/// The board pose of each robot base from `ground_truth.json`.
fn true_board_in_base(gt: &GroundTruth, robot: &str) -> Isometry3<f64> {
    nested(&gt.extra["board"]["T_base_board"][robot])
}

fn color_images(r: &CellRobot) -> Vec<(String, PathBuf)> {
    r.frames
        .iter()
        .map(|f| (f.id.clone(), f.color_path.clone().unwrap()))
        .collect()
}

/// The hand-eye frames of the images where the board was found.
fn hand_eye_frames(r: &CellRobot, obs: &BoardObservations) -> Vec<HandEyeFrame> {
    obs.found
        .iter()
        .map(|o| HandEyeFrame {
            id: o.frame.clone(),
            t_base_ee: r.frames.iter().find(|f| f.id == o.frame).unwrap().t_base_ee,
            t_cam_board: o.t_cam_board,
        })
        .collect()
}

/// Hand-eye from the robot's images: (T_ee_cam, T_base_board, frames used, PnP RMS px).
fn hand_eye_from_images(
    r: &CellRobot,
    board: &Board,
) -> (Isometry3<f64>, Isometry3<f64>, usize, f64) {
    let obs = observe_board(
        &color_images(r),
        board,
        &r.intrinsics,
        &ObserveConfig::default(),
    )
    .unwrap();
    let frames = hand_eye_frames(r, &obs);
    let he = calibrate_hand_eye(&frames, &HandEyeConfig::default()).unwrap();
    let rms =
        (obs.found.iter().map(|o| o.rms_px.powi(2)).sum::<f64>() / obs.found.len() as f64).sqrt();
    (he.t_ee_cam, he.t_base_board, frames.len(), rms)
}

#[test]
fn simulated_board_cells_hand_eye_and_robot_to_robot() {
    let n: u64 = std::env::var("DEPTHCAL_SIM_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    println!(
        "| cell | robot | frames with board | PnP RMS px | hand-eye error ° / mm | T_base_board error ° / mm |"
    );
    println!("|---|---|---|---|---|---|");
    let mut table2 = Vec::new();
    for seed in 1..=n {
        let cfg = board_cell(seed);
        let sim = SimCell::generate(&cfg).unwrap();
        let dir = scratch(&format!("vision-sim-{seed}"));
        sim.write(&dir, &|_| {}).unwrap();
        let cell = Cell::open(&dir).unwrap();
        let gt = cell.ground_truth().unwrap().unwrap();
        let truth = gt.t_base1_base2.unwrap();
        let board = Board::from_manifest_extra(&cell.manifest.extra, &dir.join("cell.toml"))
            .unwrap()
            .expect("[board] in cell.toml");

        // Hand-eye from the images of each robot.
        let mut from_handeye = Vec::new();
        for (k, r) in cell.robots.iter().enumerate() {
            let (x, z, used, rms) = hand_eye_from_images(r, &board);
            let (er, et) = pose_error(&x, &sim.robots[k].t_ee_cam);
            let (zr, zt) = pose_error(&z, &true_board_in_base(&gt, &r.name));
            println!(
                "| {seed} | {} | {used}/{} | {rms:.3} | {er:.4} / {:.3} | {zr:.4} / {:.3} |",
                r.name,
                r.frames.len(),
                et * 1e3,
                zt * 1e3
            );
            assert!(used >= 8, "seed {seed} {}: board in {used} frames", r.name);
            assert!(
                er < 0.1 && et < 1e-3,
                "seed {seed} {}: hand-eye error {er}° {} mm",
                r.name,
                et * 1e3
            );
            from_handeye.push(BoardInBase {
                robot: r.name.clone(),
                t_base_board: z,
                frames: used,
                rotation_rms_deg: 0.0,
                translation_rms_mm: 0.0,
                source: "hand-eye".into(),
            });
        }

        // Robot-to-robot by checkerboard, from the images with the cell's hand-eye.
        let (init, warnings) = checkerboard_initializer(&cell, &[]).unwrap();
        let (t, sr, st) = init.estimate();
        let (r_img, t_img) = pose_error(&t, &truth);
        // ... and from the two hand-eye runs' board poses.
        let he_init = CheckerboardInitializer {
            reference: from_handeye[0].clone(),
            other: from_handeye[1].clone(),
        };
        let (r_he, t_he) = pose_error(&he_init.estimate().0, &truth);
        assert!(
            r_img < 0.2 && t_img < 2e-3,
            "seed {seed}: checkerboard T_base1_base2 error {r_img}° {} mm",
            t_img * 1e3
        );
        assert!(
            r_he < 0.2 && t_he < 2e-3,
            "seed {seed}: checkerboard (hand-eye board poses) error {r_he}° {} mm",
            t_he * 1e3
        );
        // The reported 1-σ is honest to within a factor of a few.
        assert!(
            r_img < 4.0 * sr.max(0.01) && t_img < 4.0 * st.max(1e-4),
            "seed {seed}: error {r_img}° {t_img} m vs σ {sr}° {st} m"
        );

        // ICP from the checkerboard start, and the depth-only method, on the same cell.
        let ccfg = CalibrateConfig::default();
        let icp = calibrate(&cell, &init, &ccfg, &mut |_| {}).unwrap();
        let (r_icp, t_icp) = icp.error_vs_truth.unwrap();
        let depth = calibrate(&cell, &GlobalRegistration::default(), &ccfg, &mut |_| {}).unwrap();
        let (r_d, t_d) = depth.error_vs_truth.unwrap();
        assert!(
            r_icp < 0.2 && t_icp < 2e-3,
            "seed {seed}: ICP from the checkerboard start ended {r_icp}° {} mm off",
            t_icp * 1e3
        );
        table2.push(format!(
            "| {seed} | {r_img:.4} / {:.3} (σ {sr:.3} / {:.2}) | {r_he:.4} / {:.3} | {r_icp:.4} / {:.3} | {r_d:.4} / {:.3} | {} |",
            t_img * 1e3,
            st * 1e3,
            t_he * 1e3,
            t_icp * 1e3,
            t_d * 1e3,
            warnings.len()
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
    println!();
    println!("| cell | checkerboard (images) ° / mm | checkerboard (hand-eye board poses) ° / mm | checkerboard + ICP ° / mm | depth only ° / mm | frames without board |");
    println!("|---|---|---|---|---|---|");
    for l in table2 {
        println!("{l}");
    }
}

#[test]
fn bad_input_is_named() {
    let mut cfg = board_cell(7);
    cfg.frames = 4;
    let sim = SimCell::generate(&cfg).unwrap();
    let dir = scratch("vision-bad");
    sim.write(&dir, &|_| {}).unwrap();
    let cell = Cell::open(&dir).unwrap();
    let r = &cell.robots[0];
    let board = Board::from(Checkerboard::new(9, 6, 0.03).unwrap());

    // A board that is not in the images: the error names the images.
    let wrong = Board::from(Checkerboard::new(11, 8, 0.03).unwrap());
    let e = observe_board(
        &color_images(r),
        &wrong,
        &r.intrinsics,
        &ObserveConfig::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("none of the 4 images") && e.contains("000.png"),
        "{e}"
    );

    // Fewer than three poses: hand-eye refuses.
    let obs = observe_board(
        &color_images(r)[..2],
        &board,
        &r.intrinsics,
        &ObserveConfig::default(),
    )
    .unwrap();
    let frames = hand_eye_frames(r, &obs);
    let e = calibrate_hand_eye(&frames, &HandEyeConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 3 frames"), "{e}");

    // Mismatched counts: a frame without an image is named.
    let color_dir = dir.join(&r.name).join("color");
    let ids: Vec<String> = ["000", "001", "002", "003", "004"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let e = depthcal::vision::find_frame_images(&color_dir, &ids)
        .unwrap_err()
        .to_string();
    assert!(e.contains("frames 004") && e.contains("color"), "{e}");
    let (found, extra) = depthcal::vision::find_frame_images(&color_dir, &ids[..3]).unwrap();
    assert_eq!(found.len(), 3);
    assert_eq!(extra.len(), 1, "{extra:?}");

    // Images of another size than the intrinsics.
    let mut small = r.intrinsics.clone();
    small.width = 320;
    let e = observe_board(&color_images(r), &board, &small, &ObserveConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("640x480") && e.contains("320x480"), "{e}");

    // Colour images missing: the checkerboard method names the robot and the frame.
    let manifest = std::fs::read_to_string(dir.join("cell.toml")).unwrap();
    let no_color: String = manifest
        .lines()
        .filter(|l| !l.starts_with("color"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(dir.join("cell.toml"), no_color).unwrap();
    let cell = Cell::open(&dir).unwrap();
    let e = board_in_robot_base(&cell.robots[0], &board, &ObserveConfig::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no colour images") && e.contains(&cell.robots[0].name) && e.contains("000"),
        "{e}"
    );
    let e = checkerboard_initializer(&cell, &[])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no colour images"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
