//! The image side of the checkerboard workflow (cargo feature `vision`): intrinsics of OpenCV's left
//! chessboard images against their reference calibration (`../shared/data`, skipped with a message when
//! absent), hand-eye and robot-to-robot from simulated board images against the simulator's ground truth,
//! and bad input.
//!
//! `cargo test --release --features vision --test vision_checkerboard -- --nocapture` prints the figures.
#![cfg(feature = "vision")]

mod common;
use depthcal::cell::{Board, Checkerboard};
use depthcal::vision::intrinsics::{calibrate_intrinsics, IntrinsicsConfig};
use depthcal::vision::CornerConfig;
use std::path::PathBuf;

/// The 13 left images of `opencv-stereo-chessboard-left-right` (there is no left10).
fn left_images(dir: &std::path::Path) -> Vec<PathBuf> {
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
        .iter()
        .map(|i| dir.join(format!("left{i:02}.jpg")))
        .collect()
}

/// Reference (left_intrinsics.yml, OpenCV's calibration sample, flags = CALIB_FIX_ASPECT_RATIO):
/// fx = fy = 535.91573, cx = 342.28315, cy = 235.57083, RMS 0.39259 px.
const REF_F: f64 = 535.91573;
const REF_CX: f64 = 342.28315;
const REF_CY: f64 = 235.57083;
const REF_RMS: f64 = 0.392_590_99;

#[test]
fn left_chessboard_images_match_the_reference_intrinsics() {
    let Some(dir) = common::data("opencv-stereo-chessboard-left-right") else {
        return;
    };
    let board = Board::from(Checkerboard::new(9, 6, 0.025).unwrap());
    let images = left_images(&dir);
    // The reference's own protocol: cornerSubPix window 11 (half side), fixed aspect ratio, k1 k2 p1 p2 k3.
    let reference_flags = IntrinsicsConfig {
        fix_aspect_ratio: true,
        corners: CornerConfig {
            subpix_half_window_px: Some(11),
            ..Default::default()
        },
        ..Default::default()
    };
    let start = std::time::Instant::now();
    let c = calibrate_intrinsics(&images, &board, &reference_flags).unwrap();
    let secs = start.elapsed().as_secs_f64();
    let i = &c.intrinsics;
    println!(
        "left images, reference protocol (window 11, FIX_ASPECT_RATIO, k3 free): {} views, RMS {:.4} px (ref {REF_RMS}), fx {:.3} fy {:.3} \
         (ref {REF_F}), cx {:.3} (ref {REF_CX}), cy {:.3} (ref {REF_CY}), k {:?}, {secs:.2} s",
        c.views.len(),
        c.rms_px,
        i.fx,
        i.fy,
        i.ppx,
        i.ppy,
        i.coeffs
    );
    assert_eq!(c.views.len(), 13, "rejected: {:?}", c.rejected);
    assert!(c.rejected.is_empty());
    for f in [i.fx, i.fy] {
        let rel = (f - REF_F).abs() / REF_F;
        assert!(rel < 0.005, "focal length {f} is {:.3}% off", rel * 100.0);
    }
    assert!(
        (c.rms_px - REF_RMS).abs() < 0.05,
        "RMS {} px vs reference {REF_RMS}",
        c.rms_px
    );
    assert!((i.ppx - REF_CX).abs() < 3.0 && (i.ppy - REF_CY).abs() < 3.0);
    // The per-view RMS combine to the overall RMS (same corner count per view).
    let combined =
        (c.views.iter().map(|v| v.rms_px * v.rms_px).sum::<f64>() / c.views.len() as f64).sqrt();
    assert!((combined - c.rms_px).abs() < 1e-9);
    assert_eq!(i.model, depthcal::camera::DistortionModel::BrownConrady);
    assert_eq!(i.rms, Some(c.rms_px));

    // depthcal's default window (40% of the corner spacing, at most 11) and what a careful user compares:
    // k3 off, and a free aspect ratio.
    for (name, cfg) in [
        (
            "auto window, FIX_ASPECT_RATIO, k3 free",
            IntrinsicsConfig {
                fix_aspect_ratio: true,
                ..Default::default()
            },
        ),
        (
            "FIX_ASPECT_RATIO, k3 = 0",
            IntrinsicsConfig {
                fix_aspect_ratio: true,
                estimate_k3: false,
                ..Default::default()
            },
        ),
        (
            "free aspect, k3 free (default)",
            IntrinsicsConfig::default(),
        ),
        (
            "free aspect, k3 = 0",
            IntrinsicsConfig {
                estimate_k3: false,
                ..Default::default()
            },
        ),
    ] {
        let c2 = calibrate_intrinsics(&images, &board, &cfg).unwrap();
        let j = &c2.intrinsics;
        println!(
            "left images, {name}: RMS {:.4} px, fx {:.3} fy {:.3} cx {:.3} cy {:.3}, k {:?}, σ(fx) {:.2} px",
            c2.rms_px, j.fx, j.fy, j.ppx, j.ppy, j.coeffs, c2.sigma[0]
        );
        // Every variant stays within 1% of the reference focal length (k3 trades against k1/k2 and f at
        // the image edge), and fits the corners better than the reference: the 11 px window is wider than
        // the squares in some views and pulls corners off (left02: 5 px).
        assert!((j.fx - REF_F).abs() / REF_F < 0.01, "{name}: fx {}", j.fx);
        assert!(c2.rms_px < REF_RMS, "{name}: RMS {}", c2.rms_px);
    }
}

#[test]
fn images_without_the_board_are_rejected_by_name() {
    let Some(dir) = common::data("opencv-stereo-chessboard-left-right") else {
        return;
    };
    // The right board size of a wrong one: 9x6 is found, 8x5 in none.
    let wrong = Board::from(Checkerboard::new(8, 5, 0.025).unwrap());
    let images = left_images(&dir)[..4].to_vec();
    let e = calibrate_intrinsics(&images, &wrong, &IntrinsicsConfig::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("none of the 4 images") && e.contains("left01.jpg"),
        "{e}"
    );
    // Two good images and a missing file: too few views, and the missing file is named.
    let board = Board::from(Checkerboard::new(9, 6, 0.025).unwrap());
    let mut two = left_images(&dir)[..2].to_vec();
    two.push(dir.join("left99.jpg"));
    let e = calibrate_intrinsics(&two, &board, &IntrinsicsConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 3") && e.contains("left99.jpg"), "{e}");
    // A non-board image among good ones is rejected and named, the rest calibrates.
    let mut mixed = left_images(&dir)[..5].to_vec();
    mixed.push(dir.join("LICENSE"));
    let c = calibrate_intrinsics(&mixed, &board, &IntrinsicsConfig::default()).unwrap();
    assert_eq!(c.views.len(), 5);
    assert_eq!(c.rejected.len(), 1);
    assert!(c.rejected[0].0.ends_with("LICENSE"), "{:?}", c.rejected);
}
