//! The initialisation methods of `calibrate` and `compare`: which a cell's data allows, and building one.

use anyhow::Result;
use depthcal::calibration::board_init::checkerboard_initializer;
use depthcal::calibration::feature_init::feature_initializer;
use depthcal::calibration::initializer::{GlobalRegistration, Initializer, UserGuess};
use depthcal::calibration::marker_init::marker_initializer;
use depthcal::calibration::robot_to_robot::CalibrateConfig;
use depthcal::cell::{Cell, Checkerboard, MarkerTarget};
use depthcal::io::read_matrix_file;
use std::path::PathBuf;
use std::time::Instant;

/// Initialisation methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
}

/// The settings `calibrate` and `compare` share.
#[derive(clap::Args)]
pub struct CalibrateSettings {
    /// Ignore the [priors] table of cell.toml.
    #[arg(long)]
    no_priors: bool,
    /// Seed of the randomised steps.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// A JSON file with a (partial) CalibrateConfig.
    #[arg(long)]
    config: Option<PathBuf>,
}

impl CalibrateSettings {
    /// The configuration: the `--config` file (or the defaults) with the seed and the priors switch.
    pub fn config(&self) -> Result<CalibrateConfig> {
        let mut cfg: CalibrateConfig =
            super::output::read_config(self.config.as_deref(), "calibrate configuration")?;
        cfg.seed = self.seed;
        cfg.use_priors = !self.no_priors;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The `--config` file, if any.
    pub fn config_path(&self) -> Option<&PathBuf> {
        self.config.as_ref()
    }
}

/// What a method needs beyond the cell itself.
#[derive(Default)]
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
                anyhow::bail!("--method guess needs --init FILE");
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
                ..GlobalRegistration::default()
            }),
            0.0,
            Vec::new(),
        ),
        Method::Checkerboard => {
            let (init, warnings) = checkerboard_initializer(cell, &inputs.board_pose)?;
            (Box::new(init), ms(t0), warnings)
        }
        Method::Marker => {
            let (init, warnings) = marker_initializer(cell, &cfg.marker)?;
            (Box::new(init), ms(t0), warnings)
        }
        Method::Features => {
            let (init, warnings) = feature_initializer(cell, &cfg.features)?;
            (Box::new(init), ms(t0), warnings)
        }
    })
}

/// The methods the cell's data allows, each with the reason when it does not: depth always; the image
/// methods need colour images of every frame and the `vision` feature, the checkerboard a `[board]` and the
/// marker method a `[markers]` table.
pub fn available(cell: &Cell) -> Vec<(Method, Option<String>)> {
    let manifest = cell.dir.join(depthcal::cell::MANIFEST_FILE);
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
    let board = match Checkerboard::from_manifest_extra(&cell.manifest.extra, &manifest) {
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
