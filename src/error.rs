//! The library's typed error.

use std::path::PathBuf;

/// Every way a depthcal library call can fail.
///
/// Errors that come from a file name the file (and, where known, the line or field) and say what to do.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file could not be opened, read or written.
    #[error("{path}: {err}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The operating system's error (already part of the message, so not repeated as a cause).
        err: std::io::Error,
    },
    /// The file was read but its content is wrong (bad header, truncated data, bad number, ...).
    #[error("{path}: {msg}")]
    Format {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong, naming the line or field.
        msg: String,
    },
    /// The file extension does not name a format depthcal knows.
    #[error("{path}: unknown file format (expected one of {expected})")]
    UnknownFormat {
        /// The file concerned.
        path: PathBuf,
        /// The extensions that are understood.
        expected: &'static str,
    },
    /// The input data cannot be processed (empty cloud, too few points, NaN, degenerate geometry, ...).
    #[error("{0}")]
    InvalidInput(String),
    /// A configuration value is out of range.
    #[error("invalid configuration: {field}: {msg}")]
    Config {
        /// The configuration field, e.g. `icp.max_iterations`.
        field: String,
        /// Why it is invalid.
        msg: String,
    },
    /// An algorithm could not produce a result (e.g. RANSAC found no hypothesis).
    #[error("{0}")]
    Failed(String),
}

/// Shorthand for `Result<T, depthcal::Error>`.
pub type Result<T> = std::result::Result<T, Error>;

impl Error {
    /// A format error for `path` with message `msg`.
    pub fn format(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        Error::Format {
            path: path.into(),
            msg: msg.into(),
        }
    }
    /// An I/O error for `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            err: source,
        }
    }
}

impl Error {
    /// A configuration error: `field` (e.g. `icp.max_iterations`) is out of range because of `msg`.
    pub fn config(field: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Config {
            field: field.into(),
            msg: msg.into(),
        }
    }

    /// The same error with a configuration field prefixed by `prefix.` (the name of the nested
    /// configuration in its parent, e.g. `register`); other errors are returned as they are.
    pub fn within(self, prefix: &str) -> Self {
        match self {
            Error::Config { field, msg } => Error::Config {
                field: format!("{prefix}.{field}"),
                msg,
            },
            e => e,
        }
    }
}

/// Range checks shared by the configurations' `validate()`; each error names the field.
pub(crate) mod check {
    use super::{Error, Result};

    /// A finite number > 0.
    pub fn positive(field: &str, v: f64) -> Result<()> {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(Error::config(
                field,
                format!("must be a positive number, got {v}"),
            ))
        }
    }

    /// A finite number ≥ 0.
    pub fn non_negative(field: &str, v: f64) -> Result<()> {
        if v.is_finite() && v >= 0.0 {
            Ok(())
        } else {
            Err(Error::config(
                field,
                format!("must be a finite number ≥ 0, got {v}"),
            ))
        }
    }

    /// A fraction in (0, 1].
    pub fn fraction(field: &str, v: f64) -> Result<()> {
        if v > 0.0 && v <= 1.0 {
            Ok(())
        } else {
            Err(Error::config(field, format!("must be in (0, 1], got {v}")))
        }
    }

    /// An angle in (0, 180] degrees.
    pub fn angle_deg(field: &str, v: f64) -> Result<()> {
        if v > 0.0 && v <= 180.0 {
            Ok(())
        } else {
            Err(Error::config(
                field,
                format!("must be an angle in (0, 180] degrees, got {v}"),
            ))
        }
    }

    /// A count of at least `min`.
    pub fn at_least(field: &str, v: usize, min: usize) -> Result<()> {
        if v >= min {
            Ok(())
        } else {
            Err(Error::config(
                field,
                format!("must be at least {min}, got {v}"),
            ))
        }
    }

    /// A count of at most `max`.
    pub fn at_most(field: &str, v: usize, max: usize) -> Result<()> {
        if v <= max {
            Ok(())
        } else {
            Err(Error::config(
                field,
                format!("must be at most {max}, got {v}"),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Error;
    use crate::calibration::average::AverageConfig;
    use crate::calibration::consistency::ConsistencyConfig;
    use crate::calibration::feature_init::{FeatureMethodConfig, RigidRansacConfig};
    use crate::calibration::handeye::HandEyeConfig;
    use crate::calibration::marker_init::{DepthPlaneConfig, MarkerMethodConfig};
    use crate::calibration::robot_to_robot::CalibrateConfig;
    use crate::calibration::visibility::VisibilityConfig;
    use crate::features::FpfhConfig;
    use crate::fusion::FuseConfig;
    use crate::preprocess::normals::NormalConfig;
    use crate::preprocess::outlier::OutlierConfig;
    use crate::preprocess::scale::ScaleConfig;
    use crate::preprocess::surface::SurfaceConfig;
    use crate::registration::correspondence::MatchConfig;
    use crate::registration::verify::VerifyConfig;
    use crate::registration::{IcpConfig, RansacConfig, RegisterConfig, Trim, TrustConfig};

    fn field(r: super::Result<()>) -> String {
        match r {
            Err(Error::Config { field, .. }) => field,
            other => panic!("expected a configuration error, got {other:?}"),
        }
    }

    #[test]
    fn every_default_configuration_is_valid() {
        IcpConfig::default().validate().unwrap();
        RansacConfig::default().validate().unwrap();
        MatchConfig::default().validate().unwrap();
        VerifyConfig::default().validate().unwrap();
        ScaleConfig::default().validate().unwrap();
        NormalConfig::default().validate().unwrap();
        FpfhConfig::default().validate().unwrap();
        TrustConfig::default().validate().unwrap();
        RegisterConfig::default().validate().unwrap();
        FuseConfig::default().validate().unwrap();
        OutlierConfig::default().validate().unwrap();
        SurfaceConfig::default().validate().unwrap();
        ConsistencyConfig::default().validate().unwrap();
        MarkerMethodConfig::default().validate().unwrap();
        DepthPlaneConfig::default().validate().unwrap();
        RigidRansacConfig::default().validate().unwrap();
        FeatureMethodConfig::default().validate().unwrap();
        HandEyeConfig::default().validate().unwrap();
        AverageConfig::default().validate().unwrap();
        VisibilityConfig::default().validate().unwrap();
        CalibrateConfig::default().validate().unwrap();
        CalibrateConfig::default().register.validate().unwrap();
        #[cfg(feature = "sim")]
        crate::sim::SimConfig::default().validate().unwrap();
    }

    #[test]
    fn errors_name_the_field() {
        let mut r = RegisterConfig::default();
        r.icp.max_iterations = 0;
        assert_eq!(field(r.validate()), "icp.max_iterations");
        let mut c = CalibrateConfig::default();
        c.register.icp.trim = Trim::Fixed(1.5);
        assert_eq!(field(c.validate()), "register.icp.trim.fixed");
        let mut c = CalibrateConfig::default();
        c.register.ransac_distance_voxels = f64::NAN;
        assert_eq!(field(c.validate()), "register.ransac_distance_voxels");
        let mut c = CalibrateConfig::default();
        c.features.ransac.inlier_m = -1.0;
        assert_eq!(field(c.validate()), "features.ransac.inlier_m");
        let mut c = CalibrateConfig::default();
        c.marker.depth.shrink = 1.0;
        assert_eq!(field(c.validate()), "marker.depth.shrink");
        let e = CalibrateConfig {
            max_range_factor: Some(0.0),
            ..Default::default()
        }
        .validate()
        .unwrap_err();
        assert!(e.to_string().contains("max_range_factor"), "{e}");
        // One range cut: calibrate's own, not the fusion's.
        let mut c = CalibrateConfig::default();
        c.fuse.max_range_factor = Some(2.0);
        assert_eq!(field(c.validate()), "fuse.max_range_factor");
        let i = IcpConfig {
            max_correspondence_distance: 0.0,
            ..Default::default()
        };
        assert_eq!(field(i.validate()), "icp.max_correspondence_distance");
    }

    #[test]
    fn fields_the_pipeline_sets_are_refused_in_register_config() {
        // The pipeline sets these per level from the voxel: a value given for them would be overwritten
        // silently, so it is an error naming the field.
        RegisterConfig::default().validate().unwrap();
        let mut r = RegisterConfig::default();
        r.icp.max_correspondence_distance = 0.02;
        let e = r.validate().unwrap_err();
        assert!(e.to_string().contains("icp_distance_voxels"), "{e}");
        assert_eq!(field(Err(e)), "icp.max_correspondence_distance");
        let mut r = RegisterConfig::default();
        r.icp.translation_tolerance = 0.0;
        assert_eq!(field(r.validate()), "icp.translation_tolerance");
        let mut r = RegisterConfig::default();
        r.ransac.inlier_distance = 0.01;
        let e = r.validate().unwrap_err();
        assert!(e.to_string().contains("ransac_distance_voxels"), "{e}");
    }

    #[test]
    fn calibrate_has_one_seed_and_takes_constraints_from_the_priors() {
        let mut c = CalibrateConfig {
            seed: 4,
            ..Default::default()
        };
        c.validate().unwrap();
        c.register.seed = 4;
        c.validate().unwrap();
        c.register.seed = 5;
        assert_eq!(field(c.validate()), "register.seed");
        let mut c = CalibrateConfig::default();
        c.register.ransac.constraint.max_tilt_deg = Some(3.0);
        assert_eq!(field(c.validate()), "register.ransac.constraint");
    }
}
