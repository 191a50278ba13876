//! 2D keypoint features: detection (SIFT, ORB, AKAZE), brute-force descriptor matching, and the
//! homography between two views of a plane.
//!
//! - [`detect`]: keypoints and descriptors of a grey image, optionally inside a mask, in a canonical order.
//! - [`descriptors`]: the opaque [`Descriptors`] (float rows for SIFT, L2; binary rows for ORB and AKAZE,
//!   Hamming), which can be pooled over many images.
//! - [`knn`]: the `k` nearest train rows of every query row, brute force, parallel over query chunks.
//! - [`matching`]: Lowe's ratio test and the cross-check between two images' features.
//! - [`homography`]: RANSAC homography with a refit on the inliers, and the transfer error.
//! - [`draw`]: the side-by-side picture of the matches.
//!
//! Every result depends only on the input, never on the thread count: detection sorts its keypoints,
//! matching is exhaustive with ties broken by index, and RANSAC is seeded.
//! Pixels: `(0, 0)` is the centre of the top-left pixel, `x` to the right, `y` down.

pub mod descriptors;
pub mod detect;
pub mod draw;
pub mod homography;
pub mod knn;
pub mod matching;

pub use descriptors::Descriptors;
pub use detect::{detect_features, detect_features_masked};
pub use draw::draw_matches;
pub use homography::{
    fit_homography, map_point, transfer_error, Homography, HomographyConfig, HomographyMethod,
};
pub use knn::knn_match;
pub use matching::{match_features, FeatureMatch};

use crate::error::{Error, Result};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The keypoint detector and descriptor.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FeatureKind {
    /// SIFT (Lowe 2004; patent-free since 2020, the successor of SURF): 128 float values per keypoint,
    /// compared by Euclidean (L2) distance. Slowest, most repeatable under viewpoint change.
    #[default]
    Sift,
    /// ORB (oriented FAST + rotated BRIEF): 32 bytes per keypoint, Hamming distance. Fastest.
    Orb,
    /// AKAZE (nonlinear scale space, M-LDB): 61 bytes per keypoint, Hamming distance.
    Akaze,
}

impl FeatureKind {
    /// True for binary descriptors (compared by Hamming distance), false for float ones (L2).
    pub fn is_binary(self) -> bool {
        !matches!(self, FeatureKind::Sift)
    }

    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            FeatureKind::Sift => "sift",
            FeatureKind::Orb => "orb",
            FeatureKind::Akaze => "akaze",
        }
    }
}

impl fmt::Display for FeatureKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for FeatureKind {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "sift" => Ok(FeatureKind::Sift),
            "orb" => Ok(FeatureKind::Orb),
            "akaze" => Ok(FeatureKind::Akaze),
            _ => Err(format!(
                "unknown feature detector {s:?} (expected sift, orb or akaze)"
            )),
        }
    }
}

/// Detection and matching settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// The detector and descriptor (default SIFT).
    pub kind: FeatureKind,
    /// Keep at most this many keypoints per image, the strongest by detector response (default 2000;
    /// 0 = no limit).
    pub max_features: usize,
    /// Lowe's ratio test: a match is kept when its distance is below `ratio` times the distance to the
    /// second-nearest descriptor. In (0, 1]; default 0.8.
    pub ratio: f64,
    /// Keep only mutual best matches (the query's best train descriptor has the query as its own best).
    /// Default true.
    pub cross_check: bool,
    /// SIFT contrast threshold (OpenCV `contrastThreshold`, image values scaled to [0, 1]; default 0.04).
    /// Lower finds more keypoints in low-contrast images.
    pub sift_contrast_threshold: f64,
    /// ORB FAST threshold, grey levels (default 20).
    pub orb_fast_threshold: u32,
    /// AKAZE detector response threshold (default 0.001).
    pub akaze_threshold: f64,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig {
            kind: FeatureKind::Sift,
            max_features: 2000,
            ratio: 0.8,
            cross_check: true,
            sift_contrast_threshold: 0.04,
            orb_fast_threshold: 20,
            akaze_threshold: 0.001,
        }
    }
}

impl FeatureConfig {
    /// Checks the ranges of the settings; errors name the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("features.{field}"),
                msg,
            })
        };
        if !(self.ratio > 0.0 && self.ratio <= 1.0) {
            return bad("ratio", format!("must be in (0, 1], found {}", self.ratio));
        }
        if !(self.sift_contrast_threshold.is_finite() && self.sift_contrast_threshold >= 0.0) {
            return bad(
                "sift_contrast_threshold",
                format!("must be ≥ 0, found {}", self.sift_contrast_threshold),
            );
        }
        if !(self.akaze_threshold.is_finite() && self.akaze_threshold > 0.0) {
            return bad(
                "akaze_threshold",
                format!("must be > 0, found {}", self.akaze_threshold),
            );
        }
        if self.orb_fast_threshold == 0 || self.orb_fast_threshold > 254 {
            return bad(
                "orb_fast_threshold",
                format!("must be in 1..=254, found {}", self.orb_fast_threshold),
            );
        }
        if self.max_features > i32::MAX as usize {
            return bad(
                "max_features",
                format!("must be at most {}, found {}", i32::MAX, self.max_features),
            );
        }
        Ok(())
    }
}

/// One detected keypoint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Keypoint {
    /// Position, pixels (`(0, 0)` = centre of the top-left pixel).
    pub pt: Point2<f64>,
    /// Diameter of the described neighbourhood, pixels.
    pub size_px: f64,
    /// Orientation, degrees in [0, 360), clockwise from the image `x` axis (image `y` is down); −1 when the
    /// detector gives none.
    pub angle_deg: f64,
    /// Detector response (strength); larger is stronger. Comparable only within one detector.
    pub response: f64,
}

/// The keypoints of an image (or of several, pooled) with one descriptor row per keypoint.
#[derive(Clone, Debug, PartialEq)]
pub struct Features {
    /// The keypoints; `keypoints[i]` is described by row `i` of `descriptors`.
    pub keypoints: Vec<Keypoint>,
    /// One row per keypoint.
    pub descriptors: Descriptors,
}

impl Features {
    /// No keypoints, with descriptors of `kind` (a start for pooling with [`Features::append`]).
    pub fn empty(kind: FeatureKind) -> Self {
        Features {
            keypoints: Vec::new(),
            descriptors: Descriptors::empty(kind),
        }
    }

    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// True when there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// The detector that produced them.
    pub fn kind(&self) -> FeatureKind {
        self.descriptors.kind()
    }

    /// Appends `other`'s keypoints and descriptors after these (pooling several images: keypoint `i` of
    /// `other` becomes `self.len() + i`). Errors when the descriptor kinds or widths differ.
    pub fn append(&mut self, other: &Features) -> Result<()> {
        self.descriptors.append(&other.descriptors)?;
        self.keypoints.extend_from_slice(&other.keypoints);
        Ok(())
    }

    /// The keypoints at `idx` (in that order) with their descriptors; panics on an index out of range.
    pub fn select(&self, idx: &[usize]) -> Features {
        Features {
            keypoints: idx.iter().map(|&i| self.keypoints[i]).collect(),
            descriptors: self.descriptors.select(idx),
        }
    }

    /// The keypoint positions, pixels.
    pub fn points(&self) -> Vec<Point2<f64>> {
        self.keypoints.iter().map(|k| k.pt).collect()
    }
}

#[cfg(test)]
mod tests;
