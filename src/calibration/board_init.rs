//! Robot-to-robot by checkerboard: both robots see the same board, so
//! `T_base1_base2 = T_base1_board · T_base2_board⁻¹`.
//!
//! Each robot's `T_base_board` comes from its own frames (robot pose × hand-eye × `T_cam_board`,
//! averaged with [`crate::calibration::average`]; the `vision` feature computes it from a cell's colour
//! images) or from an earlier `depthcal handeye --json` run (its `T_base_board`). The uncertainty of the
//! result combines the standard errors of both averages and the lever arm of the second board pose's
//! rotation error.

use crate::calibration::average::PoseAverage;
use crate::calibration::initializer::{InitialGuess, Initializer, InitializerInput};
use crate::cell::{Board, Cell, CellRobot};
use crate::error::{Error, Result};
use crate::geometry::transform::isometry_from_rows;
use nalgebra::Isometry3;
use std::path::{Path, PathBuf};

/// The board pose in one robot's base with its spread over the frames that measured it.
#[derive(Clone, Debug, PartialEq)]
pub struct BoardInBase {
    /// The robot's name.
    pub robot: String,
    /// `T_base_board`, metres.
    pub t_base_board: Isometry3<f64>,
    /// Frames averaged (at least 1).
    pub frames: usize,
    /// RMS rotation of the per-frame poses about the average, degrees.
    pub rotation_rms_deg: f64,
    /// RMS translation of the per-frame poses about the average, millimetres.
    pub translation_rms_mm: f64,
    /// Where it came from (for the report).
    pub source: String,
}

impl BoardInBase {
    /// From a pose average over `frames` frames.
    pub fn from_average(robot: &str, avg: &PoseAverage, source: &str) -> Self {
        BoardInBase {
            robot: robot.to_string(),
            t_base_board: avg.mean,
            frames: avg.rotation_deg.len().max(1),
            rotation_rms_deg: avg.rotation_rms_deg,
            translation_rms_mm: avg.translation_rms_mm,
            source: source.to_string(),
        }
    }

    /// Reads the `T_base_board` of a `depthcal handeye --json` output (with its `T_base_board_spread` and
    /// `residual_summary.frames` when present).
    pub fn from_handeye_json(robot: &str, path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
        let m = v.get("T_base_board").ok_or_else(|| {
            Error::format(
                path,
                "no field `T_base_board` (expected the JSON of `depthcal handeye --json`, eye-in-hand)",
            )
        })?;
        let rows = crate::io::matrix::matrix_from_json(m).map_err(|m| {
            Error::format(
                path,
                format!("field `T_base_board` must be a 4x4 matrix (4 rows of 4 numbers): {m}"),
            )
        })?;
        let t = isometry_from_rows(&rows, "T_base_board")
            .map_err(|e| Error::format(path, e.to_string()))?;
        // `target_spread` in the report's schema; `T_base_board_spread` in files of earlier versions.
        let spread = v
            .get("target_spread")
            .or_else(|| v.get("T_base_board_spread"));
        let num = |o: Option<&serde_json::Value>, k: &str| {
            o.and_then(|o| o.get(k)).and_then(|x| x.as_f64())
        };
        let frames = v
            .get("residual_summary")
            .and_then(|s| s.get("frames"))
            .and_then(|x| x.as_u64())
            .unwrap_or(1)
            .max(1) as usize;
        Ok(BoardInBase {
            robot: robot.to_string(),
            t_base_board: t,
            frames,
            rotation_rms_deg: num(spread, "rotation_rms_deg").unwrap_or(0.0),
            translation_rms_mm: num(spread, "translation_rms_mm").unwrap_or(0.0),
            source: path.display().to_string(),
        })
    }

    /// 1-σ of the average's rotation (degrees) and translation (millimetres): the spread over √frames.
    pub fn standard_error(&self) -> (f64, f64) {
        let n = (self.frames as f64).sqrt();
        (self.rotation_rms_deg / n, self.translation_rms_mm / n)
    }
}

/// `T_base1_base2` from the board pose in both bases.
#[derive(Clone, Debug, PartialEq)]
pub struct CheckerboardInitializer {
    /// The board in the reference robot's base (base1).
    pub reference: BoardInBase,
    /// The board in the other robot's base (base2).
    pub other: BoardInBase,
}

impl CheckerboardInitializer {
    /// `T_base1_base2 = T_base1_board · T_base2_board⁻¹` with its 1-σ rotation (degrees) and translation
    /// (metres) uncertainty.
    pub fn estimate(&self) -> (Isometry3<f64>, f64, f64) {
        let t = self.reference.t_base_board * self.other.t_base_board.inverse();
        let (r1, t1) = self.reference.standard_error();
        let (r2, t2) = self.other.standard_error();
        // A rotation error δ of T_base2_board moves base2's origin, seen from the board, by δ·|t_board_base2|.
        let lever_m = self.other.t_base_board.translation.vector.norm();
        let sigma_rot_deg = r1.hypot(r2);
        let lever_mm = r2.to_radians() * lever_m * 1e3 + r1.to_radians() * lever_m * 1e3;
        let sigma_t_mm = (t1 * t1 + t2 * t2 + lever_mm * lever_mm).sqrt();
        (t, sigma_rot_deg, sigma_t_mm * 1e-3)
    }
}

impl Initializer for CheckerboardInitializer {
    fn name(&self) -> &str {
        "checkerboard"
    }
    fn needs_clouds(&self) -> bool {
        false
    }
    fn initialize(&self, _input: &InitializerInput) -> Result<InitialGuess> {
        let (transform, sigma_rotation_deg, sigma_translation_m) = self.estimate();
        let side = |b: &BoardInBase| {
            format!(
                "{} {} frames (spread {:.3}° / {:.2} mm, {})",
                b.robot, b.frames, b.rotation_rms_deg, b.translation_rms_mm, b.source
            )
        };
        Ok(InitialGuess {
            transform,
            // Never claim better than 0.01° / 0.1 mm from a board.
            sigma_rotation_deg: sigma_rotation_deg.max(0.01),
            sigma_translation_m: sigma_translation_m.max(1e-4),
            detail: format!(
                "checkerboard: T_base1_board · T_base2_board⁻¹ from {}; {}",
                side(&self.reference),
                side(&self.other)
            ),
            ambiguity: None,
            alternatives: Vec::new(),
        })
    }
}

/// Finds a robot's board pose in its colour images (`depthcal::vision::initializers` with the `vision`
/// feature; [`board_needs_vision`] without), noting frames it could not use in the warnings.
pub type BoardFinder<'a> =
    dyn FnMut(&CellRobot, &Board, &mut Vec<String>) -> Result<BoardInBase> + 'a;

/// The checkerboard initialiser of a cell: each robot's `T_base_board` from `given` (robot name → a
/// `depthcal handeye --json` file) or, for robots without one, found by `find` in the robot's colour
/// images with the cell's `[board]`. Returns it with warnings about frames not used.
pub fn checkerboard_initializer_with(
    cell: &Cell,
    given: &[(String, PathBuf)],
    find: &mut BoardFinder<'_>,
) -> Result<(CheckerboardInitializer, Vec<String>)> {
    let (reference, other) = cell.robot_pair()?;
    let manifest = cell.dir.join(crate::cell::MANIFEST_FILE);
    for (name, _) in given {
        cell.robot(name)?;
    }
    let mut warnings = Vec::new();
    let mut side = |r: &CellRobot| -> Result<BoardInBase> {
        if let Some((_, p)) = given.iter().find(|(n, _)| n == &r.name) {
            return BoardInBase::from_handeye_json(&r.name, p);
        }
        let Some(board) = Board::from_manifest_extra(&cell.manifest.extra, &manifest)? else {
            return Err(Error::InvalidInput(format!(
                "{}: no [board] table (a checkerboard's cols, rows, square_m, or a ChArUco board's type = \"charuco\", \
                 squares_x, squares_y, square_m, marker_m, dictionary): the checkerboard method needs the board's \
                 geometry, or give robot {:?}'s board pose from a hand-eye run",
                manifest.display(),
                r.name
            )));
        };
        find(r, &board, &mut warnings)
    };
    let reference = side(reference)?;
    let other = side(other)?;
    Ok((CheckerboardInitializer { reference, other }, warnings))
}

/// The [`BoardFinder`] of a build without the `vision` feature: an error saying how to get one.
pub fn board_needs_vision(
    r: &CellRobot,
    _board: &Board,
    _warnings: &mut Vec<String>,
) -> Result<BoardInBase> {
    Err(Error::InvalidInput(format!(
        "robot {:?}: finding the board in its colour images needs depthcal built with the `vision` \
         feature (OpenCV): `cargo build --release --features vision`; or give the board pose from an \
         earlier hand-eye run (calibrate --board-pose {}=HANDEYE.json)",
        r.name, r.name
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::average::{average_poses, AverageConfig};
    use crate::geometry::transform::{isometry_to_nested, random_isometry};
    use crate::geometry::Rng;

    #[test]
    fn composes_both_board_poses_and_reads_handeye_json() {
        let mut rng = Rng::new(5);
        let t_b1_b2 = random_isometry(&mut rng, 3.0, 1.5);
        let t_b2_board = random_isometry(&mut rng, 3.0, 0.8);
        let t_b1_board = t_b1_b2 * t_b2_board;
        let a1 = average_poses(&[t_b1_board], None, &AverageConfig::default()).unwrap();
        let init = CheckerboardInitializer {
            reference: BoardInBase::from_average("left", &a1, "images"),
            other: BoardInBase {
                robot: "right".into(),
                t_base_board: t_b2_board,
                frames: 4,
                rotation_rms_deg: 0.2,
                translation_rms_mm: 1.0,
                source: "x".into(),
            },
        };
        let (t, sr, st) = init.estimate();
        let d = t.inverse() * t_b1_b2;
        assert!(d.rotation.angle() < 1e-12 && d.translation.vector.norm() < 1e-12);
        assert!((sr - 0.1).abs() < 1e-12, "{sr}");
        assert!(st > 0.5e-3, "{st}");

        let dir = std::env::temp_dir().join(format!("depthcal-board-init-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("he.json");
        let json = serde_json::json!({
            "T_base_board": isometry_to_nested(&t_b2_board),
            "T_base_board_spread": {"rotation_rms_deg": 0.05, "translation_rms_mm": 0.4},
            "residual_summary": {"frames": 9},
        });
        std::fs::write(&p, json.to_string()).unwrap();
        let b = BoardInBase::from_handeye_json("right", &p).unwrap();
        assert_eq!(b.frames, 9);
        assert!(
            (b.t_base_board.inverse() * t_b2_board)
                .translation
                .vector
                .norm()
                < 1e-12
        );
        std::fs::write(&p, r#"{"T_ee_cam": 1}"#).unwrap();
        let e = BoardInBase::from_handeye_json("right", &p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("he.json") && e.contains("T_base_board"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
