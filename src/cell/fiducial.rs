//! The `[markers]` table of a cell manifest: the square fiducial markers of the cell, for the marker
//! method of `calibrate`.
//!
//! ```toml
//! [markers]
//! dictionary = "4x4_50"   # an ArUco dictionary or an AprilTag family (tag36h11, ...)
//! size_m = 0.08           # edge of the black square, border included, metres
//! ids = [0, 1, 2]         # optional: only these ids are used
//! sizes = { "7" = 0.16 }  # optional: per-id edges that differ from size_m
//! ```

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The cell's markers as `cell.toml` describes them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MarkerTarget {
    /// Dictionary or family name as the marker detector accepts it.
    pub dictionary: String,
    /// Edge of each marker's black square (border included), metres.
    pub size_m: f64,
    /// Only these ids are used (default: every id of the dictionary).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ids: Option<Vec<u32>>,
    /// Per-id black-square edges, metres, for markers printed at another size (keys are ids).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub sizes: BTreeMap<String, f64>,
}

impl MarkerTarget {
    /// Reads `[markers]` from the manifest's extra tables (`None` when absent); errors name `path` and the
    /// field.
    pub fn from_manifest_extra(extra: &toml::Table, path: &Path) -> Result<Option<Self>> {
        let Some(v) = extra.get("markers") else {
            return Ok(None);
        };
        let t: MarkerTarget = v.clone().try_into().map_err(|e: toml::de::Error| {
            Error::format(
                path,
                format!(
                    "[markers]: {} (expected dictionary: a name such as \"4x4_50\" or \"tag36h11\"; \
                     size_m: black-square edge in metres; optional ids, sizes)",
                    e.message()
                ),
            )
        })?;
        t.validate()
            .map_err(|m| Error::format(path, format!("[markers]: {m}")))?;
        Ok(Some(t))
    }

    /// Checks the values; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let ok = |s: f64| s.is_finite() && s > 0.0 && s < 5.0;
        if !ok(self.size_m) {
            return Err(format!(
                "size_m must be a length in metres (0 < size_m < 5), found {}",
                self.size_m
            ));
        }
        for (k, &s) in &self.sizes {
            if k.parse::<u32>().is_err() {
                return Err(format!("sizes: key {k:?} is not a marker id"));
            }
            if !ok(s) {
                return Err(format!("sizes.{k} must be a length in metres, found {s}"));
            }
        }
        if self.ids.as_ref().is_some_and(|i| i.is_empty()) {
            return Err("ids is empty (leave it out to use every id)".into());
        }
        Ok(())
    }

    /// Whether marker `id` is one of the cell's.
    pub fn uses(&self, id: u32) -> bool {
        self.ids.as_ref().is_none_or(|i| i.contains(&id))
    }

    /// The black-square edge of marker `id`, metres.
    pub fn size_of(&self, id: u32) -> f64 {
        self.sizes
            .get(&id.to_string())
            .copied()
            .unwrap_or(self.size_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_and_rejects() {
        let p = Path::new("cell.toml");
        let t: toml::Table =
            toml::from_str("[markers]\ndictionary = \"4x4_50\"\nsize_m = 0.08\nids = [0, 2]\nsizes = { \"2\" = 0.16 }\n")
                .unwrap();
        let m = MarkerTarget::from_manifest_extra(&t, p).unwrap().unwrap();
        assert!(m.uses(0) && !m.uses(1) && m.uses(2));
        assert_eq!((m.size_of(0), m.size_of(2)), (0.08, 0.16));
        assert!(MarkerTarget::from_manifest_extra(&toml::Table::new(), p)
            .unwrap()
            .is_none());
        for bad in [
            "[markers]\ndictionary = \"4x4_50\"\n",
            "[markers]\ndictionary = \"4x4_50\"\nsize_m = -1.0\n",
            "[markers]\ndictionary = \"4x4_50\"\nsize_m = 0.1\nsizes = { \"x\" = 0.1 }\n",
            "[markers]\ndictionary = \"4x4_50\"\nsize_m = 0.1\ncolour = 1\n",
        ] {
            let t: toml::Table = toml::from_str(bad).unwrap();
            let e = MarkerTarget::from_manifest_extra(&t, p)
                .unwrap_err()
                .to_string();
            assert!(e.contains("cell.toml") && e.contains("[markers]"), "{e}");
        }
    }
}
