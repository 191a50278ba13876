//! The settings `calibrate` and `compare` share (the methods themselves are the library's
//! `depthcal::methods`).

use anyhow::{Context, Result};
use depthcal::calibration::robot_to_robot::CalibrateConfig;
use std::path::PathBuf;

pub use depthcal::methods::{Method, MethodInputs};

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
        cfg.validate().with_context(|| {
            super::output::config_source(self.config.as_deref(), "the calibrate configuration")
        })?;
        Ok(cfg)
    }

    /// The `--config` file, if any.
    pub fn config_path(&self) -> Option<&PathBuf> {
        self.config.as_ref()
    }
}
