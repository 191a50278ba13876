//! The image initialisers of a robot-to-robot calibration: the calibration types
//! ([`crate::calibration::board_init`], [`crate::calibration::marker_init`],
//! [`crate::calibration::feature_init`]) built from what this module finds in the colour images.

use crate::calibration::board_init::{
    checkerboard_initializer_with, BoardInBase, CheckerboardInitializer,
};
use crate::calibration::feature_init::{FeatureInitializer, FeatureMethodConfig};
use crate::calibration::marker_init::{
    marker_initializer_with, MarkerInitializer, MarkerMethodConfig,
};
use crate::cell::{Board, Cell, CellRobot};
use crate::error::Result;
use crate::vision::observe::{board_in_robot_base, ObserveConfig};
use std::path::PathBuf;

/// The checkerboard initialiser of a cell: each robot's `T_base_board` from `given` (robot name → a
/// `depthcal handeye --json` file) or found in its colour images of the cell's `[board]`. Returns it with
/// warnings (frames where the board was not found).
pub fn checkerboard_initializer(
    cell: &Cell,
    given: &[(String, PathBuf)],
) -> Result<(CheckerboardInitializer, Vec<String>)> {
    checkerboard_initializer_with(cell, given, &mut board_from_images)
}

/// A robot's `T_base_board` from its colour images: the board's pose in each frame (detection + PnP),
/// through the robot pose and hand-eye into the base, robustly averaged.
pub fn board_from_images(
    r: &CellRobot,
    board: &Board,
    warnings: &mut Vec<String>,
) -> Result<BoardInBase> {
    let b = board_in_robot_base(r, board, &ObserveConfig::default())?;
    for line in b.observations.rejected_lines() {
        warnings.push(format!("robot {:?}: {line}", r.name));
    }
    let n = b.frames.len();
    Ok(BoardInBase::from_average(
        &r.name,
        &b.average,
        &format!("{n} colour images"),
    ))
}

/// The marker initialiser of a cell: each robot's markers of the cell's `[markers]` found in its colour
/// images and placed with the aligned depth. Returns it with notes about frames and sightings not used.
pub fn marker_initializer(
    cell: &Cell,
    cfg: &MarkerMethodConfig,
) -> Result<(MarkerInitializer, Vec<String>)> {
    marker_initializer_with(cell, cfg, &mut |r, target, cfg| {
        let s = crate::vision::marker_sightings::robot_marker_sightings(r, target, cfg)?;
        Ok((s.sightings, s.notes))
    })
}

/// The feature initialiser of a cell: both robots' keypoints found, lifted with depth and matched.
/// Returns it with notes about frames that gave no usable keypoints.
pub fn feature_initializer(
    cell: &Cell,
    cfg: &FeatureMethodConfig,
) -> Result<(FeatureInitializer, Vec<String>)> {
    let (reference, other) = cell.robot_pair()?;
    crate::vision::feature_lift::feature_correspondences(reference, other, cfg)
}
