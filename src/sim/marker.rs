//! Square fiducial markers (ArUco / AprilTag style) printed on sheets lying on the table, for the marker
//! method of `calibrate` with exact ground truth.
//!
//! Each marker is a black square of `size_m` (border included) whose inner `n × n` cells carry the code of
//! one marker of a dictionary, on white paper of `margin_m` around. The codes are those of OpenCV's
//! predefined dictionaries (`marker_codes`, dumped from OpenCV; with the `vision` feature a test
//! checks them against the OpenCV the crate links). Like the checkerboard, a marker is a sheet of zero
//! thickness: it changes the colour image, not the depth.
//!
//! The marker frame is OpenCV's: origin at the centre of the black square, `x` to the right of the printed
//! marker, `y` up as printed, `z` out of the printed face (here straight up, out of the table).

use super::board::{validate_print_look, TablePrint};
use super::marker_codes::{APRILTAG36H11, DICT4X4_50, DICT5X5_100, DICT6X6_250};
use crate::cell::MarkerDictionary;
use crate::error::{Error, Result};
use crate::geometry::Rng;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// The dictionaries the simulator can print: `(dictionary, inner bits per side, codes)`.
const DICTIONARIES: [(MarkerDictionary, u32, &[u64]); 4] = [
    (MarkerDictionary::Aruco4x4_50, 4, &DICT4X4_50),
    (MarkerDictionary::Aruco5x5_100, 5, &DICT5X5_100),
    (MarkerDictionary::Aruco6x6_250, 6, &DICT6X6_250),
    (MarkerDictionary::AprilTag36h11, 6, &APRILTAG36H11),
];

/// The dictionary `name` names (any spelling [`MarkerDictionary`] accepts) with its bits per side and
/// codes, when the simulator has it.
fn dictionary(name: &str) -> Option<(MarkerDictionary, u32, &'static [u64])> {
    let d: MarkerDictionary = name.parse().ok()?;
    DICTIONARIES.iter().find(|e| e.0 == d).copied()
}

/// The inner bits of marker `id` of dictionary `name`: `(bits per side n, code)`, the code's `n²` bits
/// row-major from the top-left inner cell as printed, most significant first, 1 = white.
pub fn marker_code(name: &str, id: u32) -> Result<(u32, u64)> {
    let (canon, n, codes) = dictionary(name).ok_or_else(|| {
        Error::InvalidInput(format!(
            "the simulator has no marker dictionary {name:?}; it prints {}",
            DICTIONARIES.map(|d| d.0.to_string()).join(", ")
        ))
    })?;
    let code = codes.get(id as usize).ok_or_else(|| {
        Error::InvalidInput(format!(
            "marker id {id} is not in dictionary {canon} (ids 0–{})",
            codes.len() - 1
        ))
    })?;
    Ok((n, *code))
}

/// Settings of the simulated markers (metres, degrees). Every field has a default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimMarkersConfig {
    /// Dictionary (default `4x4_50`; also `5x5_100`, `6x6_250`, `tag36h11`).
    pub dictionary: String,
    /// The marker ids to print, one sheet each (default `[0, 1, 2]`).
    pub ids: Vec<u32>,
    /// Edge of each marker's black square, metres (default 0.08).
    pub size_m: f64,
    /// White paper around the black square, metres (default 0.015).
    pub margin_m: f64,
    /// Marker centres are uniform within this radius of the table centre, metres (default 0.2): where
    /// both robots look.
    pub placement_radius_m: f64,
    /// Each marker's yaw is uniform in ± this, degrees (default 180).
    pub yaw_range_deg: f64,
    /// Linear albedo of black and white (default `[0.04, 0.85]`).
    pub albedo: [f64; 2],
    /// Sub-pixel rays per axis for the pixel coverage (default 6).
    pub supersample: u32,
    /// Gaussian blur of the colour image (optics), pixels (default 0.7).
    pub blur_sigma_px: f64,
}

impl Default for SimMarkersConfig {
    fn default() -> Self {
        SimMarkersConfig {
            dictionary: "4x4_50".into(),
            ids: vec![0, 1, 2],
            size_m: 0.08,
            margin_m: 0.015,
            placement_radius_m: 0.2,
            yaw_range_deg: 180.0,
            albedo: [0.04, 0.85],
            supersample: 6,
            blur_sigma_px: 0.7,
        }
    }
}

impl SimMarkersConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |f: &str, msg: String| {
            Err(Error::Config {
                field: format!("scene.markers.{f}"),
                msg,
            })
        };
        for &id in &self.ids {
            if let Err(e) = marker_code(&self.dictionary, id) {
                return bad("ids / dictionary", e.to_string());
            }
        }
        if self.ids.is_empty() {
            return bad("ids", "must list at least one marker id".into());
        }
        let mut sorted = self.ids.clone();
        sorted.sort_unstable();
        if sorted.windows(2).any(|w| w[0] == w[1]) {
            return bad("ids", format!("ids must differ, found {:?}", self.ids));
        }
        if !(self.size_m.is_finite() && (0.01..=1.0).contains(&self.size_m)) {
            return bad(
                "size_m",
                format!("must be in [0.01, 1] m, found {}", self.size_m),
            );
        }
        if !(self.margin_m.is_finite() && self.margin_m >= 0.0) {
            return bad("margin_m", format!("must be ≥ 0, found {}", self.margin_m));
        }
        if !(self.placement_radius_m.is_finite() && self.placement_radius_m >= 0.0) {
            return bad(
                "placement_radius_m",
                format!("must be ≥ 0, found {}", self.placement_radius_m),
            );
        }
        if !(self.yaw_range_deg.is_finite() && self.yaw_range_deg >= 0.0) {
            return bad(
                "yaw_range_deg",
                format!("must be ≥ 0, found {}", self.yaw_range_deg),
            );
        }
        validate_print_look(
            "scene.markers",
            self.albedo,
            self.supersample,
            self.blur_sigma_px,
        )?;
        Ok(())
    }
}

/// One marker sheet placed on the table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimMarker {
    /// The marker id in its dictionary.
    pub id: u32,
    /// Pose of the marker frame in the world (table) frame, metres.
    pub t_world_marker: Isometry3<f64>,
    /// Inner bits per side.
    pub bits: u32,
    /// The code ([`marker_code`]).
    pub code: u64,
}

/// The markers of a scene with the settings they were made from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimMarkers {
    /// The markers, in the order of `config.ids`.
    pub markers: Vec<SimMarker>,
    /// The settings.
    pub config: SimMarkersConfig,
}

impl SimMarkers {
    /// Places the markers of `cfg` on the table top, each clear of the others and of `keep_clear` (a test
    /// of a disc `(centre, radius)` against what is already on the table, e.g. the checkerboard), with
    /// random positions and yaws drawn from `rng`. Errors when a marker finds no room.
    pub fn place(
        cfg: &SimMarkersConfig,
        rng: &mut Rng,
        keep_clear: &dyn Fn([f64; 2], f64) -> bool,
    ) -> Result<Self> {
        cfg.validate()?;
        let radius = cfg.disc_radius();
        let mut markers: Vec<SimMarker> = Vec::with_capacity(cfg.ids.len());
        let yaw_r = cfg.yaw_range_deg.to_radians();
        for &id in &cfg.ids {
            let (bits, code) = marker_code(&cfg.dictionary, id)?;
            let mut placed = None;
            for _ in 0..1000 {
                let rr = cfg.placement_radius_m * rng.next_f64().sqrt();
                let th = rng.uniform(0.0, std::f64::consts::TAU);
                let c = [rr * th.cos(), rr * th.sin()];
                let yaw = rng.uniform(-yaw_r, yaw_r);
                let clear_of_others = markers.iter().all(|m| {
                    let p = m.t_world_marker.translation.vector;
                    (p.x - c[0]).hypot(p.y - c[1]) > 2.0 * radius + 0.01
                });
                if clear_of_others && !keep_clear(c, radius + 0.01) {
                    placed = Some((c, yaw));
                    break;
                }
            }
            let Some((c, yaw)) = placed else {
                return Err(Error::Config {
                    field: "scene.markers".into(),
                    msg: format!(
                        "no room for marker {id} within {} m of the table centre (markers of {} m with {} m margin); \
                         use fewer or smaller markers or a larger placement_radius_m",
                        cfg.placement_radius_m, cfg.size_m, cfg.margin_m
                    ),
                });
            };
            markers.push(SimMarker {
                id,
                t_world_marker: Isometry3::from_parts(
                    Translation3::new(c[0], c[1], 0.0),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
                ),
                bits,
                code,
            });
        }
        Ok(SimMarkers {
            markers,
            config: cfg.clone(),
        })
    }

    /// True when a disc of radius `r` (metres) centred at table point `c` overlaps a marker sheet.
    pub fn overlaps_disc(&self, c: [f64; 2], r: f64) -> bool {
        let half = self.config.size_m / 2.0 + self.config.margin_m;
        self.markers.iter().any(|m| {
            let p = m.t_world_marker.inverse() * Point3::new(c[0], c[1], 0.0);
            let dx = (p.x.abs() - half).max(0.0);
            let dy = (p.y.abs() - half).max(0.0);
            dx.hypot(dy) < r
        })
    }

    /// The `[markers]` table of `cell.toml`: dictionary and black-square edge.
    pub fn manifest_table(&self) -> toml::Value {
        let mut t = toml::Table::new();
        let canon = dictionary(&self.config.dictionary)
            .map_or_else(|| self.config.dictionary.clone(), |d| d.0.to_string());
        t.insert("dictionary".into(), canon.into());
        t.insert("size_m".into(), self.config.size_m.into());
        toml::Value::Table(t)
    }
}

impl TablePrint for SimMarkers {
    /// `None` off every sheet.
    fn albedo_at(&self, x: f64, y: f64) -> Option<f64> {
        let s = self.config.size_m;
        let half = s / 2.0;
        let outer = half + self.config.margin_m;
        let [black, white] = self.config.albedo;
        self.markers.iter().find_map(|m| {
            let p = m.t_world_marker.inverse() * Point3::new(x, y, 0.0);
            if p.x.abs() > outer || p.y.abs() > outer {
                return None;
            }
            if p.x.abs() >= half || p.y.abs() >= half {
                return Some(white);
            }
            let n = m.bits as i64;
            let cell = s / (n + 2) as f64;
            // Column from the left, row from the top (y up as printed).
            let c = (((p.x + half) / cell).floor() as i64).clamp(0, n + 1);
            let r = (((half - p.y) / cell).floor() as i64).clamp(0, n + 1);
            if c == 0 || r == 0 || c == n + 1 || r == n + 1 {
                return Some(black);
            }
            let k = (r - 1) * n + (c - 1);
            let bit = (m.code >> (n * n - 1 - k)) & 1;
            Some(if bit == 1 { white } else { black })
        })
    }

    fn supersample(&self) -> u32 {
        self.config.supersample
    }
}

impl SimMarkersConfig {
    /// Radius of a disc that covers one sheet, metres.
    fn disc_radius(&self) -> f64 {
        (self.size_m / 2.0 + self.margin_m) * std::f64::consts::SQRT_2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_names_and_cells() {
        assert_eq!(marker_code("DICT_4X4_50", 0).unwrap().0, 4);
        assert_eq!(
            marker_code("tag36h11", 3).unwrap(),
            marker_code("DICT_APRILTAG_36h11", 3).unwrap()
        );
        assert!(marker_code("4x4_50", 50)
            .unwrap_err()
            .to_string()
            .contains("ids 0–49"));
        assert!(marker_code("7x7_1000", 0).is_err());
        // Codes are distinct within a dictionary.
        for d in DICTIONARIES {
            let mut c = d.2.to_vec();
            c.sort_unstable();
            c.dedup();
            assert_eq!(c.len(), d.2.len(), "{}", d.0);
            assert_eq!(d.2.len() as u32, d.0.marker_count());
            assert_eq!(d.1, d.0.bits());
        }
        let cfg = SimMarkersConfig {
            ids: vec![7],
            placement_radius_m: 0.0,
            yaw_range_deg: 0.0,
            ..Default::default()
        };
        let m = SimMarkers::place(&cfg, &mut Rng::new(1), &|_, _| false).unwrap();
        let (n, code) = marker_code("4x4_50", 7).unwrap();
        let cell = 0.08 / 6.0;
        // Border black, margin white, inner cells as the code says (row 0, col 0 is the top-left).
        assert_eq!(m.albedo_at(-0.04 + cell / 2.0, 0.0), Some(0.04));
        assert_eq!(m.albedo_at(0.045, 0.0), Some(0.85));
        assert_eq!(m.albedo_at(0.06, 0.0), None);
        for r in 0..n {
            for c in 0..n {
                let x = -0.04 + (c as f64 + 1.5) * cell;
                let y = 0.04 - (r as f64 + 1.5) * cell;
                let bit = (code >> (n * n - 1 - (r * n + c))) & 1;
                let want = if bit == 1 { 0.85 } else { 0.04 };
                assert_eq!(m.albedo_at(x, y), Some(want), "cell {r},{c}");
            }
        }
        assert!(m.overlaps_disc([0.0, 0.0], 0.01));
        assert!(!m.overlaps_disc([0.3, 0.3], 0.05));
    }

    #[test]
    fn placement_keeps_clear_and_errors_without_room() {
        let cfg = SimMarkersConfig::default();
        // Keep clear of a disc of 5 cm at the centre.
        let m =
            SimMarkers::place(&cfg, &mut Rng::new(4), &|c, r| c[0].hypot(c[1]) < r + 0.05).unwrap();
        assert_eq!(m.markers.len(), 3);
        for (i, k) in m.markers.iter().enumerate() {
            let p = k.t_world_marker.translation.vector;
            assert!(p.x.hypot(p.y) > cfg.disc_radius() + 0.05);
            for q in &m.markers[..i] {
                let q = q.t_world_marker.translation.vector;
                assert!((p - q).norm() > 2.0 * cfg.disc_radius());
            }
        }
        let crowded = SimMarkersConfig {
            ids: (0..20).collect(),
            placement_radius_m: 0.05,
            ..Default::default()
        };
        let e = SimMarkers::place(&crowded, &mut Rng::new(4), &|_, _| false).unwrap_err();
        assert!(e.to_string().contains("no room"), "{e}");
    }

    /// The embedded codes are OpenCV's: every marker of the four dictionaries against the dictionaries of
    /// the OpenCV the crate links.
    #[cfg(feature = "vision")]
    #[test]
    fn embedded_codes_are_opencvs() {
        for (dict, _, codes) in DICTIONARIES {
            let name = dict.to_string();
            for id in 0..codes.len() as u32 {
                let bits = crate::vision::dictionary_bits(dict, id).unwrap();
                let (n, code) = marker_code(&name, id).unwrap();
                let ours: Vec<bool> = (0..n * n)
                    .map(|k| (code >> (n * n - 1 - k)) & 1 == 1)
                    .collect();
                assert_eq!(ours, bits, "{name} id {id}");
            }
        }
    }
}
