//! Shared output helpers for the commands: configuration files, matrices as text, progress spinners.

use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Isometry3;
use std::time::Duration;

/// Reads a JSON configuration file of type `T`, or the defaults when no file is given; errors name the
/// file (and an unknown key names the key).
///
/// The file is a partial configuration merged over the serialised `T::default()` (`depthcal::config_json::merge_json`): a
/// nested object such as `{"register": {"voxel": 0.03}}` in a calibrate configuration changes that one
/// field and keeps the command's own defaults for the rest of `register` (which serde's field defaults
/// alone would replace by `RegisterConfig::default()`).
pub fn read_config<T: serde::de::DeserializeOwned + serde::Serialize + Default>(
    path: Option<&std::path::Path>,
    what: &str,
) -> anyhow::Result<T> {
    use anyhow::Context;
    let Some(p) = path else {
        return Ok(T::default());
    };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    config_from_json(&text).with_context(|| format!("{}: not a valid {what}", p.display()))
}

/// Names where a configuration came from, for an error of its `validate()`: the `--config` file when
/// there is one (its values with the command's flags applied), else the command's flags.
pub fn config_source(path: Option<&std::path::Path>, what: &str) -> String {
    match path {
        Some(p) => format!("{}: {what} (with the flags applied)", p.display()),
        None => format!("{what} from the flags"),
    }
}

/// `T` from a partial JSON configuration merged over the serialised `T::default()`
/// ([`depthcal::config_json::config_from_json`], shared with the Python package's `config=`).
pub fn config_from_json<T: serde::de::DeserializeOwned + serde::Serialize + Default>(
    text: &str,
) -> anyhow::Result<T> {
    Ok(depthcal::config_json::config_from_json(text)?)
}

/// A spinner on stderr (drawn only when stderr is a terminal).
pub fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

/// The rows of a 4x4 matrix as text lines.
pub fn matrix4_text(t: &Isometry3<f64>) -> String {
    let m = depthcal::geometry::transform::isometry_to_nested(t);
    m.iter()
        .map(|r| {
            format!(
                "  {:>12.8} {:>12.8} {:>12.8} {:>12.6}",
                r[0], r[1], r[2], r[3]
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[cfg(test)]
mod tests {
    use super::config_from_json;
    use depthcal::calibration::robot_to_robot::CalibrateConfig;
    use depthcal::config_json::merge_json;
    use depthcal::registration::{RegisterConfig, Trim};

    #[test]
    fn partial_register_keeps_calibrate_defaults() {
        let c: CalibrateConfig = config_from_json(r#"{"register": {"voxel": 0.03}}"#).unwrap();
        let d = CalibrateConfig::default();
        assert_eq!(c.register.voxel, Some(0.03));
        assert!(c.register.sided);
        assert_eq!(c.register.icp_levels, d.register.icp_levels);
        assert_eq!(c.register.icp.factor, d.register.icp.factor);
        assert_eq!(c.register.icp.max_iterations, d.register.icp.max_iterations);
        assert!(!c.register.matching.mutual);
        assert_eq!(c.register.ransac.verify_top, d.register.ransac.verify_top);
        assert_eq!(c.fuse.depth_views, d.fuse.depth_views);
    }

    #[test]
    fn enum_variants_and_nulls_replace() {
        let c: RegisterConfig =
            config_from_json(r#"{"icp": {"trim": {"fixed": 0.5}}, "verify": null}"#).unwrap();
        assert_eq!(c.icp.trim, Trim::Fixed(0.5));
        assert!(c.verify.is_none());
        let c: RegisterConfig = config_from_json(r#"{"icp": {"trim": "none"}}"#).unwrap();
        assert_eq!(c.icp.trim, Trim::None);
        let c: RegisterConfig =
            config_from_json(r#"{"icp": {"trim": {"auto": {"lambda": 3.0}}}}"#).unwrap();
        assert_eq!(
            c.icp.trim,
            Trim::Auto {
                min_overlap: 0.05,
                lambda: 3.0
            }
        );
        let mut v = serde_json::json!({"a": {"b": 1, "c": 2}});
        merge_json(&mut v, serde_json::json!({"a": {"c": 3}, "d": 4}));
        assert_eq!(v, serde_json::json!({"a": {"b": 1, "c": 3}, "d": 4}));
    }

    #[test]
    fn an_empty_file_gives_the_defaults() {
        fn same<T: serde::de::DeserializeOwned + serde::Serialize + Default>() {
            let c: T = config_from_json("{}").unwrap();
            assert_eq!(
                serde_json::to_value(&c).unwrap(),
                serde_json::to_value(T::default()).unwrap()
            );
        }
        same::<RegisterConfig>();
        same::<CalibrateConfig>();
        same::<depthcal::calibration::handeye::HandEyeConfig>();
        #[cfg(feature = "sim")]
        same::<depthcal::sim::SimConfig>();
        #[cfg(feature = "vision")]
        {
            same::<depthcal::vision::markers::MarkerConfig>();
            same::<depthcal::vision::intrinsics::IntrinsicsConfig>();
        }
    }

    #[test]
    fn unknown_keys_are_named() {
        let e = config_from_json::<RegisterConfig>(r#"{"voxle": 0.03}"#).unwrap_err();
        assert!(format!("{e:#}").contains("voxle"), "{e:#}");
        let e =
            config_from_json::<CalibrateConfig>(r#"{"register": {"icp": {"kernal": "huber"}}}"#)
                .unwrap_err();
        assert!(format!("{e:#}").contains("kernal"), "{e:#}");
        assert!(config_from_json::<RegisterConfig>("[1]").is_err());
    }
}
