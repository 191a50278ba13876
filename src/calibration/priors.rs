//! What a user knows about a cell before calibrating it, stated in `cell.toml`:
//!
//! ```toml
//! [priors]
//! bases_level = true          # both bases upright: T_base1_base2 is (nearly) a rotation about z
//! max_tilt_deg = 5.0          # how far from upright (default 5° when bases_level is true)
//! base_distance_m = 1.2       # rough distance between the base origins
//! base_distance_tolerance_m = 0.3   # ± (default 0.3 m)
//! ```
//!
//! The priors become a [`PoseConstraint`] on the global stage's hypotheses, and a result that violates
//! them is not trusted.
//!
//! **The default.** depthcal's method assumes two robots whose bases stand upright at about the same
//! level. When `cell.toml` has no `[priors]` table, or leaves `bases_level` out, the bases are *assumed*
//! level (tilt ≤ 5°) and the report says so; `bases_level = false` states a tilted base, and `calibrate
//! --no-priors` drops every prior. The base distance is never assumed.

use crate::error::{Error, Result};
use crate::registration::PoseConstraint;
use serde::{Deserialize, Serialize};

/// The `[priors]` table of a cell manifest.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CellPriors {
    /// Both robot bases stand upright on a level floor. Absent: assumed true (see the module docs).
    pub bases_level: Option<bool>,
    /// Largest tilt of `T_base1_base2` from a pure rotation about z, degrees (default 5 with `bases_level`).
    pub max_tilt_deg: Option<f64>,
    /// Rough distance between the base origins, metres.
    pub base_distance_m: Option<f64>,
    /// Tolerance on `base_distance_m`, metres (default 0.3).
    pub base_distance_tolerance_m: Option<f64>,
    /// Workspace box `[x0, y0, z0, x1, y1, z1]` in the reference base frame, metres (informational; the
    /// simulator writes it).
    pub workspace: Option<[f64; 6]>,
}

impl CellPriors {
    /// No prior at all (`--no-priors`).
    pub fn none() -> Self {
        CellPriors {
            bases_level: Some(false),
            ..CellPriors::default()
        }
    }

    /// Reads the `[priors]` table from a manifest's extra tables (absent: the default assumption, level
    /// bases). `path` names the manifest in errors.
    pub fn from_manifest_extra(extra: &toml::Table, path: &std::path::Path) -> Result<Self> {
        let p: CellPriors = match extra.get("priors") {
            None => CellPriors::default(),
            Some(v) => v
                .clone()
                .try_into()
                .map_err(|e| Error::format(path, format!("[priors]: {e}")))?,
        };
        p.validate()
            .map_err(|m| Error::format(path, format!("[priors]: {m}")))?;
        Ok(p)
    }

    /// Checks the values; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if let Some(t) = self.max_tilt_deg {
            if !(t > 0.0 && t <= 180.0) {
                return Err(format!("max_tilt_deg = {t}: must be in (0, 180] degrees"));
            }
        }
        if let Some(d) = self.base_distance_m {
            if !(d > 0.0 && d.is_finite()) {
                return Err(format!(
                    "base_distance_m = {d}: must be a positive distance in metres"
                ));
            }
        }
        if let Some(d) = self.base_distance_tolerance_m {
            if !(d > 0.0 && d.is_finite()) {
                return Err(format!(
                    "base_distance_tolerance_m = {d}: must be a positive distance in metres"
                ));
            }
        }
        Ok(())
    }

    /// True when the bases are level by assumption (the cell did not say).
    pub fn level_assumed(&self) -> bool {
        self.bases_level.is_none()
    }

    /// The constraint these priors put on `T_base1_base2`.
    pub fn constraint(&self) -> PoseConstraint {
        let tilt = self.max_tilt_deg.or(if self.bases_level.unwrap_or(true) {
            Some(5.0)
        } else {
            None
        });
        let range = self.base_distance_m.map(|d| {
            let tol = self.base_distance_tolerance_m.unwrap_or(0.3);
            [(d - tol).max(0.0), d + tol]
        });
        PoseConstraint {
            max_tilt_deg: tilt,
            translation_range: range,
        }
    }

    /// Human-readable list of the priors in use (empty when none).
    pub fn describe(&self) -> Vec<String> {
        let c = self.constraint();
        let mut out = Vec::new();
        if let Some(t) = c.max_tilt_deg {
            if self.level_assumed() {
                out.push(format!(
                    "bases level (tilt ≤ {t}°), assumed: cell.toml does not state bases_level (--no-priors drops it)"
                ));
            } else {
                out.push(format!("bases level (tilt ≤ {t}°)"));
            }
        }
        if let Some([lo, hi]) = c.translation_range {
            out.push(format!("base distance {lo:.2}–{hi:.2} m"));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    #[test]
    fn priors_become_a_constraint() {
        let t: toml::Table =
            toml::from_str("[priors]\nbases_level = true\nbase_distance_m = 1.2\n").unwrap();
        let p = CellPriors::from_manifest_extra(&t, std::path::Path::new("cell.toml")).unwrap();
        let c = p.constraint();
        let yaw = Isometry3::from_parts(
            Translation3::new(1.1, 0.3, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2.5),
        );
        assert!(c.accepts(&yaw));
        let tilted = Isometry3::from_parts(
            Translation3::new(1.1, 0.3, 0.0),
            UnitQuaternion::from_euler_angles(0.2, 0.0, 2.5),
        );
        assert!(!c.accepts(&tilted));
        let far =
            Isometry3::from_parts(Translation3::new(2.0, 0.0, 0.0), UnitQuaternion::identity());
        assert!(!c.accepts(&far));
        assert_eq!(p.describe().len(), 2);
        // No table: level bases assumed, no distance.
        let none = CellPriors::from_manifest_extra(&toml::Table::new(), std::path::Path::new("c"))
            .unwrap();
        assert!(none.level_assumed());
        assert_eq!(none.constraint().max_tilt_deg, Some(5.0));
        assert!(none.constraint().translation_range.is_none());
        assert!(
            none.describe()[0].contains("assumed"),
            "{:?}",
            none.describe()
        );
        assert!(CellPriors::none().constraint().is_empty());
        let neg: toml::Table = toml::from_str("[priors]\nbase_distance_m = -1\n").unwrap();
        assert!(CellPriors::from_manifest_extra(&neg, std::path::Path::new("c")).is_err());
        let bad: toml::Table = toml::from_str("[priors]\nbases_levl = true\n").unwrap();
        let e =
            CellPriors::from_manifest_extra(&bad, std::path::Path::new("cell.toml")).unwrap_err();
        assert!(
            e.to_string().contains("cell.toml") && e.to_string().contains("bases_levl"),
            "{e}"
        );
    }
}
