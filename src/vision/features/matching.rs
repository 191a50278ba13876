//! Matching the features of two images: nearest neighbours, Lowe's ratio test, then the cross-check.

use super::knn::knn_match;
use super::{FeatureConfig, Features};
use crate::error::Result;
use serde::{Deserialize, Serialize};

/// One match between keypoint `query` of the first image and keypoint `train` of the second.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FeatureMatch {
    /// Index of the keypoint in the first feature set.
    pub query: usize,
    /// Index of the keypoint in the second feature set.
    pub train: usize,
    /// Descriptor distance (Euclidean for SIFT, differing bits for ORB and AKAZE).
    pub distance: f32,
}

/// Matches `a`'s keypoints to `b`'s: each keypoint of `a` takes its nearest descriptor in `b`, kept when
/// it passes Lowe's ratio test (distance below `cfg.ratio` times the second-nearest's; a keypoint with
/// a single candidate passes) and, with `cfg.cross_check`, when it is also the nearest of that keypoint
/// of `b` among `a`'s (ties broken by the lower index).
///
/// Sorted by `query` index (each query appears at most once). Errors when the descriptor kinds or widths
/// differ or the settings are out of range.
pub fn match_features(
    a: &Features,
    b: &Features,
    cfg: &FeatureConfig,
) -> Result<Vec<FeatureMatch>> {
    cfg.validate()?;
    let forward = knn_match(&a.descriptors, &b.descriptors, 2)?;
    let backward = if cfg.cross_check {
        Some(knn_match(&b.descriptors, &a.descriptors, 1)?)
    } else {
        None
    };
    let mut out = Vec::new();
    for (q, nn) in forward.iter().enumerate() {
        let Some(&(t, d)) = nn.first() else {
            continue;
        };
        if let Some(&(_, d2)) = nn.get(1) {
            if d as f64 >= cfg.ratio * d2 as f64 {
                continue;
            }
        }
        if let Some(back) = &backward {
            if back[t].first().map(|&(i, _)| i) != Some(q) {
                continue;
            }
        }
        out.push(FeatureMatch {
            query: q,
            train: t,
            distance: d,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::{Descriptors, FeatureKind, Keypoint};
    use super::*;
    use nalgebra::Point2;

    /// Features with one-value float descriptors `v`.
    fn features(v: &[f32]) -> Features {
        Features {
            keypoints: v
                .iter()
                .map(|&x| Keypoint {
                    pt: Point2::new(x as f64, 0.0),
                    size_px: 1.0,
                    angle_deg: 0.0,
                    response: 1.0,
                })
                .collect(),
            descriptors: Descriptors::from_f32(FeatureKind::Sift, 1, v.to_vec()).unwrap(),
        }
    }

    #[test]
    fn ratio_test_and_cross_check() {
        let a = features(&[0.0, 10.0, 20.0]);
        let b = features(&[1.0, 11.0, 12.0, 50.0]);
        let cfg = FeatureConfig::default();
        // a0 → b0 (1 vs 11: kept), a1 → b1 (1 vs 2: kept at 0.8), a2 → b2 (8 vs 9: ambiguous, dropped).
        let m = match_features(&a, &b, &cfg).unwrap();
        let pairs: Vec<_> = m.iter().map(|x| (x.query, x.train, x.distance)).collect();
        assert_eq!(pairs, vec![(0, 0, 1.0), (1, 1, 1.0)]);
        let loose = FeatureConfig {
            ratio: 1.0,
            ..cfg.clone()
        };
        // At ratio 1 a2 → b2 passes the ratio test but b2's nearest is a1, not a2: the cross-check drops it.
        assert_eq!(match_features(&a, &b, &loose).unwrap().len(), 2);
        let no_cc = FeatureConfig {
            ratio: 1.0,
            cross_check: false,
            ..cfg.clone()
        };
        let m = match_features(&a, &b, &no_cc).unwrap();
        assert_eq!(m.iter().map(|x| x.train).collect::<Vec<_>>(), vec![0, 1, 2]);
        // A single candidate passes the ratio test; the cross-check keeps the nearer query only.
        let a = features(&[0.0, 1.0]);
        let b = features(&[0.9]);
        let m = match_features(&a, &b, &cfg).unwrap();
        assert_eq!(m.iter().map(|x| x.query).collect::<Vec<_>>(), vec![1]);
        let no_cc = FeatureConfig {
            cross_check: false,
            ..cfg.clone()
        };
        assert_eq!(match_features(&a, &b, &no_cc).unwrap().len(), 2);
        assert!(
            match_features(&a, &Features::empty(FeatureKind::Sift), &cfg)
                .unwrap()
                .is_empty()
        );
        assert!(match_features(&a, &Features::empty(FeatureKind::Orb), &cfg).is_err());
    }
}
