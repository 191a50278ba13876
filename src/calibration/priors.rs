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
//! The priors become a [`PoseConstraint`] on the global stage's hypotheses.

use crate::error::{Error, Result};
use crate::registration::PoseConstraint;
use serde::{Deserialize, Serialize};

/// The `[priors]` table of a cell manifest.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CellPriors {
    /// Both robot bases stand upright on a level floor.
    pub bases_level: bool,
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
    /// Reads the `[priors]` table from a manifest's extra tables (absent: no priors). `path` names the
    /// manifest in errors.
    pub fn from_manifest_extra(extra: &toml::Table, path: &std::path::Path) -> Result<Self> {
        match extra.get("priors") {
            None => Ok(CellPriors::default()),
            Some(v) => v
                .clone()
                .try_into()
                .map_err(|e| Error::format(path, format!("[priors]: {e}"))),
        }
    }

    /// The constraint these priors put on `T_base1_base2`.
    pub fn constraint(&self) -> PoseConstraint {
        let tilt = self
            .max_tilt_deg
            .or(if self.bases_level { Some(5.0) } else { None });
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
            out.push(format!("bases level (tilt ≤ {t}°)"));
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
        let bad: toml::Table = toml::from_str("[priors]\nbases_levl = true\n").unwrap();
        let e =
            CellPriors::from_manifest_extra(&bad, std::path::Path::new("cell.toml")).unwrap_err();
        assert!(
            e.to_string().contains("cell.toml") && e.to_string().contains("bases_levl"),
            "{e}"
        );
    }
}
