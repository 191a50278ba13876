//! The `register` pipeline: automatic scale → voxel pyramid → normals → FPFH → matching → RANSAC →
//! verification → coarse-to-fine trimmed robust ICP → quality. Each stage is a function of its own,
//! driven by one [`RegisterRequest`] ([`register_request`]; `register`, `register_with_progress` and
//! `register_with_prior` are thin wrappers), and each is timed.

use super::extent::check_extents;
use crate::error::{Error, Result};
use crate::features::{compute_fpfh, Fpfh, FpfhConfig};
use crate::geometry::cloud::to_v64;
use crate::geometry::PointCloud;
use crate::index::KdIndex;
use crate::preprocess::normals::{
    estimate_covariances, estimate_normals, orient, LazyNormals, NormalConfig, Orientation,
};
use crate::preprocess::scale::{estimate_spacing, voxel_for_target, ScaleConfig};
use crate::preprocess::voxel::voxel_downsample;
use crate::registration::correspondence::{match_features, MatchConfig};
use crate::registration::icp::{
    icp, icp_lazy_normals, IcpCloud, IcpConfig, IcpFactor, IcpIteration, IcpResult,
};
use crate::registration::quality::{
    covariance, covariance_envelope, degeneracy, motion_along, sandwich_covariance, slide_gap,
    Degeneracy, HoldTest,
};
use crate::registration::ransac::{ransac_sided, RansacConfig, RansacResult, SideNormals};
use crate::registration::trust::{assess_registration, Trust, TrustConfig};
use crate::registration::verify::{verify_candidates, HypothesisPrior, VerifyConfig};
use crate::timing::{StageRecord, StageTimer};
use nalgebra::{Isometry3, Matrix6, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

/// Everything `register` can be told. Scale-dependent values are multiples of the voxel size, which is
/// itself chosen from the data unless given.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RegisterConfig {
    /// Voxel size of the global stage (cloud units); `None` chooses it from the data.
    pub voxel: Option<f64>,
    /// How the automatic voxel is chosen.
    pub scale: ScaleConfig,
    /// Normal search radius in voxels (default 2).
    pub normal_radius_voxels: f64,
    /// Normal neighbours at most (default 30).
    pub normal_max_neighbors: usize,
    /// How normals are oriented before FPFH; `None` (the default) orients each normal toward the centroid of
    /// its FPFH neighbourhood ([`Orientation::LocalCentroid`]), which is consistent between partially
    /// overlapping clouds whatever their poses.
    pub orientation: Option<Orientation>,
    /// FPFH radius in voxels (default 5).
    pub fpfh_radius_voxels: f64,
    /// FPFH neighbours at most (default 100).
    pub fpfh_max_neighbors: usize,
    /// Feature matching.
    pub matching: MatchConfig,
    /// RANSAC. The pipeline sets its `inlier_distance` to `ransac_distance_voxels` times the global voxel:
    /// [`RegisterConfig::validate`] refuses another value here (set `ransac_distance_voxels`).
    pub ransac: RansacConfig,
    /// RANSAC inlier distance in voxels (default 1.5).
    pub ransac_distance_voxels: f64,
    /// Verification of RANSAC's best hypotheses by a short ICP and a normal-space-balanced alignment score
    /// ([`crate::registration::verify`]); `None` keeps RANSAC's own choice (most feature inliers).
    pub verify: Option<VerifyConfig>,
    /// ICP. The pipeline sets two of its fields at every level: `max_correspondence_distance` to
    /// `icp_distance_voxels` times the level's voxel, `translation_tolerance` to 1e-3 times the level's
    /// voxel; [`RegisterConfig::validate`] refuses other values here. `sided` is on when either it or
    /// [`RegisterConfig::sided`] is.
    pub icp: IcpConfig,
    /// Number of ICP resolutions: voxel, voxel/2, voxel/4, ... (default 2).
    pub icp_levels: usize,
    /// The finest ICP voxel, in point spacings (default 1.0): a level that would be finer is clamped to
    /// it and is the last one.
    pub icp_min_voxel_spacings: f64,
    /// ICP correspondence distance at the first level, in voxels (default 3); halves with the voxel.
    pub icp_distance_voxels: f64,
    /// Most source points used by one ICP level (default 20 000; a deterministic stride subsample).
    pub icp_max_source_points: usize,
    /// Relative eigenvalue (of the coarsest ICP level's information, rotations scaled by the RMS radius)
    /// below which the geometry leaves a direction free (default 6e-4). Measured: a noisy bare plane's
    /// free directions reach 2e-5 to 2.2e-4; simulated cells' weakest direction (yaw, table-dominated)
    /// 1.9e-3 to 7e-3; 3DMatch, LiDAR 0.19-0.28. Without the hold test the directions below it are
    /// reported as unconstrained; with it, a direction the test does not hold is called unconstrained
    /// only below it, and constrained only weakly above it ([`crate::registration::quality::Degeneracy::free_below`]).
    pub degeneracy_threshold: f64,
    /// The hold test of weak directions. Every direction whose relative strength is below
    /// [`RegisterConfig::degeneracy_test_threshold`] is tested: ICP at the finest level, started this many
    /// finest voxels off the answer along it (its eigenvector: the points at their RMS radius move that far),
    /// once each way, must end within [`RegisterConfig::degeneracy_hold_fraction`] of the step of each other
    /// (a noisy bare plane's free directions closed at most three quarters of the gap between the starts).
    /// A direction that does not is reported (unconstrained, or held only loosely when the ends came within
    /// a quarter step), whatever its eigenvalue; one that does is held, whatever its eigenvalue (default 1, within ICP's capture range of [`RegisterConfig::icp_distance_voxels`]).
    /// 0 turns the test off: then the directions below [`RegisterConfig::degeneracy_threshold`] are
    /// reported. Measured on fused two-robot cells whose floor outweighs their objects (the yaw's relative
    /// strength 5e-5 to 6e-4, as low as a bare plane's): ICP started 1° off in yaw came back to within
    /// 0.002°; a low-overlap cell whose answer lay 13 mm off along its weakest translation (relative
    /// strength 1.4e-3) had its two starts 6 mm off end 19 mm apart.
    pub degeneracy_slide_voxels: f64,
    /// The hold test's bar: a direction is held when its two ICP runs end less than this fraction of the
    /// step apart along it (default 0.065). A noisy bare plane's free directions end 0.54 of the step apart
    /// or more; on the trust sweep's cells, right answers' held directions ended at most 0.046 apart and
    /// trusted answers 0.13-0.25° off 0.094-0.16 apart (their basin is that loose). A direction held more
    /// loosely than the bar makes the result untrusted, with the figures in the reason. How it was chosen
    /// and checked: docs/accuracy.md ("The hold test's bar").
    pub degeneracy_hold_fraction: f64,
    /// Directions weaker than this relative strength go to the hold test (default 0.01: simulated cells'
    /// yaw measures 1.9e-3 to 7e-3 and is tested; 3DMatch and LiDAR pairs' weakest 0.19-0.28 are not).
    pub degeneracy_test_threshold: f64,
    /// Systematic uncertainty added to the covariance: 1-σ translation as a fraction of the finest ICP voxel
    /// (default 0.12), and that over three times the RMS radius of the matched points as rotation (radians).
    pub systematic_voxel_fraction: f64,
    /// The input clouds' normals carry the side each surface was seen from: they point toward the sensors
    /// that saw it (a fused cell cloud's sight directions, see
    /// [`crate::fusion::FusedCloud::sight_directions`]). Every level's normals are then oriented to agree
    /// with them (through downsampling, FPFH and every ICP level), and surfaces seen from opposite sides are
    /// never paired: not in RANSAC's samples, not in verification, not in ICP. A flipped solution (a table
    /// seen from above laid onto one seen from below) is then impossible. Needs normals on both clouds
    /// (default false: normals are estimated and their sign is chosen locally).
    pub sided: bool,
    /// A runner-up hypothesis farther than `ambiguity_min_deg` or `ambiguity_min_voxels` from the best that
    /// scores at least this fraction of the best's verification score makes the result ambiguous (default
    /// 0.9).
    pub ambiguity_ratio: f64,
    /// How far a runner-up must be from the best to count as another answer, degrees (default 2).
    pub ambiguity_min_deg: f64,
    /// The same in translation, global voxels (default 3).
    pub ambiguity_min_voxels: f64,
    /// The quality gate's thresholds ([`crate::registration::trust`]).
    pub trust: TrustConfig,
    /// Random seed of every randomised step (the pipeline's one seed: RANSAC's draws and the verification's
    /// subsampling take it from here).
    pub seed: u64,
}

impl Default for RegisterConfig {
    fn default() -> Self {
        RegisterConfig {
            voxel: None,
            scale: ScaleConfig::default(),
            normal_radius_voxels: 2.0,
            normal_max_neighbors: 30,
            orientation: None,
            fpfh_radius_voxels: 5.0,
            fpfh_max_neighbors: 100,
            matching: MatchConfig::default(),
            ransac: RansacConfig::default(),
            ransac_distance_voxels: 1.5,
            verify: Some(VerifyConfig::default()),
            icp: IcpConfig::default(),
            icp_levels: 2,
            icp_min_voxel_spacings: 1.0,
            icp_distance_voxels: 3.0,
            icp_max_source_points: 20_000,
            degeneracy_threshold: 6e-4,
            degeneracy_slide_voxels: 1.0,
            degeneracy_hold_fraction: 0.065,
            degeneracy_test_threshold: 0.01,
            systematic_voxel_fraction: 0.12,
            sided: false,
            ambiguity_ratio: 0.9,
            ambiguity_min_deg: 2.0,
            ambiguity_min_voxels: 3.0,
            trust: TrustConfig::default(),
            seed: 0,
        }
    }
}

impl RegisterConfig {
    /// The relative strength below which a direction is weak before the hold test: the test's threshold
    /// when it runs ([`RegisterConfig::degeneracy_slide_voxels`] > 0), else
    /// [`RegisterConfig::degeneracy_threshold`].
    pub fn degeneracy_candidate_threshold(&self) -> f64 {
        if self.degeneracy_slide_voxels > 0.0 {
            self.degeneracy_threshold
                .max(self.degeneracy_test_threshold)
        } else {
            self.degeneracy_threshold
        }
    }

    /// Checks the ranges of every field (and of the nested configurations); the error names the field,
    /// e.g. `icp.max_iterations`. The fields the pipeline sets per level (see [`RegisterConfig::ransac`] and
    /// [`RegisterConfig::icp`]) must keep their defaults: a value given for them would be overwritten, so it
    /// is an error naming the setting to use instead. [`register`] calls it first.
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        if let Some(v) = self.voxel.filter(|v| !(*v > 0.0 && v.is_finite())) {
            return Err(Error::config(
                "voxel",
                format!("{v}: the voxel size must be a positive number (cloud units)"),
            ));
        }
        self.scale.validate()?;
        check::positive("normal_radius_voxels", self.normal_radius_voxels)?;
        check::at_least("normal_max_neighbors", self.normal_max_neighbors, 3)?;
        check::positive("fpfh_radius_voxels", self.fpfh_radius_voxels)?;
        check::at_least("fpfh_max_neighbors", self.fpfh_max_neighbors, 1)?;
        self.matching.validate()?;
        self.ransac.validate_shape()?;
        self.pipeline_set_fields_untouched()?;
        check::positive("ransac_distance_voxels", self.ransac_distance_voxels)?;
        if let Some(v) = &self.verify {
            v.validate()?;
        }
        self.icp.validate_shape()?;
        check::at_least("icp_levels", self.icp_levels, 1)?;
        check::positive("icp_min_voxel_spacings", self.icp_min_voxel_spacings)?;
        check::positive("icp_distance_voxels", self.icp_distance_voxels)?;
        check::at_least("icp_max_source_points", self.icp_max_source_points, 1)?;
        check::non_negative("degeneracy_threshold", self.degeneracy_threshold)?;
        check::non_negative("degeneracy_slide_voxels", self.degeneracy_slide_voxels)?;
        check::fraction("degeneracy_hold_fraction", self.degeneracy_hold_fraction)?;
        check::non_negative("degeneracy_test_threshold", self.degeneracy_test_threshold)?;
        check::non_negative("systematic_voxel_fraction", self.systematic_voxel_fraction)?;
        check::fraction("ambiguity_ratio", self.ambiguity_ratio)?;
        check::non_negative("ambiguity_min_deg", self.ambiguity_min_deg)?;
        check::non_negative("ambiguity_min_voxels", self.ambiguity_min_voxels)?;
        self.trust.validate()
    }

    /// The nested fields the pipeline sets from the voxel must not be given: a value there would be
    /// overwritten silently.
    fn pipeline_set_fields_untouched(&self) -> Result<()> {
        let (ransac, icp) = (RansacConfig::default(), IcpConfig::default());
        for (field, given, default, instead) in [
            (
                "ransac.inlier_distance",
                self.ransac.inlier_distance,
                ransac.inlier_distance,
                "ransac_distance_voxels (in voxels)",
            ),
            (
                "icp.max_correspondence_distance",
                self.icp.max_correspondence_distance,
                icp.max_correspondence_distance,
                "icp_distance_voxels (in voxels)",
            ),
            (
                "icp.translation_tolerance",
                self.icp.translation_tolerance,
                icp.translation_tolerance,
                "nothing: it is 1e-3 times each level's voxel",
            ),
        ] {
            if given.to_bits() != default.to_bits() {
                return Err(Error::config(
                    field,
                    format!(
                        "is set by the pipeline from each level's voxel, so {given} would be ignored; set                          {instead} instead"
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// Two answers that the data supports almost equally: the global stage's best hypothesis and a runner-up
/// far from it.
#[derive(Clone, Debug, Serialize)]
pub struct Ambiguity {
    /// The runner-up transform (same convention as the result's), after its verification ICP.
    pub runner_up: Isometry3<f64>,
    /// Its verification score over the best's, 0–1.
    pub score_ratio: f64,
    /// The best's verification score.
    pub best_score: f64,
    /// Rotation between the best and the runner-up, degrees.
    pub rotation_deg: f64,
    /// Translation between them (cloud units).
    pub translation: f64,
}

/// A summary of the global stage.
#[derive(Clone, Debug, Serialize)]
pub struct GlobalSummary {
    /// Feature correspondences.
    pub correspondences: usize,
    /// Correspondences consistent with the chosen hypothesis.
    pub inliers: usize,
    /// RANSAC samples drawn.
    pub iterations: usize,
    /// Fitness of the chosen hypothesis on the downsampled clouds.
    pub fitness: f64,
    /// The transform before ICP.
    pub transform: Isometry3<f64>,
}

/// One level of the coarse-to-fine ICP: its resolution, its clouds' sizes and what each iteration did.
#[derive(Clone, Debug, Serialize)]
pub struct IcpLevelTrace {
    /// The level's voxel (cloud units).
    pub voxel: f64,
    /// The level's correspondence distance (cloud units).
    pub max_correspondence_distance: f64,
    /// Source points used (after the stride subsample of `icp_max_source_points`).
    pub source_points: usize,
    /// Target points.
    pub target_points: usize,
    /// The level met its step tolerances within its budget.
    pub converged: bool,
    /// Wall time preparing the level (downsampling, normals, kd-tree), milliseconds; 0 for the first
    /// level, which reuses the global stage's clouds (`downsample_normals`). A finer point-to-plane level
    /// computes its target normals on first use, during its iterations, for the paired points only.
    pub prepare_ms: f64,
    /// One record per iteration ([`IcpIteration`]).
    pub iterations: Vec<IcpIteration>,
}

/// The result of [`register`].
#[derive(Clone, Debug)]
pub struct Registration {
    /// Maps source points into the target frame.
    pub transform: Isometry3<f64>,
    /// Fraction of (finest-level) source points with a target point within the final correspondence distance.
    pub fitness: f64,
    /// RMS distance of those pairs (cloud units).
    pub inlier_rmse: f64,
    /// Overlap ratio estimated by the trimming.
    pub overlap: f64,
    /// True when the finest ICP level met its termination tolerances (a coarser level that ran out of
    /// iterations only handed the next one its start; each level's own flag is in `icp_levels`).
    pub converged: bool,
    /// ICP iterations over all levels.
    pub iterations: usize,
    /// Information matrix `JᵀWJ` (order ω then v, about the target origin).
    pub information: Matrix6<f64>,
    /// Covariance of `[ω (rad), v (cloud units)]` for a left increment about the target origin: the
    /// envelope of `σ²(JᵀWJ)⁻¹` and the cluster-robust covariance with the re-associated curvature
    /// ([`crate::registration::quality::sandwich_covariance`]), plus the systematic floor of
    /// [`RegisterConfig::systematic_voxel_fraction`].
    pub covariance: Matrix6<f64>,
    /// Degeneracy analysis.
    pub degeneracy: Degeneracy,
    /// The global stage, unless an initial guess was given.
    pub global: Option<GlobalSummary>,
    /// Voxel size of the global stage (cloud units).
    pub voxel: f64,
    /// Median point spacing of source and target (cloud units).
    pub spacing: [f64; 2],
    /// Points in the global-stage clouds (source, target).
    pub global_points: [usize; 2],
    /// Wall time of each stage in milliseconds, in order.
    pub timings_ms: Vec<(String, f64)>,
    /// Things the user should know (dropped points, degeneracy, non-convergence...).
    pub warnings: Vec<String>,
    /// A far-away runner-up of the global stage that scored almost as well, if there was one.
    pub ambiguity: Option<Ambiguity>,
    /// The global stage's distinct hypotheses after verification, best first (the first is the one ICP
    /// started from), each farther than [`RegisterConfig::ambiguity_min_deg`] or
    /// [`RegisterConfig::ambiguity_min_voxels`] from every better one: at most
    /// [`VerifyConfig::refine_top`] of them (RANSAC's choice alone without verification). Empty when ICP
    /// started from a given guess. A caller with more knowledge of the scene (calibrate's free-space test)
    /// may refine and judge several.
    pub hypotheses: Vec<Isometry3<f64>>,
    /// Fraction of the finest level's source points that lie on a target surface after the final
    /// transform: point-to-plane distance below half the finest voxel and normals within 30° (signed when
    /// [`RegisterConfig::sided`]). A match of the same surfaces reaches about the shared fraction; clouds
    /// that merely interpenetrate (two random clouds, unrelated scenes) stay low.
    pub surface_agreement: f64,
    /// The same share with every direction of the source's surfaces weighted alike: the mean over the
    /// normal-direction bins (64, sign-free) that hold at least 1% of the points of each bin's share on a
    /// target surface. A dominant plane (a table laid on a table at any turn) is then one direction among
    /// many, and a hypothesis must also align the objects' faces. Equal to `surface_agreement` without
    /// source normals.
    pub balanced_agreement: f64,
    /// The finest ICP voxel (cloud units).
    pub finest_voxel: f64,
    /// Whether the result can be trusted, and why not ([`crate::registration::trust`]).
    pub trust: Trust,
    /// The transform ICP started from: the global stage's estimate, or the caller's initial guess.
    pub initial: Isometry3<f64>,
    /// The ICP levels, coarse to fine, with each iteration's residuals and inliers.
    pub icp_levels: Vec<IcpLevelTrace>,
    /// Each stage's wall and CPU time and item counts (the same stages as `timings_ms`; `icp` takes in
    /// its nearest-neighbour queries, source points × iterations over the levels).
    pub stages: Vec<StageRecord>,
}

/// A cloud prepared for one resolution: points, normals, index, and GICP covariances when asked for.
struct Level {
    cloud: PointCloud,
    index: KdIndex,
    covariances: Option<Vec<[f32; 6]>>,
}

impl Level {
    fn icp_cloud(&self) -> IcpCloud<'_> {
        IcpCloud {
            points: &self.cloud.points,
            normals: self.cloud.normals.as_deref(),
            covariances: self.covariances.as_deref(),
        }
    }
}

/// Levels ([`prepare_level`]) and point spacings already computed, for registrations of the same clouds
/// to share: `calibrate` refines several hypotheses whose clouds are often the very same points (the
/// other robot's body cut out under each), and the hold test prepares the finest level again. An entry is
/// reused only for a cloud equal bit for bit and the same settings, so results are those of computing it
/// afresh. Safe to share between threads: two registrations that miss at once both compute it (never
/// waiting on each other, which inside rayon could deadlock), the first stored is kept.
#[derive(Default)]
pub struct PreparedLevels {
    levels: Kept<(CloudKey, LevelSettings), Arc<Level>>,
    spacings: Kept<CloudKey, f64>,
}

/// Entries kept at most per kind (oldest dropped first): a pyramid's levels for a few distinct clouds.
const PREPARED_KEPT: usize = 24;

/// A small store of computed values by key, shared between threads.
struct Kept<K, V> {
    entries: std::sync::Mutex<Vec<(K, V)>>,
}

impl<K, V> Default for Kept<K, V> {
    fn default() -> Self {
        Kept {
            entries: std::sync::Mutex::new(Vec::new()),
        }
    }
}

impl<K, V: Clone> Kept<K, V> {
    /// The value of the first entry whose key `hit` accepts; else `compute()`, stored under `key()`
    /// (unless another thread stored one meanwhile, which is then returned).
    fn get_or_compute(
        &self,
        hit: impl Fn(&K) -> bool,
        key: impl FnOnce() -> K,
        compute: impl FnOnce() -> Result<V>,
    ) -> Result<V> {
        let lock = || self.entries.lock().unwrap_or_else(|e| e.into_inner());
        let find = |e: &[(K, V)]| e.iter().find(|(k, _)| hit(k)).map(|(_, v)| v.clone());
        if let Some(v) = find(&lock()) {
            return Ok(v);
        }
        let v = compute()?;
        let mut kept = lock();
        if let Some(held) = find(&kept) {
            return Ok(held);
        }
        if kept.len() >= PREPARED_KEPT {
            kept.remove(0);
        }
        kept.push((key(), v.clone()));
        Ok(v)
    }
}

/// A fingerprint of `c`'s positions and normals (the hash [`PreparedLevels`] files its entries under):
/// equal clouds have equal fingerprints.
pub(crate) fn cloud_fingerprint(c: &PointCloud) -> u64 {
    CloudKey::hash_of(c)
}

/// A stored cloud's positions and normals (copied only when an entry is stored), and their hash.
struct CloudKey {
    hash: u64,
    points: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
}

impl CloudKey {
    /// FNV-1a over the bits of `c`'s positions, then its normals.
    fn hash_of(c: &PointCloud) -> u64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for p in c.points.iter().chain(c.normals.iter().flatten()) {
            for x in p {
                h = (h ^ x.to_bits() as u64).wrapping_mul(0x0100_0000_01b3);
            }
        }
        h
    }

    fn new(hash: u64, c: &PointCloud) -> Self {
        CloudKey {
            hash,
            points: c.points.clone(),
            normals: c.normals.clone(),
        }
    }

    /// Whether this is cloud `c` (of hash `hash`), bit for bit.
    fn holds(&self, hash: u64, c: &PointCloud) -> bool {
        let bits = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (0..3).all(|k| x[k].to_bits() == y[k].to_bits()))
        };
        self.hash == hash
            && bits(&self.points, &c.points)
            && match (&self.normals, &c.normals) {
                (None, None) => true,
                (Some(a), Some(b)) => bits(a, b),
                _ => false,
            }
    }
}

/// What a prepared level depends on besides the cloud: the voxel and the settings [`prepare_level`]
/// reads (lengths as their bits).
#[derive(Clone, Copy, PartialEq)]
struct LevelSettings {
    voxel: u64,
    for_features: bool,
    covariances: bool,
    sided: bool,
    normal_radius_voxels: u64,
    normal_max_neighbors: usize,
    orientation: Option<Orientation>,
    fpfh_radius_voxels: u64,
}

impl PreparedLevels {
    /// An empty store.
    pub fn new() -> Self {
        Self::default()
    }

    /// [`prepare_level`] of `cloud`, from the store when it holds it.
    fn level(
        &self,
        cloud: &PointCloud,
        voxel: f64,
        cfg: &RegisterConfig,
        for_features: bool,
        covariances: bool,
    ) -> Result<Arc<Level>> {
        let settings = LevelSettings {
            voxel: voxel.to_bits(),
            for_features,
            covariances,
            sided: cfg.sided,
            normal_radius_voxels: cfg.normal_radius_voxels.to_bits(),
            normal_max_neighbors: cfg.normal_max_neighbors,
            orientation: cfg.orientation,
            fpfh_radius_voxels: cfg.fpfh_radius_voxels.to_bits(),
        };
        let hash = CloudKey::hash_of(cloud);
        self.levels.get_or_compute(
            |(c, s)| *s == settings && c.holds(hash, cloud),
            || (CloudKey::new(hash, cloud), settings),
            || prepare_level(cloud, voxel, cfg, for_features, covariances).map(Arc::new),
        )
    }

    /// [`estimate_spacing`] of `cloud`, from the store when it holds it.
    fn spacing(&self, cloud: &PointCloud) -> Result<f64> {
        let hash = CloudKey::hash_of(cloud);
        self.spacings.get_or_compute(
            |c| c.holds(hash, cloud),
            || CloudKey::new(hash, cloud),
            || estimate_spacing(&cloud.points),
        )
    }
}

/// [`prepare_level`] through `memo` when given.
fn prepared(
    memo: Option<&PreparedLevels>,
    cloud: &PointCloud,
    voxel: f64,
    cfg: &RegisterConfig,
    for_features: bool,
    covariances: bool,
) -> Result<Arc<Level>> {
    match memo {
        Some(m) => m.level(cloud, voxel, cfg, for_features, covariances),
        None => Ok(Arc::new(prepare_level(
            cloud,
            voxel,
            cfg,
            for_features,
            covariances,
        )?)),
    }
}

/// Downsamples, indexes and estimates normals (and, with `covariances`, GICP covariances); orients the
/// normals only when FPFH will use them (point-to-plane ICP does not care about their sign, and the
/// orientation's neighbourhood search is not free).
fn prepare_level(
    cloud: &PointCloud,
    voxel: f64,
    cfg: &RegisterConfig,
    for_features: bool,
    covariances: bool,
) -> Result<Level> {
    let mut down = voxel_downsample(cloud, voxel)?;
    // Sided clouds: the input normals (averaged per voxel) say which side each surface was seen from.
    let hints = if cfg.sided { down.normals.take() } else { None };
    down.normals = None;
    let index = KdIndex::new(&down.points);
    let ncfg = NormalConfig {
        radius: Some(cfg.normal_radius_voxels * voxel),
        max_neighbors: cfg.normal_max_neighbors,
    };
    let (mut normals, cov) = if covariances {
        let (c, n) = estimate_covariances(&down.points, &index, &ncfg);
        (n, Some(c))
    } else {
        (estimate_normals(&down.points, &index, &ncfg), None)
    };
    if let Some(h) = &hints {
        orient_to_hints(&mut normals, h);
    } else if for_features {
        let orientation = cfg
            .orientation
            .unwrap_or(Orientation::LocalCentroid(cfg.fpfh_radius_voxels * voxel));
        orient(&down.points, &mut normals, orientation);
    }
    down.normals = Some(normals);
    Ok(Level {
        cloud: down,
        index,
        covariances: cov,
    })
}

/// Flips each normal that points away from its hint (a direction toward the sensors that saw the point).
fn orient_to_hints(normals: &mut [[f32; 3]], hints: &[[f32; 3]]) {
    normals.par_iter_mut().zip(hints).for_each(|(n, h)| {
        if n[0] * h[0] + n[1] * h[1] + n[2] * h[2] < 0.0 {
            *n = [-n[0], -n[1], -n[2]];
        }
    });
}

/// Fails on a cloud registration cannot use: fewer than 10 points, or all of them at one place.
fn check_cloud(c: &PointCloud, what: &str) -> Result<()> {
    if c.len() < 10 {
        return Err(Error::InvalidInput(format!(
            "the {what} cloud has {} finite points; registration needs at least 10",
            c.len()
        )));
    }
    if c.extent() <= 0.0 {
        return Err(Error::InvalidInput(format!(
            "all points of the {what} cloud coincide"
        )));
    }
    Ok(())
}

/// One registration problem: what [`register_request`] is given. [`RegisterRequest::new`] sets the
/// defaults (no initial guess, no prior, no progress callback, extents checked).
pub struct RegisterRequest<'a> {
    /// The cloud to move (any unit; the result maps it into the target frame).
    pub source: &'a PointCloud,
    /// The fixed cloud, in the same unit as `source`.
    pub target: &'a PointCloud,
    /// The pipeline's settings.
    pub config: &'a RegisterConfig,
    /// An initial guess of the source-to-target transform (cloud units): the global stage is skipped and
    /// ICP starts from it.
    pub initial: Option<&'a Isometry3<f64>>,
    /// Weighs the global stage's hypotheses: it multiplies RANSAC's inlier count when choosing which
    /// hypotheses to verify, and their verification score.
    pub prior: Option<HypothesisPrior<'a>>,
    /// Called with the name of each stage as it starts.
    pub progress: Option<&'a mut dyn FnMut(&str)>,
    /// Check the clouds' extents first ([`check_extents`]; default true): a voxel at least as large as
    /// a cloud is an error, clouds whose extents differ more than 20x give a warning, a reason when the
    /// result is not trusted and the context of an error.
    pub check_extents: bool,
    /// Prepared levels and spacings to share with other registrations of the same clouds (default none:
    /// each is computed here). Results are the same either way.
    pub prepared: Option<&'a PreparedLevels>,
    /// Add the re-associated part to the covariance ([`crate::registration::icp::reassociated_information`]:
    /// thirteen correspondence searches over the finest level; default true). A caller that uses the
    /// registration only as a starting point (calibrate's depth initialiser) leaves it out; the covariance is
    /// then the fixed pairs' alone, and nothing else changes.
    pub reassociate: bool,
}

impl<'a> RegisterRequest<'a> {
    /// `source` onto `target` under `config`, with the defaults of the other fields.
    pub fn new(source: &'a PointCloud, target: &'a PointCloud, config: &'a RegisterConfig) -> Self {
        RegisterRequest {
            source,
            target,
            config,
            initial: None,
            prior: None,
            progress: None,
            check_extents: true,
            prepared: None,
            reassociate: true,
        }
    }
}

/// Registers `source` onto `target`: returns the transform mapping source points into the target frame.
///
/// With `init`, the global stage is skipped and ICP starts from it. Non-finite points are dropped (and
/// counted in the warnings).
pub fn register(
    source: &PointCloud,
    target: &PointCloud,
    init: Option<&Isometry3<f64>>,
    cfg: &RegisterConfig,
) -> Result<Registration> {
    register_request(RegisterRequest {
        initial: init,
        ..RegisterRequest::new(source, target, cfg)
    })
}

/// As [`register`], calling `progress` with the name of each stage as it starts.
///
/// First checks the clouds' extents ([`check_extents`]): a voxel at least as large as a cloud is an error;
/// clouds whose extents differ more than 20x (millimetres vs metres) give a warning, a reason when the
/// result is not trusted, and the context of an error.
pub fn register_with_progress(
    source: &PointCloud,
    target: &PointCloud,
    init: Option<&Isometry3<f64>>,
    cfg: &RegisterConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Registration> {
    register_request(RegisterRequest {
        initial: init,
        progress: Some(progress),
        ..RegisterRequest::new(source, target, cfg)
    })
}

/// As [`register_with_progress`], with a [`HypothesisPrior`] weighing the global stage's hypotheses: it
/// multiplies RANSAC's inlier count when choosing which hypotheses to verify, and their verification
/// score. The clouds' extents are not checked.
pub fn register_with_prior(
    source: &PointCloud,
    target: &PointCloud,
    init: Option<&Isometry3<f64>>,
    cfg: &RegisterConfig,
    progress: &mut dyn FnMut(&str),
    prior: Option<HypothesisPrior>,
) -> Result<Registration> {
    register_request(RegisterRequest {
        initial: init,
        prior,
        progress: Some(progress),
        check_extents: false,
        ..RegisterRequest::new(source, target, cfg)
    })
}

/// The one entry point of the pipeline: the extents check when asked for (see
/// [`RegisterRequest::check_extents`]), then the stages `clean → scale → downsample_normals → global →
/// verify → icp_pyramid → quality` (see [`Registration::stages`]).
pub fn register_request(mut req: RegisterRequest) -> Result<Registration> {
    let mut silent = |_: &str| {};
    let progress: &mut dyn FnMut(&str) = match req.progress.take() {
        Some(p) => p,
        None => &mut silent,
    };
    if !req.check_extents {
        return run_pipeline(&req, progress);
    }
    let notes = check_extents(req.source, req.target, req.config.voxel)?;
    let context = notes.units.as_ref().or(notes.big_voxel.as_ref());
    let mut reg = run_pipeline(&req, progress).map_err(|e| match context {
        Some(c) => Error::InvalidInput(format!("{c}: {e}")),
        None => e,
    })?;
    if let Some(u) = notes.units {
        if !reg.trust.trusted {
            reg.trust.reasons.push(u.clone());
        }
        reg.warnings.push(u);
    }
    Ok(reg)
}

/// The pipeline, stage by stage (each timed in [`Registration::stages`]):
///
/// 1. [`clean`]: drop non-finite points, check the clouds and the configuration;
/// 2. [`scale`]: point spacings and the global voxel;
/// 3. [`prepare_level`] at the global voxel: downsampling, normals (and GICP covariances);
/// 4. [`global`] (without an initial guess): FPFH, feature matching, RANSAC;
/// 5. [`verify`] (with [`RegisterConfig::verify`]): the best hypotheses refined and rescored;
/// 6. [`icp_pyramid`]: coarse-to-fine trimmed robust ICP;
/// 7. [`quality`]: degeneracy, covariance, then the trust verdict.
fn run_pipeline(req: &RegisterRequest, progress: &mut dyn FnMut(&str)) -> Result<Registration> {
    let (source, target, init, cfg) = (req.source, req.target, req.initial, req.config);
    let (prior, memo) = (req.prior, req.prepared);
    let mut timer = StageTimer::new();
    progress("measuring scale");
    let Cleaned {
        source: src,
        target: tgt,
        mut warnings,
    } = clean(source, target, cfg)?;
    let Scale { spacing, voxel } = scale(&src, &tgt, cfg, memo)?;
    timer.lap_counted("scale", Some(src.len() + tgt.len()), None);

    progress("downsampling, normals");
    let gicp = cfg.icp.factor == IcpFactor::Gicp;
    // From a given start with normals ICP can compute on first use, the first level needs none up front:
    // its target's come as ICP pairs them, its source's for the points it samples (the same normals).
    let (s0, t0) = if init.is_some() && memo.is_none() && lazy_normals_ok(cfg) {
        (bare_level(&src, voxel)?, bare_level(&tgt, voxel)?)
    } else {
        (
            prepared(memo, &src, voxel, cfg, init.is_none(), gicp)?,
            prepared(memo, &tgt, voxel, cfg, init.is_none(), gicp)?,
        )
    };
    timer.lap_counted(
        "downsample_normals",
        Some(src.len() + tgt.len()),
        Some(s0.cloud.len() + t0.cloud.len()),
    );

    progress("features");
    let mut ambiguity = None;
    let mut hypotheses = Vec::new();
    let (initial, global_summary) = match init {
        Some(t) => (*t, None),
        None => {
            let mut g = global(&s0, &t0, voxel, cfg, &mut timer, progress)?;
            if let Some(vcfg) = &cfg.verify {
                progress("verifying hypotheses");
                (ambiguity, hypotheses) =
                    verify(&mut g, &s0, &t0, voxel, prior, cfg, vcfg, &mut timer);
            }
            progress("ICP");
            let summary = summarize_global(&g.ransac);
            if hypotheses.is_empty() {
                hypotheses.push(summary.transform);
            }
            (summary.transform, Some(summary))
        }
    };

    let pyramid = icp_pyramid(
        &src,
        &tgt,
        (&s0, &t0),
        &initial,
        (voxel, spacing),
        cfg,
        memo,
        req.reassociate,
    )?;
    timer.lap_counted(
        "icp",
        Some(
            pyramid
                .traces
                .iter()
                .map(|l| l.source_points * l.iterations.len())
                .sum(),
        ),
        Some(pyramid.finest.pairs),
    );

    progress("checking weak directions");
    let pyramid = Pyramid {
        coarse_degeneracy: confirm_weak_directions(
            pyramid.coarse_degeneracy.clone(),
            &src,
            &tgt,
            &pyramid.transform,
            pyramid.finest_voxel,
            cfg,
            memo,
        )?,
        ..pyramid
    };
    let (degeneracy, covariance) = quality(&pyramid, cfg, &mut warnings);
    timer.lap("quality");
    let mut out = Registration {
        transform: pyramid.transform,
        fitness: pyramid.finest.fitness,
        inlier_rmse: pyramid.finest.inlier_rmse,
        overlap: pyramid.finest.overlap,
        converged: pyramid.converged,
        iterations: pyramid.iterations,
        information: pyramid.finest.information,
        covariance,
        degeneracy,
        global: global_summary,
        voxel,
        spacing,
        global_points: [s0.cloud.len(), t0.cloud.len()],
        timings_ms: timer.wall_ms(),
        stages: timer.into_records(),
        warnings,
        ambiguity,
        hypotheses,
        surface_agreement: pyramid.surface_agreement.plain,
        balanced_agreement: pyramid.surface_agreement.balanced,
        finest_voxel: pyramid.finest_voxel,
        trust: Trust::default(),
        initial,
        icp_levels: pyramid.traces,
    };
    out.trust = assess_registration(&out, &cfg.trust, "");
    Ok(out)
}

/// The clouds as registration uses them: finite points only, and what was dropped.
struct Cleaned {
    source: PointCloud,
    target: PointCloud,
    warnings: Vec<String>,
}

/// Stage 1. Takes the input clouds and the configuration; gives copies without non-finite points (one
/// warning per cloud that lost some). Fails on a cloud of fewer than 10 points or of one place, an
/// invalid configuration, or a sided registration without normals on both clouds.
fn clean(source: &PointCloud, target: &PointCloud, cfg: &RegisterConfig) -> Result<Cleaned> {
    let mut warnings = Vec::new();
    let mut src = source.clone();
    let mut tgt = target.clone();
    for (c, what) in [(&mut src, "source"), (&mut tgt, "target")] {
        let dropped = c.drop_non_finite();
        if dropped > 0 {
            let msg = format!("{dropped} {what} points with NaN/infinite coordinates were dropped");
            log::debug!("{msg}");
            warnings.push(msg);
        }
    }
    check_cloud(&src, "source")?;
    check_cloud(&tgt, "target")?;
    cfg.validate()?;
    if cfg.sided && (src.normals.is_none() || tgt.normals.is_none()) {
        return Err(Error::Config {
            field: "sided".into(),
            msg: "sided registration needs normals on both clouds, pointing toward the sensors"
                .into(),
        });
    }
    Ok(Cleaned {
        source: src,
        target: tgt,
        warnings,
    })
}

/// The clouds' resolution: median point spacings (source, target) and the global voxel, cloud units.
struct Scale {
    spacing: [f64; 2],
    voxel: f64,
}

/// Stage 2. Takes the cleaned clouds; gives their median point spacings and the global voxel (cloud
/// units): [`RegisterConfig::voxel`] when given, else the geometric mean of the voxels that bring each
/// cloud to [`ScaleConfig::target_points`], at least `min_voxel_per_spacing` spacings.
fn scale(
    src: &PointCloud,
    tgt: &PointCloud,
    cfg: &RegisterConfig,
    memo: Option<&PreparedLevels>,
) -> Result<Scale> {
    let spacing_of = |c: &PointCloud| match memo {
        Some(m) => m.spacing(c),
        None => estimate_spacing(&c.points),
    };
    let spacing = [spacing_of(src)?, spacing_of(tgt)?];
    let min_voxel = cfg.scale.min_voxel_per_spacing * spacing[0].max(spacing[1]);
    let voxel = match cfg.voxel {
        Some(v) if v > 0.0 && v.is_finite() => v,
        Some(v) => {
            return Err(Error::Config {
                field: "voxel".into(),
                msg: format!("must be a positive length, got {v}"),
            })
        }
        None => {
            let vs = voxel_for_target(&src.points, cfg.scale.target_points, min_voxel)?;
            let vt = voxel_for_target(&tgt.points, cfg.scale.target_points, min_voxel)?;
            (vs * vt).sqrt()
        }
    };
    log::info!(
        "spacing {:.4} / {:.4}, voxel {voxel:.4}",
        spacing[0],
        spacing[1]
    );
    Ok(Scale { spacing, voxel })
}

/// What the global stage found: RANSAC's result (its transform replaced by the verification's winner)
/// and the RANSAC settings it ran with.
struct GlobalStage {
    ransac: RansacResult,
    config: RansacConfig,
}

/// Stage 4. Takes the global-voxel levels (`voxel`, cloud units; normals oriented for features); gives
/// RANSAC's hypotheses over FPFH correspondences, with its inlier distance
/// [`RegisterConfig::ransac_distance_voxels`] × `voxel`. Laps `fpfh`, `match` and `ransac`.
fn global(
    s0: &Level,
    t0: &Level,
    voxel: f64,
    cfg: &RegisterConfig,
    timer: &mut StageTimer,
    progress: &mut dyn FnMut(&str),
) -> Result<GlobalStage> {
    let fcfg = FpfhConfig {
        radius: cfg.fpfh_radius_voxels * voxel,
        max_neighbors: cfg.fpfh_max_neighbors,
    };
    let sf = level_features(s0, &fcfg);
    let tf = level_features(t0, &fcfg);
    timer.lap_counted(
        "fpfh",
        Some(s0.cloud.len() + t0.cloud.len()),
        Some(sf.len() + tf.len()),
    );
    progress("matching");
    let corr = match_features(&sf, &tf, &cfg.matching);
    timer.lap_counted("match", Some(sf.len() + tf.len()), Some(corr.len()));
    progress("RANSAC");
    let rcfg = RansacConfig {
        inlier_distance: cfg.ransac_distance_voxels * voxel,
        ..cfg.ransac.clone()
    };
    let sides = cfg.sided.then(|| SideNormals {
        source: level_normals(s0),
        target: level_normals(t0),
        // Matched points of one surface agree to far better than 60°; opposite sides are ~180°.
        min_cos: 0.5,
    });
    let r = ransac_sided(
        &s0.cloud.points,
        &t0.cloud.points,
        &t0.index,
        &corr,
        &rcfg,
        cfg.seed,
        sides,
    )?;
    timer.lap_counted("ransac", Some(corr.len()), Some(r.candidates.len()));
    Ok(GlobalStage {
        ransac: r,
        config: rcfg,
    })
}

/// A level's normals (every prepared level has them).
fn level_normals(level: &Level) -> &[[f32; 3]] {
    level.cloud.normals.as_deref().expect("level normals")
}

/// FPFH descriptors of a level's points (one per point).
fn level_features(level: &Level, fcfg: &FpfhConfig) -> Vec<Fpfh> {
    compute_fpfh(
        &level.cloud.points,
        level.cloud.normals.as_ref().unwrap(),
        &level.index,
        fcfg,
    )
}

/// Stage 5. Takes RANSAC's hypotheses on the global-voxel levels; refines and rescores the
/// [`VerifyConfig::max_candidates`] most promising ([`verify_candidates`]), and makes the winner (when it
/// scores above 0) the global stage's transform and inlier count. Gives the ambiguity among the fully
/// refined ones, if any, and the distinct ones that scored above 0 ([`distinct_hypotheses`]). Laps
/// `verify`.
#[allow(clippy::too_many_arguments)]
fn verify(
    g: &mut GlobalStage,
    s0: &Level,
    t0: &Level,
    voxel: f64,
    prior: Option<HypothesisPrior>,
    cfg: &RegisterConfig,
    vcfg: &VerifyConfig,
    timer: &mut StageTimer,
) -> (Option<Ambiguity>, Vec<Isometry3<f64>>) {
    let r = &mut g.ransac;
    let order = candidates_to_verify(r, prior, vcfg.max_candidates);
    let cands: Vec<Isometry3<f64>> = order.iter().map(|&k| r.candidates[k].2).collect();
    let mut v = verify_candidates(
        &s0.cloud.points,
        s0.cloud.normals.as_ref().expect("level normals"),
        &t0.cloud.points,
        t0.cloud.normals.as_ref().expect("level normals"),
        &t0.index,
        &cands,
        voxel,
        &g.config.constraint,
        prior,
        cfg.sided,
        vcfg,
    );
    for c in v.iter_mut() {
        c.candidate = order[c.candidate];
    }
    let refined = &v[..vcfg.refine_top.max(1).min(v.len())];
    let ambiguity = find_ambiguity(refined, voxel, cfg);
    let hypotheses = distinct_hypotheses(refined, voxel, cfg);
    if let Some(best) = v.first().filter(|b| b.score > 0.0) {
        log::info!(
            "verification: candidate {} of {} wins with score {:.3} (RANSAC's choice: {:.3})",
            best.candidate,
            v.len(),
            best.score,
            v.iter().find(|x| x.candidate == 0).map_or(0.0, |x| x.score)
        );
        r.transform = best.transform;
        r.inlier_count = r.candidates[best.candidate].0;
    }
    timer.lap_counted("verify", Some(cands.len()), Some(v.len()));
    (ambiguity, hypotheses)
}

/// The fully verified candidates (best first) that scored above 0, each kept only when it lies farther
/// than [`RegisterConfig::ambiguity_min_deg`] or [`RegisterConfig::ambiguity_min_voxels`] × `voxel` from
/// every one kept before it.
fn distinct_hypotheses(
    verified: &[crate::registration::verify::Verified],
    voxel: f64,
    cfg: &RegisterConfig,
) -> Vec<Isometry3<f64>> {
    let mut kept: Vec<Isometry3<f64>> = Vec::new();
    for v in verified.iter().filter(|v| v.score > 0.0) {
        let far_from_all = kept.iter().all(|k| {
            let (rot_deg, trans) = crate::geometry::transform::pose_error(&v.transform, k);
            rot_deg > cfg.ambiguity_min_deg || trans > cfg.ambiguity_min_voxels * voxel
        });
        if far_from_all {
            kept.push(v.transform);
        }
    }
    kept
}

/// Indices into RANSAC's candidates of the (at most `max`, at least one) to verify: the most feature
/// inliers times the caller's prior, ties by index. The prior (at most 1) is evaluated in order of
/// inliers, and only while a candidate's inliers could still beat the `max`-th score: the same choice
/// as weighing every candidate, with far fewer evaluations of a costly prior.
fn candidates_to_verify(
    r: &RansacResult,
    prior: Option<HypothesisPrior>,
    max: usize,
) -> Vec<usize> {
    let max = max.max(1);
    let count = |k: usize| r.candidates[k].0 as f64;
    let mut by_count: Vec<usize> = (0..r.candidates.len()).collect();
    by_count.sort_by(|&a, &b| count(b).total_cmp(&count(a)).then(a.cmp(&b)));
    let Some(prior) = prior else {
        by_count.truncate(max);
        return by_count;
    };
    let best_first = |x: &(f64, usize), y: &(f64, usize)| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1));
    let mut scored: Vec<(f64, usize)> = Vec::with_capacity(by_count.len());
    let mut next = 0;
    while next < by_count.len() {
        if scored.len() >= max {
            scored.sort_by(best_first);
            // A candidate scores at most its inliers: below the max-th score it cannot enter.
            if count(by_count[next]) < scored[max - 1].0 {
                break;
            }
        }
        let end = (next + if next == 0 { max } else { PRIOR_BATCH }).min(by_count.len());
        scored.par_extend(
            by_count[next..end]
                .par_iter()
                .map(|&k| (count(k) * prior(&r.candidates[k].2), k)),
        );
        next = end;
    }
    scored.sort_by(best_first);
    scored.into_iter().take(max).map(|(_, k)| k).collect()
}

/// Candidates whose prior [`candidates_to_verify`] evaluates at once after the first `max`.
const PRIOR_BATCH: usize = 16;

/// The global stage's summary (logged): its correspondences, inliers, samples, fitness and transform.
fn summarize_global(r: &RansacResult) -> GlobalSummary {
    log::info!(
        "global: {} correspondences, {} inliers, {} samples, fitness {:.3}",
        r.correspondence_count,
        r.inlier_count,
        r.iterations,
        r.fitness
    );
    GlobalSummary {
        correspondences: r.correspondence_count,
        inliers: r.inlier_count,
        iterations: r.iterations,
        fitness: r.fitness,
        transform: r.transform,
    }
}

/// What the coarse-to-fine ICP gives.
struct Pyramid {
    /// The final transform (source to target).
    transform: Isometry3<f64>,
    /// The finest level met its tolerances.
    converged: bool,
    /// Iterations over all levels.
    iterations: usize,
    /// The finest level's ICP result.
    finest: IcpResult,
    /// The finest level's information with re-association
    /// ([`crate::registration::icp::reassociated_information`], a step of one finest voxel).
    reassociated: Option<Matrix6<f64>>,
    /// The finest level's (subsampled) source points.
    finest_source: Vec<[f32; 3]>,
    /// [`surface_agreement`] at the finest level.
    surface_agreement: Agreement,
    /// The finest level's voxel (cloud units).
    finest_voxel: f64,
    /// Degeneracy judged at the coarsest level.
    coarse_degeneracy: Degeneracy,
    /// One trace per level run.
    traces: Vec<IcpLevelTrace>,
}

/// What an ICP level leaves for the pyramid's result: its ICP result, its source points, its surface
/// agreement and (the last level only) its re-associated information.
type LevelOutcome = (IcpResult, Vec<[f32; 3]>, Agreement, Option<Matrix6<f64>>);

/// Stage 6. Takes the cleaned clouds, the global-voxel levels, the starting transform and the global
/// voxel and spacings (cloud units); runs ICP at voxel, voxel/2, ... ([`RegisterConfig::icp_levels`]),
/// the last level clamped to [`RegisterConfig::icp_min_voxel_spacings`] spacings, each level starting
/// from the previous one's transform. Gives the final transform, the finest level's result and every
/// level's trace.
#[allow(clippy::too_many_arguments)]
fn icp_pyramid(
    src: &PointCloud,
    tgt: &PointCloud,
    (s0, t0): (&Level, &Level),
    initial: &Isometry3<f64>,
    (voxel, spacing): (f64, [f64; 2]),
    cfg: &RegisterConfig,
    memo: Option<&PreparedLevels>,
    reassociate: bool,
) -> Result<Pyramid> {
    let finest = cfg.icp_min_voxel_spacings * spacing[0].max(spacing[1]);
    let mut t = *initial;
    let mut converged = false;
    let mut iterations = 0;
    let mut last: Option<LevelOutcome> = None;
    let mut finest_voxel = voxel;
    let mut coarse_degeneracy = None;
    let mut traces = Vec::new();
    let levels = cfg.icp_levels.max(1);
    for level in 0..levels {
        let (v, last_level) = level_voxel(voxel, finest, level, levels);
        let level_start = Instant::now();
        // Finer levels' target normals are computed on first use, for the points ICP pairs.
        let lazy = level > 0 && lazy_normals_ok(cfg);
        let (sl, tl) = if level == 0 {
            (None, None)
        } else {
            let (sl, tl) = icp_level_clouds(src, tgt, v, cfg, lazy, memo)?;
            (Some(sl), Some(tl))
        };
        let slev: &Level = sl.as_deref().unwrap_or(s0);
        let tlev: &Level = tl.as_deref().unwrap_or(t0);
        let ncfg = NormalConfig {
            radius: Some(cfg.normal_radius_voxels * v),
            max_neighbors: cfg.normal_max_neighbors,
        };
        let mut sub = subsample_source(slev, cfg.icp_max_source_points);
        if level == 0 && slev.cloud.normals.is_none() {
            // A first level prepared bare: the sampled points' normals, as the whole level's would be.
            sub.normals = Some(sampled_normals(
                slev,
                cfg.icp_max_source_points,
                ncfg.clone(),
            ));
        }
        let icfg = level_icp_config(cfg, v);
        let lazy = (lazy || (level == 0 && tlev.cloud.normals.is_none()))
            .then(|| LazyNormals::new(&tlev.cloud.points, &tlev.index, ncfg));
        let prep_ms = level_start.elapsed().as_secs_f64() * 1e3;
        let source_cloud = IcpCloud {
            points: &sub.points,
            normals: sub.normals.as_deref(),
            covariances: sub.covariances.as_deref(),
        };
        let r = match &lazy {
            Some(l) => {
                icp_lazy_normals(&source_cloud, &tlev.icp_cloud(), l, &tlev.index, &t, &icfg)?
            }
            None => icp(&source_cloud, &tlev.icp_cloud(), &tlev.index, &t, &icfg)?,
        };
        log::info!(
            "icp level {level} (voxel {v:.4}, {} source / {} target points, prepared in {prep_ms:.1} ms, ran in {:.1} ms): {} iterations, converged {}, fitness {:.3}, overlap {:.3}, rmse {:.5}",
            sub.points.len(),
            tlev.cloud.len(),
            level_start.elapsed().as_secs_f64() * 1e3 - prep_ms,
            r.iterations,
            r.converged,
            r.fitness,
            r.overlap,
            r.inlier_rmse
        );
        if level == 0 {
            coarse_degeneracy = Some(coarse_level_degeneracy(&r, &sub.points, cfg));
        }
        traces.push(IcpLevelTrace {
            voxel: v,
            max_correspondence_distance: icfg.max_correspondence_distance,
            source_points: sub.points.len(),
            target_points: tlev.cloud.len(),
            converged: r.converged,
            prepare_ms: if level == 0 { 0.0 } else { prep_ms },
            iterations: r.history.clone(),
        });
        let reassociated = if last_level && reassociate {
            crate::registration::icp::reassociated_information(
                &source_cloud,
                &tlev.icp_cloud(),
                lazy.as_ref(),
                &tlev.index,
                &r.transform,
                &icfg,
                v,
            )
            .map_err(|e| log::warn!("re-associated information: {e}"))
            .ok()
        } else {
            None
        };
        t = r.transform;
        // What the answer is judged by is the finest level's convergence: a coarser level that runs out
        // of its budget only hands the next one its start (a pose-noise cell's middle level crept for
        // 150 iterations, then the finest level converged in 15).
        converged = r.converged;
        iterations += r.iterations;
        let agreement = surface_agreement(
            &sub.points,
            sub.normals.as_deref(),
            tlev,
            lazy.as_ref(),
            &t,
            0.5 * v,
            cfg.sided,
        );
        last = Some((r, sub.points, agreement, reassociated));
        finest_voxel = v;
        if last_level {
            break;
        }
    }
    let (r, s_sub, agreement, reassociated) = last.expect("at least one ICP level");
    Ok(Pyramid {
        transform: t,
        converged,
        iterations,
        finest: r,
        reassociated,
        finest_source: s_sub,
        surface_agreement: agreement,
        finest_voxel,
        coarse_degeneracy: coarse_degeneracy.expect("level 0 always runs"),
        traces,
    })
}

/// The voxel (cloud units) of ICP level `level` of `levels` from the global `voxel`, and whether it is the
/// last: voxel, voxel/2, ...; the last level is clamped to the finest useful voxel `finest` (the clouds' own
/// resolution), and a level within 1.5x of it goes straight to it (one level fewer, the same result).
fn level_voxel(voxel: f64, finest: f64, level: usize, levels: usize) -> (f64, bool) {
    let v = voxel / (1u64 << level) as f64;
    let near_finest = level > 0 && v < 1.5 * finest;
    let last = level + 1 == levels || near_finest;
    (if near_finest { finest } else { v }, last)
}

/// Prepares into `memo` every level that a refinement of `source` onto `target` from a given start under
/// `cfg` asks for ([`register_request`] with `initial` and `prepared: Some(memo)`: the cleaned clouds'
/// spacings, the global level and each finer ICP level, with their normals and covariances), with the
/// pool's threads on each. Several refinements of the same clouds started side by side then find them
/// all in the memo, where each would otherwise compute the same levels at the same time (the memo never
/// waits on a computation in progress). Changes no result: an entry is what the refinement computes.
/// Not prepared: the finest target in full for the hold test of a refinement whose finer targets get
/// their normals as ICP pairs them (point-to-plane without a normal gate; `calibrate`'s GICP prepares it).
pub fn prepare_refinement(
    source: &PointCloud,
    target: &PointCloud,
    cfg: &RegisterConfig,
    memo: &PreparedLevels,
) -> Result<()> {
    let Cleaned {
        source: src,
        target: tgt,
        ..
    } = clean(source, target, cfg)?;
    let Scale { spacing, voxel } = scale(&src, &tgt, cfg, Some(memo))?;
    let gicp = cfg.icp.factor == IcpFactor::Gicp;
    prepared(Some(memo), &src, voxel, cfg, false, gicp)?;
    prepared(Some(memo), &tgt, voxel, cfg, false, gicp)?;
    let finest = cfg.icp_min_voxel_spacings * spacing[0].max(spacing[1]);
    let levels = cfg.icp_levels.max(1);
    for level in 1..levels {
        let (v, last) = level_voxel(voxel, finest, level, levels);
        icp_level_clouds(&src, &tgt, v, cfg, lazy_normals_ok(cfg), Some(memo))?;
        if last {
            break;
        }
    }
    Ok(())
}

/// The ICP settings of a level of voxel `v` (cloud units): correspondences within
/// [`RegisterConfig::icp_distance_voxels`] voxels, translation tolerance 1e-3 voxel, sided when either
/// setting says so.
fn level_icp_config(cfg: &RegisterConfig, v: f64) -> IcpConfig {
    IcpConfig {
        max_correspondence_distance: cfg.icp_distance_voxels * v,
        translation_tolerance: 1e-3 * v,
        sided: cfg.sided || cfg.icp.sided,
        ..cfg.icp.clone()
    }
}

/// Stage 6b. Takes the coarsest level's degeneracy, the cleaned clouds, the answer and the finest ICP
/// voxel (cloud units); gives the degeneracy with each weak direction that the geometry holds moved to
/// [`Degeneracy::held`]. For each weak direction, ICP at the finest level (where the answer is settled)
/// starts [`RegisterConfig::degeneracy_slide_voxels`] voxels off the answer along it, once each way
/// ([`motion_along`]); the direction is held when the two ends lie less than
/// [`RegisterConfig::degeneracy_hold_fraction`] of the step apart along it ([`slide_gap`]): the geometry
/// pulled both back to one answer. Along an unconstrained direction (a bare plane's in-plane motions, a
/// corridor's length) nothing pulls and the ends stay about two steps apart; along a loosely held one
/// (a yaw pinned by a few distant objects) ICP creeps back and stops short. A run that fails counts as
/// not held. Every tested direction keeps its figures ([`HoldTest`]). Runs only when a direction is weak.
fn confirm_weak_directions(
    deg: Degeneracy,
    src: &PointCloud,
    tgt: &PointCloud,
    answer: &Isometry3<f64>,
    voxel: f64,
    cfg: &RegisterConfig,
    memo: Option<&PreparedLevels>,
) -> Result<Degeneracy> {
    if deg.weak.is_empty() || cfg.degeneracy_slide_voxels <= 0.0 {
        return Ok(deg);
    }
    let (s_level, t0) = icp_level_clouds(src, tgt, voxel, cfg, false, memo)?;
    let sub = subsample_source(&s_level, cfg.icp_max_source_points);
    let icfg = level_icp_config(cfg, voxel);
    let source = IcpCloud {
        points: &sub.points,
        normals: sub.normals.as_deref(),
        covariances: sub.covariances.as_deref(),
    };
    let step = cfg.degeneracy_slide_voxels * voxel;
    let Degeneracy {
        condition,
        weak,
        mut held,
        free_below,
    } = deg;
    let mut free = Vec::new();
    for mut w in weak {
        let delta = step;
        let end = |sign: f64| {
            let start = motion_along(&w, sign * delta) * answer;
            icp(&source, &t0.icp_cloud(), &t0.index, &start, &icfg).map(|r| r.transform)
        };
        let (plus, minus) = rayon::join(|| end(1.0), || end(-1.0));
        let gap = match (plus, minus) {
            (Ok(a), Ok(b)) => slide_gap(&w, &a, &b),
            _ => f64::INFINITY,
        };
        let holds = gap < cfg.degeneracy_hold_fraction * delta;
        w.hold = Some(HoldTest::new(&w, delta, gap));
        log::info!(
            "weak direction {} ({:.2}, {:.2}, {:.2}), relative strength {:.1e}: started ±{delta:.4} off, the ends lie {gap:.5} apart: {}",
            w.kind,
            w.axis[0],
            w.axis[1],
            w.axis[2],
            w.relative_strength,
            if holds { "held" } else { "free" }
        );
        if holds {
            held.push(w);
        } else {
            free.push(w);
        }
    }
    Ok(Degeneracy {
        condition,
        weak: free,
        held,
        free_below,
    })
}

/// The source and target clouds of an ICP level finer than the global one (`voxel`, cloud units). The
/// source gets normals (and covariances) only when ICP uses them: GICP, a normal-angle gate, or sides.
/// With `lazy_normals` the target gets no normals here (ICP computes the ones it needs).
fn icp_level_clouds(
    src: &PointCloud,
    tgt: &PointCloud,
    voxel: f64,
    cfg: &RegisterConfig,
    lazy_normals: bool,
    memo: Option<&PreparedLevels>,
) -> Result<(Arc<Level>, Arc<Level>)> {
    let gicp = cfg.icp.factor == IcpFactor::Gicp;
    let sl = if gicp || cfg.icp.max_normal_angle_deg.is_some() || cfg.sided {
        prepared(memo, src, voxel, cfg, false, gicp)?
    } else {
        let cloud = voxel_downsample(src, voxel)?;
        Arc::new(Level {
            index: KdIndex::new(&[]),
            cloud,
            covariances: None,
        })
    };
    let tl = if lazy_normals {
        bare_level(tgt, voxel)?
    } else {
        prepared(memo, tgt, voxel, cfg, false, gicp)?
    };
    Ok((sl, tl))
}

/// `cloud` downsampled at `voxel` and indexed, without normals (not even the input's averaged ones).
fn bare_level(cloud: &PointCloud, voxel: f64) -> Result<Arc<Level>> {
    let mut cloud = voxel_downsample(cloud, voxel)?;
    cloud.normals = None;
    Ok(Arc::new(Level {
        index: KdIndex::new(&cloud.points),
        cloud,
        covariances: None,
    }))
}

/// Whether the finer ICP levels can compute their target normals on first use: point-to-plane on
/// clouds that are not sided (sided normals take their signs from the input's, averaged per voxel).
fn lazy_normals_ok(cfg: &RegisterConfig) -> bool {
    cfg.icp.factor == IcpFactor::PointToPlane && !cfg.sided && !cfg.icp.sided
}

/// A level's source points (with their normals and covariances, when present) after a deterministic
/// stride subsample to at most about `max_points` (never fewer than 100 kept per stride).
struct SourceSample {
    points: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    covariances: Option<Vec<[f32; 6]>>,
}

/// Takes a level and [`RegisterConfig::icp_max_source_points`]; gives every `step`-th point, normal and
/// covariance, `step = ⌈n / max(max_points, 100)⌉`.
fn subsample_source(level: &Level, max_points: usize) -> SourceSample {
    let s_points = &level.cloud.points;
    let step = sample_step(s_points.len(), max_points);
    SourceSample {
        points: s_points.iter().step_by(step).copied().collect(),
        normals: level
            .cloud
            .normals
            .as_ref()
            .map(|c| c.iter().step_by(step).copied().collect()),
        covariances: level
            .covariances
            .as_ref()
            .map(|c| c.iter().step_by(step).copied().collect()),
    }
}

/// The stride of [`subsample_source`] over `n` points.
fn sample_step(n: usize, max_points: usize) -> usize {
    n.div_ceil(max_points.max(100)).max(1)
}

/// The normals of the points [`subsample_source`] keeps of `level` (which has none), estimated over the
/// whole level's points as [`prepare_level`] estimates them when no features follow (unoriented).
fn sampled_normals(level: &Level, max_points: usize, ncfg: NormalConfig) -> Vec<[f32; 3]> {
    let points = &level.cloud.points;
    let lazy = LazyNormals::new(points, &level.index, ncfg);
    let step = sample_step(points.len(), max_points);
    (0..points.len())
        .into_par_iter()
        .step_by(step)
        .map(|i| lazy.get(i))
        .collect()
}

/// Degeneracy of the coarsest level's information `r.information`, rotations scaled by the RMS radius
/// of its source points `s_sub` mapped by `r.transform` (cloud units).
fn coarse_level_degeneracy(r: &IcpResult, s_sub: &[[f32; 3]], cfg: &RegisterConfig) -> Degeneracy {
    // Degeneracy is judged at the coarsest level: its normals come from wide neighbourhoods, so
    // their noise does not prop up free directions (a bare noisy plane: 2e-5 here against 3e-4
    // at the finest voxel, where simulated cells' weakest direction falls to 2e-3).
    let moved: Vec<Vector3<f64>> = s_sub
        .iter()
        .map(|p| (r.transform * nalgebra::Point3::from(to_v64(p))).coords)
        .collect();
    let (center, length) = centre_and_radius(&moved);
    Degeneracy {
        free_below: cfg.degeneracy_threshold,
        ..degeneracy(
            &r.information,
            &center,
            length,
            cfg.degeneracy_candidate_threshold(),
        )
    }
}

/// Stage 7. Takes the ICP pyramid's result; gives the degeneracy (judged at the coarsest level) and the
/// covariance of `[ω (rad), v (cloud units)]`: the envelope of `σ²(JᵀWJ)⁻¹` of the finest level and its
/// cluster-robust covariance ([`sandwich_covariance`] with the re-associated curvature), plus the
/// systematic floor of [`RegisterConfig::systematic_voxel_fraction`] and, when the finest ICP ended on a
/// cycle, its extent ([`crate::registration::icp::IcpResult::cycle`]). Adds a warning for a degenerate
/// geometry, for ICP that did not converge and for one that ended on a cycle.
fn quality(
    p: &Pyramid,
    cfg: &RegisterConfig,
    warnings: &mut Vec<String>,
) -> (Degeneracy, Matrix6<f64>) {
    let moved: Vec<Vector3<f64>> = p
        .finest_source
        .iter()
        .map(|q| p.transform * nalgebra::Point3::from(to_v64(q)))
        .map(|q| q.coords)
        .collect();
    let (centre, length) = centre_and_radius(&moved);
    let deg = p.coarse_degeneracy.clone();
    if let Some(msg) = degeneracy_warning(&deg) {
        // Carried in the result, which the front ends print; only a debug log here, since calibrate's
        // internal registrations (one frame against a cloud) would otherwise print claims about
        // sub-problems beside a result that has no such weakness.
        log::debug!("{msg}");
        warnings.push(msg);
    }
    if !p.converged {
        warnings
            .push("ICP did not meet its convergence tolerances within the iteration budget".into());
    }
    // Statistical part σ²(JᵀWJ)⁻¹ (independent residuals) plus a systematic floor for what it leaves
    // out: neighbouring residuals are correlated and the surfaces are represented at the finest voxel.
    let r = &p.finest;
    let mut cov = covariance(&r.information, r.residual_sigma * r.residual_sigma);
    // Where residuals are correlated within surface patches, or sliding to other correspondences costs
    // less than the fixed pairs predict, the cluster-robust covariance with the re-associated curvature
    // is the larger: the reported one is at least each of the two.
    if let Some(k) = &p.reassociated {
        let robust = sandwich_covariance(k, &r.block_scores, r.blocks, &centre, length);
        cov = covariance_envelope(&cov, &robust);
    }
    let sys_t = cfg.systematic_voxel_fraction * p.finest_voxel;
    let sys_r = sys_t / (3.0 * length).max(p.finest_voxel);
    for k in 0..3 {
        cov[(k, k)] += sys_r * sys_r;
        cov[(k + 3, k + 3)] += sys_t * sys_t;
    }
    // ICP that ended on a cycle leaves the answer anywhere on it: its largest step is one more 1-σ term.
    if let Some(c) = &r.cycle {
        warnings.push(format!(
            "ICP ended on a cycle of {} poses (its pairs alternate between sets): the answer moves by up to {:.4}° / {:.3e} (cloud units) between them, included in the covariance",
            c.period,
            c.rotation.to_degrees(),
            c.translation
        ));
        for k in 0..3 {
            cov[(k, k)] += c.rotation * c.rotation;
            cov[(k + 3, k + 3)] += c.translation * c.translation;
        }
    }
    (deg, cov)
}

/// The warning a degenerate result carries (`None` when no direction is weak): "unconstrained" only when
/// some direction is free ([`Degeneracy::is_free`]), else "held only weakly".
fn degeneracy_warning(deg: &Degeneracy) -> Option<String> {
    deg.is_degenerate().then(|| {
        let free = deg.weak.iter().any(|w| deg.is_free(w));
        format!(
            "{DEGENERACY_WARNING} {}: {} (the result may slide along it)",
            if free {
                "leaves some motion unconstrained"
            } else {
                "holds some motion only weakly"
            },
            deg.describe()
        )
    })
}

/// How [`degeneracy_warning`] begins.
const DEGENERACY_WARNING: &str = "the geometry";

/// Runs the hold test of stage 6b ([`RegisterConfig::degeneracy_slide_voxels`]) on a registration of
/// `source` onto `target` made with `cfg` but without it (its weak directions judged by their eigenvalues
/// alone), then updates its degeneracy, its warnings and its trust verdict; `cfg`'s
/// [`RegisterConfig::degeneracy_threshold`] says which weak directions the geometry leaves free
/// ([`Degeneracy::free_below`]). For callers that refine many hypotheses and need the test only for the
/// one they keep (`calibrate`), with the levels prepared for that refinement when given (`prepared`).
pub fn recheck_weak_directions(
    reg: &mut Registration,
    mut src: PointCloud,
    mut tgt: PointCloud,
    cfg: &RegisterConfig,
    prepared: Option<&PreparedLevels>,
) -> Result<()> {
    if !reg.degeneracy.is_degenerate() {
        return Ok(());
    }
    src.drop_non_finite();
    tgt.drop_non_finite();
    reg.degeneracy = confirm_weak_directions(
        Degeneracy {
            free_below: cfg.degeneracy_threshold,
            ..reg.degeneracy.clone()
        },
        &src,
        &tgt,
        &reg.transform,
        reg.finest_voxel,
        cfg,
        prepared,
    )?;
    reg.warnings.retain(|w| !w.starts_with(DEGENERACY_WARNING));
    reg.warnings.extend(degeneracy_warning(&reg.degeneracy));
    reg.trust = assess_registration(reg, &cfg.trust, "");
    Ok(())
}

/// The first of the fully verified candidates (best first) that lies far from the best and scores almost
/// as well, as an [`Ambiguity`].
fn find_ambiguity(
    verified: &[crate::registration::verify::Verified],
    voxel: f64,
    cfg: &RegisterConfig,
) -> Option<Ambiguity> {
    let best = verified.first().filter(|b| b.score > 0.0)?;
    verified[1..].iter().find_map(|v| {
        let (rot_deg, trans) =
            crate::geometry::transform::pose_error(&v.transform, &best.transform);
        let far = rot_deg > cfg.ambiguity_min_deg || trans > cfg.ambiguity_min_voxels * voxel;
        let ratio = v.score / best.score;
        (far && ratio >= cfg.ambiguity_ratio).then_some(Ambiguity {
            runner_up: v.transform,
            score_ratio: ratio,
            best_score: best.score,
            rotation_deg: rot_deg,
            translation: trans,
        })
    })
}

/// The share of source points on a target surface: of all, and per normal direction ([`surface_agreement`]).
#[derive(Clone, Copy, Debug)]
struct Agreement {
    /// [`Registration::surface_agreement`].
    plain: f64,
    /// [`Registration::balanced_agreement`].
    balanced: f64,
}

/// Fraction of `source` points (mapped by `t`) whose nearest target point has a point-to-plane distance
/// below `tau` and a normal within 30° of theirs (signed when `sided`); without source normals only the
/// distance counts. The target's normals are its cloud's, else `lazy`'s. Also the mean of that fraction
/// over the source normals' direction bins that hold at least 1% of the points (the plain fraction
/// without source normals). NaN for both without target normals.
fn surface_agreement(
    source: &[[f32; 3]],
    source_normals: Option<&[[f32; 3]]>,
    target: &Level,
    lazy: Option<&LazyNormals>,
    t: &Isometry3<f64>,
    tau: f64,
    sided: bool,
) -> Agreement {
    let normal_of = |j: usize| match (target.cloud.normals.as_deref(), lazy) {
        (Some(n), _) => n[j],
        (None, Some(l)) => l.get(j),
        (None, None) => unreachable!("checked below"),
    };
    if target.cloud.normals.is_none() && lazy.is_none() {
        return Agreement {
            plain: f64::NAN,
            balanced: f64::NAN,
        };
    }
    if source.is_empty() {
        return Agreement {
            plain: 0.0,
            balanced: 0.0,
        };
    }
    let cos_max = 30f64.to_radians().cos();
    let reach2 = (4.0 * tau * tau) as f32;
    let hit: Vec<bool> = source
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let pw = crate::geometry::cloud::transform_point(t, p);
            let Some((j, _)) = target.index.nearest_within(&pw, reach2) else {
                return false;
            };
            let nt = to_v64(&normal_of(j));
            if let Some(sn) = source_normals {
                let c = (t.rotation * to_v64(&sn[i])).dot(&nt);
                if (if sided { c } else { c.abs() }) < cos_max {
                    return false;
                }
            }
            nt.dot(&(to_v64(&pw) - to_v64(&target.cloud.points[j])))
                .abs()
                < tau
        })
        .collect();
    let plain = hit.iter().filter(|&&h| h).count() as f64 / source.len() as f64;
    let Some(normals) = source_normals.filter(|n| n.len() == source.len()) else {
        return Agreement {
            plain,
            balanced: plain,
        };
    };
    let mut bins = [(0usize, 0usize); 64];
    for (n, &h) in normals.iter().zip(&hit) {
        let b = &mut bins[crate::registration::verify::normal_bin(n) as usize];
        b.0 += 1;
        b.1 += h as usize;
    }
    let min = (source.len() / 100).max(1);
    let shares: Vec<f64> = bins
        .iter()
        .filter(|b| b.0 >= min)
        .map(|b| b.1 as f64 / b.0 as f64)
        .collect();
    let balanced = if shares.is_empty() {
        plain
    } else {
        shares.iter().sum::<f64>() / shares.len() as f64
    };
    Agreement { plain, balanced }
}

/// Centroid of `points` and their RMS distance from it (metres).
fn centre_and_radius(points: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    let n = points.len().max(1) as f64;
    let center = points.iter().sum::<Vector3<f64>>() / n;
    let radius = (points
        .iter()
        .map(|p| (p - center).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt();
    (center, radius)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// The pruned choice equals weighing every candidate (ties included), and skips most prior
    /// evaluations when the prior is mild.
    #[test]
    fn candidates_to_verify_is_the_full_weighing() {
        let mut s = 11u64;
        let mut r = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s >> 33
        };
        for (n, levels) in [(0, 5), (1, 5), (7, 3), (300, 40), (300, 400)] {
            let candidates: Vec<(usize, f64, Isometry3<f64>)> = (0..n)
                .map(|k| {
                    let t = Isometry3::translation(k as f64, 0.0, 0.0);
                    ((r() % levels) as usize, 0.0, t)
                })
                .collect();
            let result = RansacResult {
                transform: Isometry3::identity(),
                inlier_count: 0,
                correspondence_count: 0,
                iterations: 0,
                fitness: 0.0,
                verified: n,
                candidates,
            };
            // A prior of the candidate's index: 1 for most, lower or 0 for some, repeated values (ties).
            let weight = |t: &Isometry3<f64>| -> f64 {
                match t.translation.x as usize % 7 {
                    0 => 0.0,
                    1 => 0.5,
                    2 => 0.9,
                    _ => 1.0,
                }
            };
            let calls = AtomicUsize::new(0);
            let prior = |t: &Isometry3<f64>| {
                calls.fetch_add(1, Ordering::Relaxed);
                weight(t)
            };
            for max in [1, 5, 50, 1000] {
                calls.store(0, Ordering::Relaxed);
                let got = candidates_to_verify(&result, Some(&prior), max);
                let mut oracle: Vec<usize> = (0..n).collect();
                let score =
                    |k: usize| result.candidates[k].0 as f64 * weight(&result.candidates[k].2);
                oracle.sort_by(|&a, &b| score(b).total_cmp(&score(a)).then(a.cmp(&b)));
                oracle.truncate(max.max(1));
                assert_eq!(got, oracle, "n {n}, levels {levels}, max {max}");
                if n == 300 && levels == 400 && max == 5 {
                    let c = calls.load(Ordering::Relaxed);
                    assert!(c < 100, "{c} prior evaluations");
                }
                // Without a prior: by inliers, ties by index.
                let plain = candidates_to_verify(&result, None, max);
                let mut by_count: Vec<usize> = (0..n).collect();
                by_count.sort_by(|&a, &b| {
                    result.candidates[b]
                        .0
                        .cmp(&result.candidates[a].0)
                        .then(a.cmp(&b))
                });
                by_count.truncate(max.max(1));
                assert_eq!(plain, by_count);
            }
        }
    }

    /// A floor sampled every 2 cm, 2 m square, plus (with `boxes`) three boxes standing on it, with a little
    /// noise.
    fn floor_scene(boxes: bool, seed: u64) -> PointCloud {
        let mut rng = crate::geometry::Rng::new(seed);
        let mut pts = Vec::new();
        let mut push = |p: [f64; 3], rng: &mut crate::geometry::Rng| {
            pts.push([
                (p[0] + 0.0005 * rng.normal()) as f32,
                (p[1] + 0.0005 * rng.normal()) as f32,
                (p[2] + 0.0005 * rng.normal()) as f32,
            ]);
        };
        for i in 0..100 {
            for j in 0..100 {
                push([i as f64 * 0.02, j as f64 * 0.02, 0.0], &mut rng);
            }
        }
        if boxes {
            // Boxes 20 cm wide, 30 cm tall, at different yaw: their sides hold the yaw.
            for (cx, cy, yaw) in [(0.5, 0.5, 0.0f64), (1.4, 0.7, 0.5), (0.9, 1.5, 1.0)] {
                let (c, s) = (yaw.cos(), yaw.sin());
                for k in 0..15 {
                    for m in 0..10 {
                        let (a, z) = (m as f64 * 0.02 - 0.1, k as f64 * 0.02);
                        for (u, v) in [(a, -0.1), (a, 0.1), (-0.1, a), (0.1, a)] {
                            push([cx + c * u - s * v, cy + s * u + c * v, z], &mut rng);
                        }
                    }
                }
            }
        }
        PointCloud::from_points(pts)
    }

    /// The hold test's bar is a fraction of its step: 0 and above 1 are refused, naming the setting.
    #[test]
    fn the_hold_fraction_is_checked() {
        for bad in [0.0, -0.1, 1.5, f64::NAN] {
            let cfg = RegisterConfig {
                degeneracy_hold_fraction: bad,
                ..RegisterConfig::default()
            };
            let e = cfg.validate().unwrap_err().to_string();
            assert!(e.contains("degeneracy_hold_fraction"), "{e}");
        }
        let cfg = RegisterConfig {
            degeneracy_hold_fraction: 0.05,
            ..RegisterConfig::default()
        };
        cfg.validate().unwrap();
    }

    /// Registrations that share prepared levels give, bit for bit, what each gives alone (GICP, so the
    /// covariances are shared too, and with the hold test, which prepares the finest level again); the
    /// second of two equal registrations prepares nothing, and a cloud one point away from a stored one
    /// is not served its levels.
    #[test]
    fn shared_prepared_levels_change_nothing() {
        let truth = Isometry3::new(Vector3::new(0.03, -0.02, 0.01), Vector3::z() * 0.02);
        let start = Isometry3::new(Vector3::new(0.035, -0.015, 0.01), Vector3::z() * 0.025);
        let cfg = RegisterConfig {
            icp: IcpConfig {
                factor: IcpFactor::Gicp,
                ..IcpConfig::default()
            },
            sided: false,
            degeneracy_test_threshold: 0.5,
            ..RegisterConfig::default()
        };
        let target = floor_scene(true, 1);
        let source = floor_scene(true, 2).transformed(&truth.inverse());
        let mut moved = source.clone();
        moved.points[17][2] += 1e-3;
        let bits = |r: &Registration| r.transform.to_homogeneous().map(|x| x.to_bits());
        let shared = PreparedLevels::new();
        let with = |s: &PointCloud| {
            register_request(RegisterRequest {
                initial: Some(&start),
                prepared: Some(&shared),
                ..RegisterRequest::new(s, &target, &cfg)
            })
            .unwrap()
        };
        let entries = || shared.levels.entries.lock().unwrap().len();
        let alone = register(&source, &target, Some(&start), &cfg).unwrap();
        let first = with(&source);
        let kept = entries();
        assert!(kept >= 4, "{kept} levels kept");
        let second = with(&source);
        assert_eq!(entries(), kept, "the second run prepared a level");
        assert_eq!(bits(&first), bits(&alone));
        assert_eq!(bits(&second), bits(&alone));
        assert_eq!(first.degeneracy.held.len(), alone.degeneracy.held.len());
        assert_eq!(first.covariance, alone.covariance);
        let other = with(&moved);
        assert!(entries() > kept, "the moved cloud was served stored levels");
        let other_alone = register(&moved, &target, Some(&start), &cfg).unwrap();
        assert_eq!(bits(&other), bits(&other_alone));
    }

    /// [`prepare_refinement`] prepares every level a refinement from a given start asks for: the refinement
    /// that follows prepares nothing more, and gives, bit for bit, what it gives alone. For GICP (levels
    /// with covariances, the hold test on) and point-to-plane (finer targets' normals computed as ICP pairs
    /// them; the hold test off, as it prepares its finest target in full).
    #[test]
    fn a_prepared_refinement_prepares_nothing_more() {
        let truth = Isometry3::new(Vector3::new(0.03, -0.02, 0.01), Vector3::z() * 0.02);
        let start = Isometry3::new(Vector3::new(0.035, -0.015, 0.01), Vector3::z() * 0.025);
        let target = floor_scene(true, 1);
        let source = floor_scene(true, 2).transformed(&truth.inverse());
        let slide = RegisterConfig::default().degeneracy_slide_voxels;
        for (factor, slide) in [(IcpFactor::Gicp, slide), (IcpFactor::PointToPlane, 0.0)] {
            let cfg = RegisterConfig {
                icp: IcpConfig {
                    factor,
                    ..IcpConfig::default()
                },
                icp_levels: 3,
                sided: false,
                degeneracy_test_threshold: 0.5,
                degeneracy_slide_voxels: slide,
                ..RegisterConfig::default()
            };
            let shared = PreparedLevels::new();
            prepare_refinement(&source, &target, &cfg, &shared).unwrap();
            let entries = || {
                (
                    shared.levels.entries.lock().unwrap().len(),
                    shared.spacings.entries.lock().unwrap().len(),
                )
            };
            let kept = entries();
            assert!(kept.0 >= 2 && kept.1 == 2, "{factor:?}: {kept:?} kept");
            let with = register_request(RegisterRequest {
                initial: Some(&start),
                prepared: Some(&shared),
                ..RegisterRequest::new(&source, &target, &cfg)
            })
            .unwrap();
            assert_eq!(
                entries(),
                kept,
                "{factor:?}: the refinement prepared a level"
            );
            let alone = register(&source, &target, Some(&start), &cfg).unwrap();
            let bits = |r: &Registration| r.transform.to_homogeneous().map(|x| x.to_bits());
            assert_eq!(bits(&with), bits(&alone), "{factor:?}");
            assert_eq!(with.covariance, alone.covariance, "{factor:?}");
        }
    }

    /// From a given start, point-to-plane registration prepares its first level bare (normals computed as
    /// ICP pairs the target's points and for the source's sampled points only) and gives, bit for bit,
    /// what the same registration with every normal prepared up front gives (shared levels prepare them
    /// all), with and without a normal gate.
    #[test]
    fn a_bare_first_level_changes_nothing() {
        let truth = Isometry3::new(Vector3::new(0.03, -0.02, 0.01), Vector3::z() * 0.02);
        let start = Isometry3::new(Vector3::new(0.035, -0.015, 0.01), Vector3::z() * 0.025);
        let target = floor_scene(true, 1);
        let source = floor_scene(true, 2).transformed(&truth.inverse());
        for gate in [None, Some(60.0)] {
            let cfg = RegisterConfig {
                icp: IcpConfig {
                    factor: IcpFactor::PointToPlane,
                    max_normal_angle_deg: gate,
                    ..IcpConfig::default()
                },
                sided: false,
                icp_max_source_points: 3000,
                ..RegisterConfig::default()
            };
            assert!(lazy_normals_ok(&cfg));
            let bare = register(&source, &target, Some(&start), &cfg).unwrap();
            let shared = PreparedLevels::new();
            let eager = register_request(RegisterRequest {
                initial: Some(&start),
                prepared: Some(&shared),
                ..RegisterRequest::new(&source, &target, &cfg)
            })
            .unwrap();
            let bits = |r: &Registration| r.transform.to_homogeneous().map(|x| x.to_bits());
            assert_eq!(bits(&bare), bits(&eager), "gate {gate:?}");
            assert_eq!(bare.covariance, eager.covariance);
            assert_eq!(bare.fitness.to_bits(), eager.fitness.to_bits());
            assert_eq!(bare.degeneracy.weak.len(), eager.degeneracy.weak.len());
            assert_eq!(
                bare.surface_agreement.to_bits(),
                eager.surface_agreement.to_bits()
            );
            assert_eq!(bare.trust.trusted, eager.trust.trusted);
            let (deg, m) = crate::geometry::transform::pose_error(&bare.transform, &truth);
            assert!(deg < 0.1 && m < 2e-3, "{deg}° {m} m");
        }
    }

    /// The hold test keeps a floor's yaw when boxes stand on it and reports it on the bare floor: every
    /// direction weaker than 0.5 is tested, so the verdict is the test's, not the eigenvalue's.
    #[test]
    fn the_hold_test_tells_a_held_direction_from_a_free_one() {
        let truth = Isometry3::new(Vector3::new(0.03, -0.02, 0.01), Vector3::z() * 0.02);
        let start = Isometry3::new(Vector3::new(0.035, -0.015, 0.01), Vector3::z() * 0.025);
        let cfg = RegisterConfig {
            degeneracy_test_threshold: 0.5,
            ..RegisterConfig::default()
        };
        for boxes in [true, false] {
            let target = floor_scene(boxes, 1);
            let source = floor_scene(boxes, 2).transformed(&truth.inverse());
            let r = register(&source, &target, Some(&start), &cfg).unwrap();
            let free: Vec<_> = r.degeneracy.weak.iter().map(|w| w.kind).collect();
            if boxes {
                assert!(!r.degeneracy.is_degenerate(), "{:?}", r.degeneracy);
                assert!(!r.degeneracy.held.is_empty(), "{:?}", r.degeneracy);
                for w in &r.degeneracy.held {
                    let h = w.hold.expect("a held direction carries its test");
                    assert!(h.step > 0.0, "{h:?}");
                    assert!(h.fraction() < cfg.degeneracy_hold_fraction, "{h:?}");
                }
                let (deg, m) = crate::geometry::transform::pose_error(&r.transform, &truth);
                assert!(deg < 0.05 && m < 2e-3, "{deg}° {m} m");
            } else {
                // The floor's own motions: two translations in it and the rotation about its normal.
                assert_eq!(free.len(), 3, "{:?}", r.degeneracy);
                assert_eq!(free.iter().filter(|k| **k == "translation").count(), 2);
                assert!(!r.trust.trusted);
                // Free, not loosely held: the ends stayed far apart, and the reason says so with figures.
                for w in &r.degeneracy.weak {
                    assert!(w.hold.expect("tested").fraction() >= 0.25, "{w:?}");
                }
                let reason = r.trust.reasons.join(" ");
                assert!(
                    reason.contains("unconstrained") && reason.contains("apart"),
                    "{reason}"
                );
            }
        }
    }
}
