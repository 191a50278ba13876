//! The report of `match`: [`MatchReport`]. Plain data; built from keypoint matches with the cargo feature
//! `vision`.

use serde::Serialize;

/// The schema name and version of [`MatchReport`].
pub const MATCH_SCHEMA: &str = "depthcal.match/1";

/// One keypoint match between the two images.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MatchPair {
    /// The keypoint in IMAGE1 `[x, y]`, pixels (`(0, 0)` = centre of the top-left pixel).
    pub p1_px: [f64; 2],
    /// The keypoint in IMAGE2 `[x, y]`, pixels.
    pub p2_px: [f64; 2],
    /// The descriptor distance (L2 for SIFT, Hamming bits for ORB and AKAZE).
    pub distance: f32,
    /// The homography maps `p1_px` to within the threshold of `p2_px` (false when there is no homography).
    pub inlier: bool,
}

/// Keypoint matches between two images and the homography between them, as `depthcal match --json`
/// prints it.
#[derive(Clone, Debug, Serialize)]
pub struct MatchReport {
    /// [`MATCH_SCHEMA`].
    pub schema: &'static str,
    /// The first image, as given.
    pub image1: String,
    /// The second image, as given.
    pub image2: String,
    /// The keypoint detector: `sift`, `orb` or `akaze`.
    pub detector: &'static str,
    /// Keypoints found in IMAGE1.
    pub keypoints1: usize,
    /// Keypoints found in IMAGE2.
    pub keypoints2: usize,
    /// Matches kept (ratio test, cross-check).
    pub matches: usize,
    /// Of those, inliers of the homography (0 without one).
    pub inliers: usize,
    /// The inlier threshold: transfer error in IMAGE2, pixels.
    pub threshold_px: f64,
    /// The homography mapping IMAGE1 pixels to IMAGE2 pixels, 3 rows of 3, scaled so `h22 = 1`; `null`
    /// when none fits.
    pub homography: Option<[[f64; 3]; 3]>,
    /// The matches, in match order.
    pub pairs: Vec<MatchPair>,
    /// The configuration used: `features` (`FeatureConfig`) and `homography` (`HomographyConfig`).
    pub config: serde_json::Value,
}

#[cfg(feature = "vision")]
impl MatchReport {
    /// The report of matching `f1` (from `image1`) against `f2` (from `image2`): the matches `matches` and
    /// the homography `fit`, found with `cfg` and `hcfg`.
    pub fn new(
        (image1, image2): (&std::path::Path, &std::path::Path),
        (f1, f2): (&crate::vision::Features, &crate::vision::Features),
        matches: &[crate::vision::features::FeatureMatch],
        fit: Option<&crate::vision::features::Homography>,
        cfg: &crate::vision::features::FeatureConfig,
        hcfg: &crate::vision::features::HomographyConfig,
    ) -> crate::Result<Self> {
        let value = |v: Result<serde_json::Value, serde_json::Error>| {
            v.map_err(|e| crate::Error::Failed(format!("serialising the configuration: {e}")))
        };
        let mut config = serde_json::Map::new();
        config.insert("features".into(), value(serde_json::to_value(cfg))?);
        config.insert("homography".into(), value(serde_json::to_value(hcfg))?);
        let pairs: Vec<MatchPair> = matches
            .iter()
            .enumerate()
            .map(|(k, m)| {
                let (a, b) = (f1.keypoints[m.query].pt, f2.keypoints[m.train].pt);
                MatchPair {
                    p1_px: [a.x, a.y],
                    p2_px: [b.x, b.y],
                    distance: m.distance,
                    inlier: fit.is_some_and(|h| h.inliers.get(k).copied().unwrap_or(false)),
                }
            })
            .collect();
        Ok(MatchReport {
            schema: MATCH_SCHEMA,
            image1: image1.display().to_string(),
            image2: image2.display().to_string(),
            detector: cfg.kind.name(),
            keypoints1: f1.len(),
            keypoints2: f2.len(),
            matches: matches.len(),
            inliers: pairs.iter().filter(|p| p.inlier).count(),
            threshold_px: hcfg.threshold_px,
            homography: fit.map(|h| {
                let mut r = [[0.0; 3]; 3];
                for (i, row) in r.iter_mut().enumerate() {
                    for (j, x) in row.iter_mut().enumerate() {
                        *x = h.h[(i, j)];
                    }
                }
                r
            }),
            pairs,
            config: serde_json::Value::Object(config),
        })
    }
}
