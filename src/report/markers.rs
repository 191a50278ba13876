//! The report of `markers`: [`MarkersReport`]. Plain data; built from detections with the cargo feature
//! `vision`.

use crate::cell::MarkerDictionary;
use serde::Serialize;

/// The schema name and version of [`MarkersReport`].
pub const MARKERS_SCHEMA: &str = "depthcal.markers/1";

/// Rounds a pixel coordinate to 1/10000 px for output.
fn round_px(v: f64) -> f64 {
    (v * 1e4).round() / 1e4
}

/// One marker found in an image.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MarkerReport {
    /// The marker id in its dictionary.
    pub id: u32,
    /// The four corners of the black square `[x, y]`, pixels (`(0, 0)` = centre of the top-left pixel,
    /// rounded to 1/10000 px), in the report's `corner_order`.
    pub corners_px: [[f64; 2]; 4],
}

impl MarkerReport {
    /// Marker `id` with its corners `[x, y]` in pixels (rounded here to 1/10000 px).
    pub fn new(id: u32, corners_px: [[f64; 2]; 4]) -> Self {
        MarkerReport {
            id,
            corners_px: corners_px.map(|[x, y]| [round_px(x), round_px(y)]),
        }
    }
}

/// The markers of one image.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MarkerImageReport {
    /// The image file, as given.
    pub path: String,
    /// Its width, pixels.
    pub width: u32,
    /// Its height, pixels.
    pub height: u32,
    /// The markers found, in the detector's order.
    pub markers: Vec<MarkerReport>,
}

/// Square fiducial markers found in images, as `depthcal markers --json` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MarkersReport {
    /// [`MARKERS_SCHEMA`].
    pub schema: &'static str,
    /// The dictionary (family) searched for.
    pub dictionary: MarkerDictionary,
    /// The detector that ran: `opencv` or `apriltag`.
    pub detector: &'static str,
    /// The order of each marker's corners: `opencv` (top-left, top-right, bottom-right, bottom-left as
    /// printed) or `apriltag` (top-right, top-left, bottom-left, bottom-right as OpenCV draws the marker).
    pub corner_order: &'static str,
    /// Per image, in input order.
    pub images: Vec<MarkerImageReport>,
}

#[cfg(feature = "vision")]
impl MarkerImageReport {
    /// The markers `found` in the image `img` read from `path`.
    pub fn new(
        path: &std::path::Path,
        img: &crate::vision::GreyImage,
        found: &[crate::vision::markers::MarkerDetection],
    ) -> Self {
        MarkerImageReport {
            path: path.to_string_lossy().into_owned(),
            width: img.width,
            height: img.height,
            markers: found
                .iter()
                .map(|m| MarkerReport::new(m.id, m.corners.map(|p| [p.x, p.y])))
                .collect(),
        }
    }
}

#[cfg(feature = "vision")]
impl MarkersReport {
    /// The report of the searches `images` with the configuration `cfg`.
    pub fn new(cfg: &crate::vision::markers::MarkerConfig, images: Vec<MarkerImageReport>) -> Self {
        use crate::vision::markers::CornerOrder;
        MarkersReport {
            schema: MARKERS_SCHEMA,
            dictionary: cfg.dictionary,
            detector: cfg.detector.resolve(cfg.dictionary).name(),
            corner_order: match cfg.detector.corner_order(cfg.dictionary) {
                CornerOrder::OpenCv => "opencv",
                CornerOrder::AprilTag => "apriltag",
            },
            images,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_are_rounded_to_a_ten_thousandth_of_a_pixel() {
        let m = MarkerReport::new(
            3,
            [[1.234_56, 2.0], [0.0; 2], [-7.000_04, 9.999_99], [0.0; 2]],
        );
        assert_eq!(m.corners_px[0], [1.2346, 2.0]);
        assert_eq!(m.corners_px[2], [-7.0, 10.0]);
        let v = serde_json::to_value(&m).unwrap();
        assert_eq!(v["corners_px"][0][0], 1.2346);
    }
}
