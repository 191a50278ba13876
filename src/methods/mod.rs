//! The initialisation methods of a robot-to-robot calibration: which a cell's data allows, building one
//! (the image methods from what [`crate::vision`] finds, with the `vision` feature), calibrating a cell
//! with one ([`run::calibrate_with_method`]) and comparing them all ([`run::compare_methods`]).
//!
//! This sits above `calibration` and `vision` in the module graph: calibration owns the initialisers'
//! types and mathematics, vision finds their observations in the images, and this module joins them.

pub mod run;

pub use run::{
    calibrate_refining_hand_eyes, calibrate_with_method, compare_methods, Comparison,
    HandEyeRefinement, MethodOutcome, MethodRow,
};

use crate::calibration::initializer::{GlobalRegistration, Initializer, UserGuess};
use crate::calibration::robot_to_robot::CalibrateConfig;
use crate::cell::{Board, Cell, MarkerTarget};
use crate::error::{Error, Result};
use crate::io::read_matrix_file;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Initialisation methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Depth only: FPFH + RANSAC under the cell's priors, then trimmed robust ICP.
    Depth,
    /// Start from `--init` and refine with trimmed robust ICP.
    Guess,
    /// Both robots' board poses (colour images of the cell's [board], needs the `vision` feature; or
    /// --board-pose), T_base1_board · T_base2_board⁻¹, then trimmed robust ICP.
    Checkerboard,
    /// Square fiducial markers of the cell's [markers] seen by both robots (colour + depth, `vision`
    /// feature), through the common marker frames, then trimmed robust ICP.
    Marker,
    /// 2D keypoints of both robots' colour images matched and lifted to 3D with depth, RANSAC + rigid fit
    /// (`vision` feature), then trimmed robust ICP.
    Features,
}

impl Method {
    /// Every method, in the order `compare` runs them.
    pub const ALL: [Method; 5] = [
        Method::Depth,
        Method::Guess,
        Method::Checkerboard,
        Method::Marker,
        Method::Features,
    ];

    /// The name as the command line spells it.
    pub fn name(self) -> &'static str {
        match self {
            Method::Depth => "depth",
            Method::Guess => "guess",
            Method::Checkerboard => "checkerboard",
            Method::Marker => "marker",
            Method::Features => "features",
        }
    }

    /// The method called `name` (as [`Method::name`] spells it).
    pub fn from_name(name: &str) -> Result<Self> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                Error::InvalidInput(format!(
                    "unknown method {name:?}: expected one of {}",
                    names.join(", ")
                ))
            })
    }
}

/// What a method needs beyond the cell itself.
#[derive(Clone, Debug, Default)]
pub struct MethodInputs {
    /// `--init`: the guess file.
    pub init: Option<PathBuf>,
    /// `--board-pose ROBOT=FILE`.
    pub board_pose: Vec<(String, PathBuf)>,
}

/// A built initialiser, the time it took to find its targets in the images (milliseconds; 0 when it works
/// on the clouds), and warnings for the user.
pub type BuiltInitializer = (Box<dyn Initializer>, f64, Vec<String>);

/// Builds the initialiser of `method` for `cell`: image methods find their targets here (timed).
pub fn build(
    method: Method,
    cell: &Cell,
    inputs: &MethodInputs,
    cfg: &CalibrateConfig,
) -> Result<BuiltInitializer> {
    let t0 = Instant::now();
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
    Ok(match method {
        Method::Guess => {
            let Some(p) = &inputs.init else {
                return Err(Error::InvalidInput(
                    "--method guess needs --init FILE".into(),
                ));
            };
            let b = UserGuess {
                transform: read_matrix_file(p)?,
                source: p.display().to_string(),
            };
            (Box::new(b), 0.0, Vec::new())
        }
        Method::Depth => (
            Box::new(GlobalRegistration {
                config: cfg.register.clone(),
                visibility: Some(cfg.visibility.clone()),
                search: cfg.search.clone(),
            }),
            0.0,
            Vec::new(),
        ),
        Method::Checkerboard => {
            let (init, warnings) = images::checkerboard(cell, &inputs.board_pose)?;
            (Box::new(init), ms(t0), warnings)
        }
        Method::Marker => {
            let (init, warnings) = images::marker(cell, &cfg.marker)?;
            (Box::new(init), ms(t0), warnings)
        }
        Method::Features => {
            let (init, warnings) = images::features(cell, &cfg.features)?;
            (Box::new(init), ms(t0), warnings)
        }
    })
}

/// The image initialisers: found in the images with the `vision` feature.
#[cfg(feature = "vision")]
mod images {
    pub use crate::vision::initializers::{
        checkerboard_initializer as checkerboard, feature_initializer as features,
        marker_initializer as marker,
    };
}

/// The image initialisers of a build without the `vision` feature: the checkerboard from given board
/// poses only; the others an error saying how to get them.
#[cfg(not(feature = "vision"))]
mod images {
    use crate::calibration::board_init::{
        board_needs_vision, checkerboard_initializer_with, CheckerboardInitializer,
    };
    use crate::calibration::feature_init::{FeatureInitializer, FeatureMethodConfig};
    use crate::calibration::marker_init::{
        marker_initializer_with, markers_need_vision, MarkerInitializer, MarkerMethodConfig,
    };
    use crate::cell::Cell;
    use crate::error::{Error, Result};
    use std::path::PathBuf;

    pub fn checkerboard(
        cell: &Cell,
        given: &[(String, PathBuf)],
    ) -> Result<(CheckerboardInitializer, Vec<String>)> {
        checkerboard_initializer_with(cell, given, &mut board_needs_vision)
    }

    pub fn marker(
        cell: &Cell,
        cfg: &MarkerMethodConfig,
    ) -> Result<(MarkerInitializer, Vec<String>)> {
        marker_initializer_with(cell, cfg, &mut markers_need_vision)
    }

    pub fn features(
        cell: &Cell,
        _cfg: &FeatureMethodConfig,
    ) -> Result<(FeatureInitializer, Vec<String>)> {
        let (reference, _) = cell.robot_pair()?;
        Err(Error::InvalidInput(format!(
            "robot {:?}: keypoints in its colour images need depthcal built with the `vision` feature \
             (OpenCV): `cargo build --release --features vision`",
            reference.name
        )))
    }
}

/// The methods the cell's data allows, each with the reason when it does not: depth always; the image
/// methods need colour images of every frame and the `vision` feature, the checkerboard a `[board]` and the
/// marker method a `[markers]` table.
pub fn available(cell: &Cell) -> Vec<(Method, Option<String>)> {
    let manifest = cell.dir.join(crate::cell::MANIFEST_FILE);
    let colour = cell
        .robots
        .iter()
        .all(|r| r.frames.iter().all(|f| f.color_path.is_some()));
    let vision = cfg!(feature = "vision");
    let image_reason = |extra: Option<String>| -> Option<String> {
        if extra.is_some() {
            extra
        } else if !colour {
            Some("no colour images".into())
        } else if !vision {
            Some("built without the `vision` feature".into())
        } else {
            None
        }
    };
    let board = match Board::from_manifest_extra(&cell.manifest.extra, &manifest) {
        Ok(Some(_)) => None,
        Ok(None) => Some("no [board] in cell.toml".to_string()),
        Err(e) => Some(e.to_string()),
    };
    let markers = match MarkerTarget::from_manifest_extra(&cell.manifest.extra, &manifest) {
        Ok(Some(_)) => None,
        Ok(None) => Some("no [markers] in cell.toml".to_string()),
        Err(e) => Some(e.to_string()),
    };
    vec![
        (Method::Depth, None),
        (Method::Checkerboard, image_reason(board)),
        (Method::Marker, image_reason(markers)),
        (Method::Features, image_reason(None)),
    ]
}
