//! Robot-to-robot by 2D visual features lifted to 3D with depth.
//!
//! Keypoints of both robots' colour images are lifted to 3D with the aligned depth and brought into each
//! robot's base; matched across the robots (`vision` feature: `depthcal::vision::feature_lift`) they are
//! 3D-3D correspondences base2 → base1, from which RANSAC over minimal samples of three with the
//! closed-form rigid fit (Arun / Umeyama without scale) finds `T_base1_base2`, refitted on all inliers
//! ([`ransac_rigid`]).

use crate::calibration::initializer::{InitialGuess, Initializer, InitializerInput};
use crate::error::{Error, Result};
use crate::geometry::Rng;
use crate::registration::consensus::{consensus_loop, draw_sequential, samples_needed, LoopLimits};
use crate::registration::rigid_fit::rigid_fit;
use nalgebra::{Isometry3, Point3};
use serde::{Deserialize, Serialize};

/// Settings of the RANSAC rigid fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigidRansacConfig {
    /// A correspondence is an inlier when the fitted transform brings its points within this, metres
    /// (default 0.01: depth noise, keypoint localisation and the keypoint's shift with the viewpoint).
    pub inlier_m: f64,
    /// Most minimal samples (default 20000); fewer when the inlier ratio seen so far makes
    /// `confidence` certain.
    pub max_iterations: usize,
    /// Stop when the chance of having missed an all-inlier sample is below `1 − confidence` (default
    /// 0.9999).
    pub confidence: f64,
    /// Fewer inliers than this is a failure (default 8).
    pub min_inliers: usize,
    /// Refit-and-reclassify rounds on the inliers (default 3).
    pub refine_rounds: usize,
}

impl Default for RigidRansacConfig {
    fn default() -> Self {
        RigidRansacConfig {
            inlier_m: 0.01,
            max_iterations: 20000,
            confidence: 0.9999,
            min_inliers: 8,
            refine_rounds: 3,
        }
    }
}

impl RigidRansacConfig {
    /// Checks the ranges; the error names the field (`ransac.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        check::positive("ransac.inlier_m", self.inlier_m)?;
        check::at_least("ransac.max_iterations", self.max_iterations, 1)?;
        check::fraction("ransac.confidence", self.confidence)?;
        check::at_least("ransac.min_inliers", self.min_inliers, 3)
    }
}

/// The result of [`ransac_rigid`].
#[derive(Clone, Debug, PartialEq)]
pub struct RigidRansac {
    /// The transform mapping `src` onto `dst`.
    pub transform: Isometry3<f64>,
    /// Which pairs are inliers of it.
    pub inliers: Vec<bool>,
    /// The inliers' RMS residual, metres.
    pub rms_m: f64,
    /// RMS distance of the inliers' `dst` points from their centroid, metres (the fit's lever arm).
    pub spread_m: f64,
    /// Minimal samples drawn.
    pub iterations: usize,
}

impl RigidRansac {
    /// Number of inliers.
    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|i| **i).count()
    }

    /// 1-σ rotation (degrees) and translation (metres) of the fit from the residuals over `n_eff`
    /// independent pairs: `rms / √n_eff` over the lever arm for the rotation, `√2 · rms / √n_eff` for the
    /// translation.
    pub fn sigmas(&self, n_eff: usize) -> (f64, f64) {
        let n = n_eff.max(1) as f64;
        let se = self.rms_m / n.sqrt();
        let rot = (se / self.spread_m.max(1e-3)).atan();
        (rot.to_degrees(), se * 2f64.sqrt())
    }
}

/// RANSAC over minimal samples of three pairs `src[i] → dst[i]` with the closed-form rigid fit; hypotheses
/// `accept` rejects (the cell's priors) are skipped. The best by inlier count is refitted on its inliers
/// `cfg.refine_rounds` times. Deterministic for a seed. `None` when fewer than `cfg.min_inliers` agree.
pub fn ransac_rigid(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    cfg: &RigidRansacConfig,
    seed: u64,
    accept: &dyn Fn(&Isometry3<f64>) -> bool,
) -> Option<RigidRansac> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let thr2 = cfg.inlier_m * cfg.inlier_m;
    let count = |t: &Isometry3<f64>| {
        src.iter()
            .zip(dst)
            .filter(|(s, d)| (t * *s - *d).norm_squared() <= thr2)
            .count()
    };
    // One minimal sample: three distinct pairs about as far apart in both clouds (no degenerate
    // samples), their rigid fit, accepted by the priors, with its inlier count.
    let hypothesis = |rng: &mut Rng, _it: usize| -> Option<(usize, Isometry3<f64>)> {
        let a = rng.below(n);
        let b = rng.below(n);
        let c = rng.below(n);
        if a == b || b == c || a == c {
            return None;
        }
        let (s, d) = ([src[a], src[b], src[c]], [dst[a], dst[b], dst[c]]);
        let consistent = [(0, 1), (1, 2), (0, 2)].iter().all(|&(i, j)| {
            let (ls, ld) = ((s[i] - s[j]).norm(), (d[i] - d[j]).norm());
            (ls - ld).abs() <= 2.0 * cfg.inlier_m && ls > 2.0 * cfg.inlier_m
        });
        if !consistent {
            return None;
        }
        let t = rigid_fit(&s, &d, None)?;
        if !accept(&t) {
            return None;
        }
        Some((count(&t), t))
    };
    // The registration's RANSAC loop, one sample per batch from one sequential generator; the best is
    // the first with the most inliers, and the confidence rule uses its inlier ratio cubed.
    let mut rng = Rng::new(seed ^ 0xF1A7_0000_0000_0003);
    let mut best: Option<(usize, Isometry3<f64>)> = None;
    let ln_fail = (1.0 - cfg.confidence).ln();
    let limits = LoopLimits {
        max_iterations: cfg.max_iterations,
        min_iterations: 0,
        batch: 1,
    };
    let it = consensus_loop(
        &limits,
        |its| draw_sequential(&mut rng, its, hypothesis),
        |batch| {
            for (k, t) in batch {
                if best.as_ref().is_none_or(|(bk, _)| k > *bk) {
                    best = Some((k, t));
                }
            }
            let (k, _) = best.as_ref()?;
            let w = *k as f64 / n as f64;
            let need = samples_needed(w.powi(3), ln_fail);
            need.is_finite().then_some(need)
        },
    );
    let (k, mut t) = best?;
    if k < cfg.min_inliers.max(3) {
        return None;
    }
    let mut inliers: Vec<bool> = src
        .iter()
        .zip(dst)
        .map(|(s, d)| (t * s - d).norm_squared() <= thr2)
        .collect();
    for _ in 0..cfg.refine_rounds {
        let (s, d): (Vec<Point3<f64>>, Vec<Point3<f64>>) = src
            .iter()
            .zip(dst)
            .zip(&inliers)
            .filter(|(_, &i)| i)
            .map(|((s, d), _)| (*s, *d))
            .unzip();
        let Some(r) = rigid_fit(&s, &d, None) else {
            break;
        };
        let next: Vec<bool> = src
            .iter()
            .zip(dst)
            .map(|(s, d)| (r * s - d).norm_squared() <= thr2)
            .collect();
        if next.iter().filter(|i| **i).count() < cfg.min_inliers.max(3) {
            break;
        }
        t = r;
        let same = next == inliers;
        inliers = next;
        if same {
            break;
        }
    }
    let (mut ss, mut m) = (0.0, 0usize);
    let mut centroid = nalgebra::Vector3::zeros();
    for ((s, d), &i) in src.iter().zip(dst).zip(&inliers) {
        if i {
            ss += (t * s - d).norm_squared();
            centroid += d.coords;
            m += 1;
        }
    }
    centroid /= m.max(1) as f64;
    let spread = (dst
        .iter()
        .zip(&inliers)
        .filter(|(_, &i)| i)
        .map(|(d, _)| (d.coords - centroid).norm_squared())
        .sum::<f64>()
        / m.max(1) as f64)
        .sqrt();
    Some(RigidRansac {
        transform: t,
        inliers,
        rms_m: (ss / m.max(1) as f64).sqrt(),
        spread_m: spread,
        iterations: it,
    })
}

/// Settings of the 2D-feature method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureMethodConfig {
    /// Keypoint detector and descriptor: `sift` (default), `orb` or `akaze`.
    pub detector: String,
    /// Most keypoints per image, strongest first (default 800).
    pub max_per_image: usize,
    /// Lowe's ratio test: the best match's descriptor distance over the best match at another place
    /// (default 0.8).
    pub ratio: f64,
    /// Keep only matches that are also the best the other way (default true).
    pub cross_check: bool,
    /// Keypoints of one robot closer than this in its base are the same place (seen in several frames):
    /// the ratio test and the cross-check compare places, not keypoints, metres (default 0.015).
    pub place_radius_m: f64,
    /// Nearest descriptors looked at per keypoint (default 12).
    pub knn: usize,
    /// A keypoint is lifted only where the depth of its 3x3 neighbourhood is complete and spans less
    /// than this, or 2% of the depth if larger, metres (default 0.01): no missing depth, no depth edges.
    pub max_depth_step_m: f64,
    /// The RANSAC rigid fit.
    pub ransac: RigidRansacConfig,
}

impl Default for FeatureMethodConfig {
    fn default() -> Self {
        FeatureMethodConfig {
            detector: "sift".into(),
            max_per_image: 800,
            ratio: 0.8,
            cross_check: true,
            place_radius_m: 0.015,
            knn: 12,
            max_depth_step_m: 0.01,
            ransac: RigidRansacConfig::default(),
        }
    }
}

impl FeatureMethodConfig {
    /// Checks the ranges; the error names the field (`features.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        if !matches!(
            self.detector.trim().to_ascii_lowercase().as_str(),
            "sift" | "orb" | "akaze"
        ) {
            return Err(Error::config(
                "features.detector",
                format!(
                    "unknown detector {:?} (expected sift, orb or akaze)",
                    self.detector
                ),
            ));
        }
        check::at_least("features.max_per_image", self.max_per_image, 1)?;
        check::fraction("features.ratio", self.ratio)?;
        check::positive("features.place_radius_m", self.place_radius_m)?;
        check::at_least("features.knn", self.knn, 1)?;
        check::positive("features.max_depth_step_m", self.max_depth_step_m)?;
        self.ransac.validate().map_err(|e| e.within("features"))
    }
}

/// One 3D-3D correspondence from a feature match: a point in the other robot's base (base2) and the
/// matched point in the reference robot's base (base1), metres, with the frames they came from.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureCorrespondence {
    /// The point in base2.
    pub other: Point3<f64>,
    /// The point in base1.
    pub reference: Point3<f64>,
    /// The other robot's frame id.
    pub other_frame: String,
    /// The reference robot's frame id.
    pub reference_frame: String,
}

/// `T_base1_base2` from the feature correspondences of both robots' images.
#[derive(Clone, Debug)]
pub struct FeatureInitializer {
    /// The correspondences (matches between the robots' keypoints lifted to 3D).
    pub correspondences: Vec<FeatureCorrespondence>,
    /// RANSAC settings.
    pub ransac: RigidRansacConfig,
    /// A description of how the correspondences were found (detector, keypoints, matches).
    pub summary: String,
}

impl Initializer for FeatureInitializer {
    fn name(&self) -> &str {
        "features"
    }
    fn needs_clouds(&self) -> bool {
        false
    }
    fn initialize(&self, input: &InitializerInput) -> Result<InitialGuess> {
        let src: Vec<Point3<f64>> = self.correspondences.iter().map(|c| c.other).collect();
        let dst: Vec<Point3<f64>> = self.correspondences.iter().map(|c| c.reference).collect();
        let accept =
            |t: &Isometry3<f64>| input.constraint.is_empty() || input.constraint.accepts(t);
        let r = ransac_rigid(&src, &dst, &self.ransac, input.seed, &accept).ok_or_else(|| {
            Error::Failed(format!(
                "features: RANSAC found no rigid transform that {} or more of the {} 3D matches agree on \
                 (within {:.0} mm{}); {}. The robots' images may share too little textured surface",
                self.ransac.min_inliers,
                src.len(),
                self.ransac.inlier_m * 1e3,
                if input.constraint.is_empty() {
                    ""
                } else {
                    ", under the cell's priors"
                },
                self.summary
            ))
        })?;
        // Matches of one place seen in many frames are not independent: count places (1.5 cm cells of
        // the reference points) rather than matches.
        let mut places: Vec<[i64; 3]> = self
            .correspondences
            .iter()
            .zip(&r.inliers)
            .filter(|(_, &i)| i)
            .map(|(c, _)| {
                c.reference
                    .coords
                    .map(|v| (v / 0.015).floor() as i64)
                    .into()
            })
            .collect();
        places.sort_unstable();
        places.dedup();
        let (sr, st) = r.sigmas(places.len());
        let mut pairs: Vec<(&str, &str)> = self
            .correspondences
            .iter()
            .zip(&r.inliers)
            .filter(|(_, &i)| i)
            .map(|(c, _)| (c.other_frame.as_str(), c.reference_frame.as_str()))
            .collect();
        pairs.sort_unstable();
        pairs.dedup();
        Ok(InitialGuess {
            transform: r.transform,
            // Keypoints shift with the viewpoint and the depth under them is noisy: never below 0.05° / 1 mm
            // (simulated cells: errors of 0.4-0.9 mm against 0.15 mm from the residuals alone).
            sigma_rotation_deg: sr.max(0.05),
            sigma_translation_m: st.max(1e-3),
            detail: format!(
                "features: {} of {} 3D matches inliers at {} places (RMS {:.1} mm, {} samples) from {} image pairs; {}",
                r.inlier_count(),
                src.len(),
                places.len(),
                r.rms_m * 1e3,
                r.iterations,
                pairs.len(),
                self.summary
            ),
            ambiguity: None,
            alternatives: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::pose_error;
    use crate::geometry::transform::random_isometry;

    #[test]
    fn ransac_finds_the_transform_among_outliers() {
        let mut rng = Rng::new(4);
        let truth = random_isometry(&mut rng, 3.0, 1.0);
        let mut src = Vec::new();
        let mut dst = Vec::new();
        for k in 0..300 {
            let p = Point3::new(
                rng.uniform(-0.3, 0.3),
                rng.uniform(-0.3, 0.3),
                rng.uniform(0.0, 0.2),
            );
            src.push(p);
            if k % 3 == 0 {
                let q = truth * p;
                dst.push(
                    q + nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.002,
                );
            } else {
                dst.push(Point3::new(
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                ));
            }
        }
        let cfg = RigidRansacConfig::default();
        let r = ransac_rigid(&src, &dst, &cfg, 1, &|_| true).unwrap();
        let (er, et) = pose_error(&r.transform, &truth);
        assert!(er < 0.2 && et < 2e-3, "{er}° / {et} m");
        assert!(
            (95..=105).contains(&r.inlier_count()),
            "{}",
            r.inlier_count()
        );
        assert!(r.rms_m > 0.001 && r.rms_m < 0.006, "{}", r.rms_m);
        let (sr, st) = r.sigmas(r.inlier_count());
        assert!(sr > 0.0 && sr < 0.2 && st > 0.0 && st < 2e-3, "{sr} {st}");
        // Same seed, same result; a prior that rejects everything finds nothing.
        assert_eq!(ransac_rigid(&src, &dst, &cfg, 1, &|_| true).unwrap(), r);
        assert!(ransac_rigid(&src, &dst, &cfg, 1, &|_| false).is_none());
        // Pure noise: no consensus.
        let noise: Vec<Point3<f64>> = (0..300)
            .map(|_| {
                Point3::new(
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                )
            })
            .collect();
        let cfg_strict = RigidRansacConfig {
            min_inliers: 20,
            max_iterations: 3000,
            ..cfg
        };
        assert!(ransac_rigid(&src, &noise, &cfg_strict, 1, &|_| true).is_none());
    }
}
