//! Square fiducial markers (ArUco dictionaries and AprilTag families): detection with sub-pixel corners,
//! and the marker frame their corners belong to.
//!
//! Two detectors read the markers ([`MarkerDetector`]): OpenCV's ArUco detector (every
//! [`MarkerDictionary`], see [`super::aruco`]) and AprilTag 3's own detector (the AprilTag families, see
//! [`super::apriltag`]). [`MarkerDetector::Auto`] takes AprilTag's for the AprilTag families and OpenCV's
//! for the ArUco dictionaries (which AprilTag cannot read), as measured on AprilTag's regression images
//! (three 799×533 JPEGs with 47 tag36h11 tags of 13–45 px; reference = AprilTag's own corners with
//! `refine_edges` off; a tag counts when all four corners are within 1.5 px; median and max over the
//! tags matched within 5 px; tests/markers_real.rs prints the table):
//!
//! | detector (settings) | within 1.5 px | median | max | time / image |
//! | --- | --- | --- | --- | --- |
//! | AprilTag 3.4.5, `quad_decimate` 1, `refine_edges` (**default**) | 45/47 | 0.32 px | 3.4 px | 30–80 ms |
//! | AprilTag, `refine_edges` off (the reference's own settings) | 47/47 | 0.00 px | 0.14 px | 30–80 ms |
//! | AprilTag + `cornerSubPix` | 29/47 | 0.62 px | 4.9 px | 30–80 ms |
//! | AprilTag, `quad_decimate` 2 | 33/47 | 0.33 px | 1.8 px | 50 ms |
//! | OpenCV 4.6 aruco + edge fit (OpenCV **default** here), 22 found | 20/47 | 0.29 px | 0.82 px | 20–40 ms |
//! | OpenCV 4.6 aruco, defaults (whole-pixel corners) | 17/47 | 1.03 px | 3.3 px | 20–40 ms |
//! | OpenCV + `cornerSubPix` (window = cell size) | 13/47 | 0.76 px | 3.3 px | 17–40 ms |
//! | OpenCV, `CORNER_REFINE_CONTOUR` | 19/47 | 0.69 px | 1.7 px | 23–50 ms |
//! | OpenCV, `CORNER_REFINE_APRILTAG` (15 found) | 15/47 | 0.71 px | 0.71 px | 70–150 ms |
//! | OpenCV tuned (perimeter rate 0.01, threshold step 4, 8 px per cell; 29 found) + `cornerSubPix` | 15/47 | 0.76 px | 5.9 px | 50–80 ms |
//!
//! (Times vary with the load of a shared 2-core machine; AprilTag's first call on a thread adds ~40 ms
//! for the tag36h11 decode table, kept afterwards.) OpenCV 4.6's `CORNER_REFINE_APRILTAG` returns
//! every corner shifted by exactly (+0.5, +0.5) px: it keeps AprilTag's pixel convention. On synthetic
//! images with known corners (unit tests: 8×8 supersampling, blur σ 0.7 px) AprilTag with
//! `refine_edges` is within 0.015 px at 120 px tags and 0.07 px at 40 px (0.12 / 0.17 px without
//! `refine_edges`, hence the default); OpenCV with the edge fit ([`SubpixMethod::Edges`]) within
//! 0.012 px, with `cornerSubPix` within 0.22–0.24 px. On OpenCV's ChArUco tutorial photos
//! (DICT_6X6_250) OpenCV finds 67 of the 68 markers; the median per-marker PnP residual with the
//! reference intrinsics is 0.084 px with the edge fit, 0.153 px with `cornerSubPix`, 0.162 px without
//! refinement.
//!
//! Each detector keeps its own corner order ([`CornerOrder`]); [`MarkerDetection::canonical_corners`]
//! gives OpenCV's order for either, and [`MarkerDetection::object_corners`] the marker-frame points that
//! match `corners` entry by entry, ready for PnP.
//!
//! # Marker frame (OpenCV's)
//!
//! Origin at the centre of the marker, `x` to the right of the printed marker, `y` up as printed, `z` out
//! of the printed face towards a viewer. "As printed" is the marker as OpenCV's `drawMarker` draws it.
//! **For the AprilTag families OpenCV draws every tag turned by a half turn relative to AprilTag's own
//! images** (`apriltag_to_image`, the official tag PNGs; a unit test checks all four families): for a tag
//! printed from AprilTag's images the marker frame's `x` points to the left of that print and `y` down
//! it, and [`super::aruco::dictionary_bits`] gives its bits turned likewise. Both detectors report this
//! same frame, so poses do not depend on the detector. With `side_m` the edge of the black square (border included), the printed top-left corner is at
//! `(−side_m/2, side_m/2, 0)`.

use super::apriltag::{detect_apriltags, AprilTagConfig};
use super::aruco::{detect_aruco, ArucoConfig};
use super::cv;
use super::image::GreyImage;
use crate::cell::MarkerDictionary;
use crate::error::{Error, Result};
use nalgebra::{Point2, Point3};
use opencv::core::{Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Which detector reads the markers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MarkerDetector {
    /// AprilTag's detector for the AprilTag families, OpenCV's for the ArUco dictionaries (see the module
    /// documentation for the measurement behind this choice).
    Auto,
    /// OpenCV's ArUco detector (any dictionary).
    #[serde(rename = "opencv")]
    OpenCv,
    /// AprilTag 3's own detector (AprilTag families only).
    #[serde(rename = "apriltag")]
    AprilTag,
}

impl MarkerDetector {
    /// The detector that actually runs for `dict`: `Auto` resolved, the others unchanged.
    pub fn resolve(self, dict: MarkerDictionary) -> MarkerDetector {
        match self {
            MarkerDetector::Auto if dict.is_apriltag() => MarkerDetector::AprilTag,
            MarkerDetector::Auto => MarkerDetector::OpenCv,
            d => d,
        }
    }

    /// The corner order of the detector that runs for `dict`.
    pub fn corner_order(self, dict: MarkerDictionary) -> CornerOrder {
        match self.resolve(dict) {
            MarkerDetector::AprilTag => CornerOrder::AprilTag,
            _ => CornerOrder::OpenCv,
        }
    }

    /// The detector's name in results: `opencv` or `apriltag` (`auto` before resolving).
    pub fn name(self) -> &'static str {
        match self {
            MarkerDetector::Auto => "auto",
            MarkerDetector::OpenCv => "opencv",
            MarkerDetector::AprilTag => "apriltag",
        }
    }
}

impl fmt::Display for MarkerDetector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for MarkerDetector {
    type Err = Error;

    /// `auto`, `opencv` (or `aruco`) or `apriltag`, case-insensitively.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(MarkerDetector::Auto),
            "opencv" | "aruco" => Ok(MarkerDetector::OpenCv),
            "apriltag" => Ok(MarkerDetector::AprilTag),
            _ => Err(Error::InvalidInput(format!(
                "unknown marker detector {s:?}: expected auto, opencv or apriltag"
            ))),
        }
    }
}

/// The order in which a detector lists a marker's four corners, named by their place on the printed
/// marker (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CornerOrder {
    /// OpenCV ArUco's: top-left, top-right, bottom-right, bottom-left (clockwise on the screen when the
    /// printed face is seen).
    #[serde(rename = "opencv")]
    OpenCv,
    /// AprilTag's: top-right, top-left, bottom-left, bottom-right of the marker as OpenCV draws it
    /// (counter-clockwise on the screen). AprilTag's own tag images are OpenCV's turned by a half turn
    /// (see the module documentation), so in AprilTag's own terms this is bottom-left, bottom-right,
    /// top-right, top-left.
    #[serde(rename = "apriltag")]
    AprilTag,
}

impl CornerOrder {
    /// For the printed top-left, top-right, bottom-right and bottom-left corner (OpenCV's order), its index
    /// in this order.
    pub fn canonical_indices(self) -> [usize; 4] {
        match self {
            CornerOrder::OpenCv => [0, 1, 2, 3],
            CornerOrder::AprilTag => [1, 0, 3, 2],
        }
    }
}

/// How [`SubpixConfig`] refines corners.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SubpixMethod {
    /// Lines fitted to the four edges of the black square on the image gradient, intersected (see
    /// `vision/edges.rs`).
    Edges,
    /// OpenCV's `cornerSubPix` at each corner, with a window sized to the marker.
    #[serde(rename = "cornersubpix")]
    CornerSubPix,
}

/// Sub-pixel corner refinement after detection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SubpixConfig {
    /// Refine the corners of OpenCV's detector (default true: it gives whole-pixel polygon corners).
    /// OpenCV's own `CORNER_REFINE_*` ([`ArucoConfig::corner_refinement`]) runs before this.
    pub opencv: bool,
    /// Refine the corners of AprilTag's detector as well (default false: its edge refinement is already
    /// sub-pixel).
    pub apriltag: bool,
    /// The refinement (default `edges`).
    pub method: SubpixMethod,
    /// Edge refinement passes, each from the last one's corners (default 2).
    pub edge_passes: u32,
    /// `cornerSubPix`: half side of the search window, pixels (the window is `2·n + 1` pixels wide). Default none:
    /// the marker's cell size (its shortest side over `bits + 2`), between 2 and 11 px, so the window
    /// stays near the corner.
    pub half_window_px: Option<u32>,
    /// `cornerSubPix`: most iterations (default 40).
    pub max_iterations: u32,
    /// `cornerSubPix`: stop when a corner moves less than this, pixels (default 0.001).
    pub epsilon_px: f64,
}

impl Default for SubpixConfig {
    fn default() -> Self {
        SubpixConfig {
            opencv: true,
            apriltag: false,
            method: SubpixMethod::Edges,
            edge_passes: 2,
            half_window_px: None,
            max_iterations: 40,
            epsilon_px: 0.001,
        }
    }
}

/// Marker detection settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MarkerConfig {
    /// The dictionary (family) of the markers (default `tag36h11`).
    pub dictionary: MarkerDictionary,
    /// Which detector reads them (default `auto`).
    pub detector: MarkerDetector,
    /// Sub-pixel refinement after detection.
    pub subpix: SubpixConfig,
    /// Settings of OpenCV's detector.
    pub opencv: ArucoConfig,
    /// Settings of AprilTag's detector.
    pub apriltag: AprilTagConfig,
}

impl MarkerConfig {
    /// Checks the settings of the refinement and of both detectors; the error names the field.
    pub fn validate(&self) -> Result<()> {
        self.subpix.validate()?;
        self.opencv.validate()?;
        self.apriltag.validate()
    }
}

impl Default for MarkerConfig {
    fn default() -> Self {
        MarkerConfig {
            dictionary: MarkerDictionary::AprilTag36h11,
            detector: MarkerDetector::Auto,
            subpix: SubpixConfig::default(),
            opencv: ArucoConfig::default(),
            apriltag: AprilTagConfig::default(),
        }
    }
}

/// One marker found in an image.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerDetection {
    /// The marker id in its dictionary.
    pub id: u32,
    /// The four corners of the black square, pixels (`(0, 0)` = centre of the top-left pixel), in the
    /// detector's order [`Self::order`].
    pub corners: [Point2<f64>; 4],
    /// The order of `corners`.
    pub order: CornerOrder,
    /// The detector that found it: `opencv` or `apriltag`.
    pub detector: &'static str,
    /// The dictionary it was decoded with.
    pub dictionary: MarkerDictionary,
}

impl MarkerDetection {
    /// The corners in OpenCV's ArUco order: top-left, top-right, bottom-right, bottom-left as printed.
    pub fn canonical_corners(&self) -> [Point2<f64>; 4] {
        self.order.canonical_indices().map(|i| self.corners[i])
    }

    /// The marker-frame coordinates (metres, see the module documentation) of each entry of
    /// [`Self::corners`], for a marker whose black square has edge `side_m` metres.
    pub fn object_corners(&self, side_m: f64) -> [Point3<f64>; 4] {
        let h = side_m / 2.0;
        let canonical = [
            Point3::new(-h, h, 0.0),
            Point3::new(h, h, 0.0),
            Point3::new(h, -h, 0.0),
            Point3::new(-h, -h, 0.0),
        ];
        let mut out = [Point3::origin(); 4];
        for (k, &i) in self.order.canonical_indices().iter().enumerate() {
            out[i] = canonical[k];
        }
        out
    }

    /// The centre of the marker: the intersection of its diagonals, pixels.
    pub fn centre(&self) -> Point2<f64> {
        let [a, b, c, d] = self.corners;
        // a + s·(c − a) = b + t·(d − b)
        let (r, q) = (c - a, d - b);
        let den = r.x * q.y - r.y * q.x;
        if den.abs() < 1e-12 {
            return Point2::from((a.coords + b.coords + c.coords + d.coords) / 4.0);
        }
        let s = ((b.x - a.x) * q.y - (b.y - a.y) * q.x) / den;
        a + r * s
    }
}

/// A marker as a detector reports it: id and corners in the detector's order.
type Found = (u32, [Point2<f64>; 4]);

/// Finds every marker of `cfg.dictionary` in `img`, sorted by id (then by centre, top to bottom and left
/// to right, for markers with the same id). Errors on invalid settings or when a detector fails.
pub fn detect_markers(img: &GreyImage, cfg: &MarkerConfig) -> Result<Vec<MarkerDetection>> {
    let dict = cfg.dictionary;
    let detector = cfg.detector.resolve(dict);
    cfg.validate()?;
    let (order, mut found): (CornerOrder, Vec<Found>) = match detector {
        MarkerDetector::AprilTag => {
            if !dict.is_apriltag() {
                return Err(Error::InvalidInput(format!(
                    "the apriltag detector reads the AprilTag families (tag16h5, tag25h9, tag36h10, \
                     tag36h11), not {dict}: use --detector opencv or auto"
                )));
            }
            let hits = detect_apriltags(img, dict, &cfg.apriltag)?;
            (
                detector.corner_order(dict),
                hits.into_iter().map(|h| (h.id, h.corners)).collect(),
            )
        }
        _ => (
            detector.corner_order(dict),
            detect_aruco(img, dict, &cfg.opencv)?,
        ),
    };
    let refine = match detector {
        MarkerDetector::AprilTag => cfg.subpix.apriltag,
        _ => cfg.subpix.opencv,
    };
    if refine {
        refine_corners(img, dict, &mut found, &cfg.subpix)?;
    }
    let mut out: Vec<MarkerDetection> = found
        .into_iter()
        .filter(|(_, c)| c.iter().all(|p| p.x.is_finite() && p.y.is_finite()))
        .map(|(id, corners)| MarkerDetection {
            id,
            corners,
            order,
            detector: detector.name(),
            dictionary: dict,
        })
        .collect();
    out.sort_by(|a, b| {
        let (ca, cb) = (a.centre(), b.centre());
        a.id.cmp(&b.id)
            .then(ca.y.total_cmp(&cb.y))
            .then(ca.x.total_cmp(&cb.x))
    });
    Ok(out)
}

impl SubpixConfig {
    /// Checks the settings; the error names the field (`subpix.…`).
    pub fn validate(&self) -> Result<()> {
        let s = self;
        let bad = |field: &str, msg: &str| {
            Err(Error::Config {
                field: format!("subpix.{field}"),
                msg: msg.into(),
            })
        };
        if s.half_window_px == Some(0) {
            return bad("half_window_px", "must be at least 1");
        }
        if s.edge_passes == 0 {
            return bad("edge_passes", "must be at least 1");
        }
        if s.max_iterations == 0 {
            return bad("max_iterations", "must be at least 1");
        }
        if s.epsilon_px.is_nan() || s.epsilon_px <= 0.0 {
            return bad("epsilon_px", "must be positive");
        }
        Ok(())
    }
}

/// The window half side for a marker: its cell size (shortest side / (bits + 2)), 2 to 11 px.
fn auto_half_window(c: &[Point2<f64>; 4], dict: MarkerDictionary) -> u32 {
    let side = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::MAX, f64::min);
    let cell = side / (dict.bits() + 2) as f64;
    (cell.round() as u32).clamp(2, 11)
}

/// The configured refinement of each marker's corners.
fn refine_corners(
    img: &GreyImage,
    dict: MarkerDictionary,
    found: &mut [Found],
    s: &SubpixConfig,
) -> Result<()> {
    if found.is_empty() {
        return Ok(());
    }
    if s.method == SubpixMethod::Edges {
        for (_, c) in found.iter_mut() {
            // A corner the edges move by more than a cell (or 2 px) is not trusted.
            let cell = auto_half_window(c, dict) as f64;
            super::edges::refine_quad(img, c, dict.bits() + 2, s.edge_passes, cell.max(2.0));
        }
        return Ok(());
    }
    let mat = img.to_mat()?;
    let crit = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        s.max_iterations as i32,
        s.epsilon_px,
    )
    .map_err(|e| cv::error("TermCriteria", e))?;
    for (_, c) in found.iter_mut() {
        let half = s
            .half_window_px
            .unwrap_or_else(|| auto_half_window(c, dict)) as i32;
        let mut pts: Vector<Point2f> = cv::points2f(c);
        opencv::imgproc::corner_sub_pix(
            &mat,
            &mut pts,
            Size::new(half, half),
            Size::new(-1, -1),
            crit,
        )
        .map_err(|e| cv::error("cornerSubPix", e))?;
        let r = cv::from_points2f(&pts);
        // A corner that wandered off by more than a window is not trusted: keep the detector's.
        for (k, q) in r.into_iter().enumerate() {
            if (q - c[k]).norm() <= half as f64 {
                c[k] = q;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::apriltag::apriltag_image;
    use super::super::aruco::dictionary_bits;
    use super::super::pnp::pose_of_points;
    use super::*;
    use crate::camera::Intrinsics;
    use crate::geometry::Rng;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    /// The black square of marker `id` as OpenCV draws it: `(bits + 2)²` cells, `true` = white.
    fn marker_cells(dict: MarkerDictionary, id: u32) -> (usize, Vec<bool>) {
        let n = dict.bits() as usize;
        let inner = dictionary_bits(dict, id).unwrap();
        let m = n + 2;
        let cells = (0..m * m)
            .map(|k| {
                let (r, c) = (k / m, k % m);
                r > 0 && c > 0 && r <= n && c <= n && inner[(r - 1) * n + c - 1]
            })
            .collect();
        (m, cells)
    }

    /// Marker-frame point (metres) of marker-plane position `(u, v)` in cells from the printed top-left
    /// corner (`v` down as printed).
    fn plane_point(u: f64, v: f64, m: usize, side_m: f64) -> Point3<f64> {
        let cell = side_m / m as f64;
        Point3::new(
            (u - m as f64 / 2.0) * cell,
            (m as f64 / 2.0 - v) * cell,
            0.0,
        )
    }

    /// A camera image of the marker at `t_cam_marker` on a white background: 8×8 supersampling of each
    /// pixel's footprint (pixel `(i, j)` covers `[i − ½, i + ½] × [j − ½, j + ½]`), a Gaussian blur of
    /// `sigma` pixels and ±2 grey levels of noise.
    fn render(
        cells: &[bool],
        m: usize,
        side_m: f64,
        intr: &Intrinsics,
        t_cam_marker: &Isometry3<f64>,
        sigma: f64,
    ) -> GreyImage {
        let (w, h) = (intr.width as usize, intr.height as usize);
        // Ray through an image point meets the marker plane z = 0 (marker frame).
        let inv = t_cam_marker.inverse();
        let cell = side_m / m as f64;
        let mut img = vec![0f64; w * h];
        for j in 0..h {
            for i in 0..w {
                let mut acc = 0.0;
                for s in 0..64 {
                    let x = i as f64 - 0.5 + ((s % 8) as f64 + 0.5) / 8.0;
                    let y = j as f64 - 0.5 + ((s / 8) as f64 + 0.5) / 8.0;
                    let d = nalgebra::Vector3::new(
                        (x - intr.ppx) / intr.fx,
                        (y - intr.ppy) / intr.fy,
                        1.0,
                    );
                    let o = inv * Point3::origin();
                    let dir = inv * d;
                    let t = -o.z / dir.z;
                    let p = o + dir * t;
                    let u = p.x / cell + m as f64 / 2.0;
                    let v = m as f64 / 2.0 - p.y / cell;
                    let white = if t > 0.0 && u >= 0.0 && v >= 0.0 && u < m as f64 && v < m as f64 {
                        cells[v as usize * m + u as usize]
                    } else {
                        true
                    };
                    acc += if white { 225.0 } else { 30.0 };
                }
                img[j * w + i] = acc / 64.0;
            }
        }
        let r = (3.0 * sigma).ceil() as i64;
        let k: Vec<f64> = (-r..=r)
            .map(|x| (-(x * x) as f64 / (2.0 * sigma * sigma)).exp())
            .collect();
        let ks: f64 = k.iter().sum();
        let blur = |src: &[f64], horizontal: bool| -> Vec<f64> {
            let mut out = vec![0f64; w * h];
            for j in 0..h as i64 {
                for i in 0..w as i64 {
                    let mut a = 0.0;
                    for (q, kv) in k.iter().enumerate() {
                        let o = q as i64 - r;
                        let (ii, jj) = if horizontal {
                            ((i + o).clamp(0, w as i64 - 1), j)
                        } else {
                            (i, (j + o).clamp(0, h as i64 - 1))
                        };
                        a += kv * src[jj as usize * w + ii as usize];
                    }
                    out[j as usize * w + i as usize] = a / ks;
                }
            }
            out
        };
        let img = blur(&blur(&img, true), false);
        let mut rng = Rng::new(7);
        let data = img
            .iter()
            .map(|v| (v + rng.uniform(-2.0, 2.0)).round().clamp(0.0, 255.0) as u8)
            .collect();
        GreyImage::new(w as u32, h as u32, data).unwrap()
    }

    fn camera() -> Intrinsics {
        Intrinsics::pinhole(480, 400, 600.0, 600.0, 241.3, 198.7)
    }

    fn poses() -> Vec<Isometry3<f64>> {
        vec![
            Isometry3::from_parts(
                Translation3::new(0.01, -0.005, 0.5),
                UnitQuaternion::from_euler_angles(2.8, 0.35, 0.4),
            ),
            Isometry3::from_parts(
                Translation3::new(-0.02, 0.01, 0.6),
                UnitQuaternion::from_euler_angles(-2.7, -0.4, 2.5),
            ),
        ]
    }

    fn project(intr: &Intrinsics, t: &Isometry3<f64>, p: &Point3<f64>) -> Point2<f64> {
        let c = t * p;
        let [u, v] = intr.project([c.x, c.y, c.z]);
        Point2::new(u, v)
    }

    /// Detects the one marker in synthetic views (the marker `scale` times farther than in [`poses`])
    /// and checks its corners against the truth, the corner order through `object_corners` and
    /// `canonical_corners`, and a PnP round trip; returns the worst corner error, pixels.
    fn check_synthetic(
        dict: MarkerDictionary,
        id: u32,
        cfg: &MarkerConfig,
        scale: f64,
        tol_px: f64,
    ) -> f64 {
        let side_m = 0.1;
        let intr = camera();
        let (m, cells) = marker_cells(dict, id);
        let cfg = MarkerConfig {
            dictionary: dict,
            ..cfg.clone()
        };
        let detector = cfg.detector;
        let mut worst_all: f64 = 0.0;
        for (k, pose) in poses().iter().enumerate() {
            let mut pose = *pose;
            pose.translation.vector *= scale;
            let img = render(&cells, m, side_m, &intr, &pose, 0.7);
            let found = detect_markers(&img, &cfg).unwrap();
            assert_eq!(found.len(), 1, "{dict} {detector} view {k}: {found:?}");
            let d = &found[0];
            assert_eq!((d.id, d.dictionary), (id, dict));
            assert_eq!(d.detector, detector.resolve(dict).name());
            // Printed top-left, top-right, bottom-right, bottom-left corners of the black square.
            let truth = [
                (0.0, 0.0),
                (m as f64, 0.0),
                (m as f64, m as f64),
                (0.0, m as f64),
            ]
            .map(|(u, v)| project(&intr, &pose, &plane_point(u, v, m, side_m)));
            let canon = d.canonical_corners();
            let obj = d.object_corners(side_m);
            let mut worst: f64 = 0.0;
            for q in 0..4 {
                worst = worst.max((canon[q] - truth[q]).norm());
                // object_corners matches corners entry by entry.
                worst = worst.max((project(&intr, &pose, &obj[q]) - d.corners[q]).norm());
            }
            println!("{dict} {detector} x{scale} view {k}: worst corner error {worst:.3} px");
            assert!(
                worst < tol_px,
                "{dict} {detector} view {k}: worst corner error {worst:.3} px"
            );
            let est = pose_of_points(&d.corners, &obj, &intr).unwrap();
            let e = pose.inverse() * est.t_cam_board;
            // A single small marker's pose is weak in depth and tilt; this checks the frame, not PnP.
            assert!(
                e.rotation.angle().to_degrees() < scale,
                "{}",
                e.rotation.angle()
            );
            assert!(
                e.translation.vector.norm() < 0.005 * scale * scale,
                "{}",
                e.translation.vector.norm()
            );
            // Deterministic.
            assert_eq!(detect_markers(&img, &cfg).unwrap(), found);
            worst_all = worst_all.max(worst);
        }
        worst_all
    }

    fn with(detector: MarkerDetector) -> MarkerConfig {
        MarkerConfig {
            detector,
            ..MarkerConfig::default()
        }
    }

    #[test]
    fn synthetic_aruco_marker_through_opencv() {
        use MarkerDictionary::{Aruco4x4_50 as A4, Aruco6x6_250 as A6};
        let (auto, ocv) = (with(MarkerDetector::Auto), with(MarkerDetector::OpenCv));
        check_synthetic(A4, 7, &auto, 1.0, 0.05);
        check_synthetic(A6, 123, &ocv, 1.0, 0.05);
        // ~40 px markers.
        check_synthetic(A4, 7, &ocv, 3.0, 0.1);
        check_synthetic(A6, 123, &ocv, 3.0, 0.1);
        // cornerSubPix, the alternative refinement.
        let mut c = with(MarkerDetector::OpenCv);
        c.subpix.method = SubpixMethod::CornerSubPix;
        check_synthetic(A6, 123, &c, 1.0, 0.3);
    }

    #[test]
    fn synthetic_tag36h11_through_both_detectors() {
        use MarkerDictionary::{AprilTag16h5, AprilTag36h10, AprilTag36h11};
        let (auto, april, ocv) = (
            with(MarkerDetector::Auto),
            with(MarkerDetector::AprilTag),
            with(MarkerDetector::OpenCv),
        );
        check_synthetic(AprilTag36h11, 0, &auto, 1.0, 0.05);
        check_synthetic(AprilTag36h11, 42, &april, 1.0, 0.05);
        check_synthetic(AprilTag36h11, 42, &ocv, 1.0, 0.05);
        check_synthetic(AprilTag16h5, 3, &april, 1.0, 0.05);
        check_synthetic(AprilTag36h10, 100, &april, 1.0, 0.05);
        // A marker of ~40 px, as small as the regression images' larger tags.
        check_synthetic(AprilTag36h11, 42, &april, 3.0, 0.15);
        check_synthetic(AprilTag36h11, 42, &ocv, 3.0, 0.15);
    }

    #[test]
    fn opencv_draws_apriltags_turned_by_a_half_turn() {
        for dict in MarkerDictionary::ALL
            .into_iter()
            .filter(|d| d.is_apriltag())
        {
            let n = dict.bits() as usize;
            for id in [0, 1, 17, dict.marker_count() - 1] {
                let (w, im) = apriltag_image(dict, id).unwrap();
                let (w, off) = (w as usize, (w as usize - n) / 2);
                // AprilTag's own image turned by 180°.
                let turned: Vec<bool> = (0..n * n)
                    .map(|k| {
                        let (r, c) = (n - 1 - k / n, n - 1 - k % n);
                        im[(r + off) * w + c + off] > 127
                    })
                    .collect();
                assert_eq!(dictionary_bits(dict, id).unwrap(), turned, "{dict} {id}");
                // The border cells are black in AprilTag's image too.
                assert!(im[(off - 1) * w + off - 1] < 128 && im[(off - 2) * w + off - 2] > 127);
            }
        }
    }

    #[test]
    fn dictionary_bits_sizes_and_errors() {
        for dict in MarkerDictionary::ALL {
            let n = dict.bits() as usize;
            let b = dictionary_bits(dict, 0).unwrap();
            assert_eq!(b.len(), n * n, "{dict}");
            let last = dictionary_bits(dict, dict.marker_count() - 1).unwrap();
            assert_ne!(b, last, "{dict}");
            let e = dictionary_bits(dict, dict.marker_count()).unwrap_err();
            assert!(e.to_string().contains(&dict.to_string()), "{e}");
        }
    }

    #[test]
    fn corner_orders_are_consistent() {
        let c = [
            Point2::new(10.0, 10.0),
            Point2::new(20.0, 10.0),
            Point2::new(20.0, 20.0),
            Point2::new(10.0, 20.0),
        ];
        for order in [CornerOrder::OpenCv, CornerOrder::AprilTag] {
            let idx = order.canonical_indices();
            let mut seen = idx;
            seen.sort();
            assert_eq!(seen, [0, 1, 2, 3]);
            let d = MarkerDetection {
                id: 1,
                corners: c,
                order,
                detector: "test",
                dictionary: MarkerDictionary::AprilTag36h11,
            };
            let obj = d.object_corners(0.2);
            let canon = d.canonical_corners();
            let canon_obj = idx.map(|i| obj[i]);
            assert_eq!(canon_obj[0], Point3::new(-0.1, 0.1, 0.0)); // printed top-left
            assert_eq!(canon_obj[2], Point3::new(0.1, -0.1, 0.0)); // printed bottom-right
            for k in 0..4 {
                assert_eq!(canon[k], c[idx[k]]);
            }
            assert!((d.centre() - Point2::new(15.0, 15.0)).norm() < 1e-12);
        }
    }

    #[test]
    fn bad_settings_are_refused() {
        let img = GreyImage::new(64, 48, vec![200; 64 * 48]).unwrap();
        let cfg = MarkerConfig {
            dictionary: MarkerDictionary::Aruco4x4_50,
            detector: MarkerDetector::AprilTag,
            ..MarkerConfig::default()
        };
        let e = detect_markers(&img, &cfg).unwrap_err().to_string();
        assert!(
            e.contains("AprilTag families") && e.contains("DICT_4X4_50"),
            "{e}"
        );
        let mut cfg = MarkerConfig::default();
        cfg.apriltag.max_hamming = 4;
        assert!(detect_markers(&img, &cfg).is_err());
        let mut cfg = MarkerConfig::default();
        cfg.subpix.half_window_px = Some(0);
        assert!(detect_markers(&img, &cfg).is_err());
        assert!(detect_markers(&img, &MarkerConfig::default())
            .unwrap()
            .is_empty());
        assert_eq!(
            "OpenCV".parse::<MarkerDetector>().unwrap(),
            MarkerDetector::OpenCv
        );
        assert!("sift".parse::<MarkerDetector>().is_err());
        let c: MarkerConfig =
            serde_json::from_str(r#"{"dictionary": "4x4_50", "detector": "opencv"}"#).unwrap();
        assert_eq!(c.dictionary, MarkerDictionary::Aruco4x4_50);
        assert!(serde_json::from_str::<MarkerConfig>(r#"{"dict": "4x4_50"}"#).is_err());
    }
}
