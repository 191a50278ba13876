//! Robot-to-robot calibration of a cell: fuse each robot's frames in its base frame, get an initial
//! `T_base1_base2` from an [`Initializer`], refine it with trimmed robust ICP, and report its quality.

use crate::calibration::consistency::{robot_consistency, ConsistencyConfig, RobotConsistency};
use crate::calibration::handeye::depth::check::{
    check_hand_eye_under_scatter, HandEyeCheck, HandEyeCheckConfig,
};
use crate::calibration::hypotheses::{
    choose, refine_and_judge, without_robot_bodies, FreeSpaceTest,
};
use crate::calibration::initializer::{InitialGuess, Initializer, InitializerInput, SearchConfig};
use crate::calibration::pose_scatter::{estimate_pose_scatter, PoseScatter, PoseScatterConfig};
use crate::calibration::priors::CellPriors;
use crate::calibration::uncertainty::{
    cloud_motion_covariance, inputs_covariance, normalised_error, NormalisedError,
};
use crate::calibration::visibility::VisibilityConfig;
use crate::cell::{Cell, CellRobot};
use crate::error::{Error, Result};
use crate::fusion::{fuse_robot, FuseConfig, FusedCloud};
use crate::geometry::transform::pose_error;
use crate::registration::correspondence::MatchConfig;
use crate::registration::pipeline::recheck_weak_directions;
use crate::registration::quality::Degeneracy;
use crate::registration::Trust;
use crate::registration::{IcpConfig, IcpFactor, RansacConfig, RegisterConfig, RobustKernel};
use crate::timing::StageTimer;
use nalgebra::{Isometry3, Matrix6};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Settings of [`calibrate`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrateConfig {
    /// Fusion of each robot's frames (default: automatic voxel at 4 pixel footprints, no outlier removal
    /// (the trimmed ICP and the robust kernel deal with stray points), no normals (registration estimates
    /// its own)).
    pub fuse: FuseConfig,
    /// Registration settings for the refinement (and for the depth initialiser): three ICP levels and
    /// one-way feature matches by default.
    pub register: RegisterConfig,
    /// Use the `[priors]` of `cell.toml` (default true).
    pub use_priors: bool,
    /// Seed of every randomised step: calibrate's one seed (the initialisers and the refinement take it;
    /// `register.seed` must be left out).
    pub seed: u64,
    /// The marker method's settings (`--method marker`).
    pub marker: crate::calibration::marker_init::MarkerMethodConfig,
    /// The 2D-feature method's settings (`--method features`).
    pub features: crate::calibration::feature_init::FeatureMethodConfig,
    /// The check of each robot's own frames against each other ([`crate::calibration::consistency`]).
    pub consistency: ConsistencyConfig,
    /// Registration uses only the fused points within this multiple of the robot's median range (the
    /// distance from a point to the cameras that saw it); `None` keeps every point. Default 2.5: depth noise
    /// grows with the square of the range, so a surface at 2.5 times the median range is about six times
    /// noisier than the workspace the cameras look at, and a wide far floor or wall then outweighs the
    /// shared objects in every stage (measured on foreign cells with a floor in view: untrusted without
    /// the cut, 0.007° / 0.13 mm with it; 2.0 cost the demo cell 0.02° / 0.25 mm). The free-space test still uses whole frames.
    pub max_range_factor: Option<f64>,
    /// `--refine-hand-eye`: the per-robot hand-eye refinements from depth, the joint refinement of both
    /// hand-eyes with `T_base1_base2`, and whether its base-to-base transform is adopted
    /// (docs/handeye.md#hand-eye-from-depth).
    pub refine_hand_eye: crate::calibration::handeye::depth::joint::RefineHandEyeConfig,
    /// The check of each robot's stated hand-eye (and its 1-σ) against its own depth frames
    /// ([`crate::calibration::handeye::depth::check`]); an inconsistent one makes the result untrusted.
    pub hand_eye_check: HandEyeCheckConfig,
    /// The free-space test of hypotheses and of the result ([`crate::calibration::visibility`]); its
    /// `robot_body_radius_m` also leaves the other robot's body out of the refinement under each
    /// hypothesis ([`crate::calibration::hypotheses`]).
    pub visibility: VisibilityConfig,
    /// The depth initialiser's searches ([`SearchConfig`]).
    pub search: SearchConfig,
    /// Each robot's pose scatter from its own frames, and the frames moved by it before they are fused
    /// ([`crate::calibration::pose_scatter`]).
    pub pose_scatter: PoseScatterConfig,
    /// Two robots' base origins stand at least this far apart, metres (default 0.12; 0 turns it off). Not
    /// a prior of the cell but a fact of any cell: two bases cannot share one footprint, and the smallest
    /// common arm's is 128 mm across (a UR3's). The global search drops hypotheses that put the bases
    /// closer, and a result that does is not trusted. On cells whose robots each see mostly their own
    /// side of the workspace, the clouds laid on each other (the bases 6-77 mm apart) explained the data
    /// better than the truth and were the answer on 4 of 10 wrong low-overlap cells (docs/accuracy.md).
    pub min_base_distance_m: f64,
    /// Cells of three or more robots: the pose graph over the pairwise results
    /// (`calibration::multi_robot`, which builds on this module).
    pub pose_graph: crate::calibration::pose_graph::PoseGraphConfig,
}

impl Default for CalibrateConfig {
    fn default() -> Self {
        CalibrateConfig {
            fuse: FuseConfig {
                auto_voxel_factor: 4.0,
                outlier: None,
                normals: None,
                // Each frame's depth in 4x4-pixel blocks, for the free-space test of the hypotheses.
                depth_views: Some(4),
                ..FuseConfig::default()
            },
            register: RegisterConfig {
                icp_levels: 3,
                // GICP with Tukey's kernel: from the truth on simulated cells it settles at a median
                // 0.010° / 0.15 mm (worst of 6: 0.037° / 0.31 mm) where point-to-plane with Huber settled at
                // 0.059° / 0.79 mm (worst 0.126° / 1.66 mm) (`tools/refine_probe.rs`).
                icp: IcpConfig {
                    factor: IcpFactor::Gicp,
                    kernel: RobustKernel::Tukey,
                    // Pairs between different surfaces (a face one robot saw against the edge of one the
                    // other saw) bias the yaw where the robots share little.
                    max_normal_angle_deg: Some(30.0),
                    // GICP creeps along a cell's weakest direction: a foreign table cell needed 108
                    // iterations at its middle level (40 left it 0.25° / 2.8 mm off and unconverged).
                    // Cells that converge early do not pay for the larger budget.
                    max_iterations: 150,
                    ..IcpConfig::default()
                },
                // One-way matches: the priors already prune hypotheses hard, and on cells whose robots
                // share little (35-50%) the mutual filter left too few true matches (measured).
                matching: MatchConfig {
                    mutual: false,
                    ..MatchConfig::default()
                },
                // Many distinct hypotheses for the free-space test to choose from: at low overlap the
                // truth is rarely among RANSAC's 50 best by feature inliers.
                ransac: RansacConfig {
                    verify_top: 300,
                    ..RansacConfig::default()
                },
                // GICP on fused cells leaves a smaller systematic part than the generic floor assumes:
                // with 0.12 voxel the normalised errors of seeded cells had an RMS of 0.21 (`cell_sweep`).
                systematic_voxel_fraction: 0.04,
                // Fused clouds know which side each surface was seen from.
                sided: true,
                ..RegisterConfig::default()
            },
            use_priors: true,
            seed: 0,
            marker: Default::default(),
            features: Default::default(),
            consistency: ConsistencyConfig::default(),
            max_range_factor: Some(2.5),
            refine_hand_eye: Default::default(),
            hand_eye_check: HandEyeCheckConfig::default(),
            visibility: VisibilityConfig::default(),
            search: SearchConfig::default(),
            pose_scatter: PoseScatterConfig::default(),
            min_base_distance_m: 0.12,
            pose_graph: Default::default(),
        }
    }
}

impl CalibrateConfig {
    /// Checks the ranges of every field and nested configuration; the error names the field, e.g.
    /// `register.icp.max_iterations`. [`calibrate_request`] calls it first.
    pub fn validate(&self) -> Result<()> {
        self.fuse.validate()?;
        self.register.validate().map_err(|e| e.within("register"))?;
        if self.register.seed != RegisterConfig::default().seed && self.register.seed != self.seed {
            return Err(Error::config(
                "register.seed",
                format!(
                    "calibrate has one seed, `seed` ({}); set it there instead of register.seed ({})",
                    self.seed, self.register.seed
                ),
            ));
        }
        if self.register.ransac.constraint != Default::default() {
            return Err(Error::config(
                "register.ransac.constraint",
                "calibrate takes its pose constraint from the cell's [priors] (cell.toml); state the priors there",
            ));
        }
        self.marker.validate()?;
        self.features.validate()?;
        self.consistency.validate()?;
        if let Some(f) = self.max_range_factor {
            crate::error::check::positive("max_range_factor", f)?;
        }
        self.refine_hand_eye.validate()?;
        self.hand_eye_check.validate()?;
        self.visibility.validate()?;
        self.pose_scatter.validate()?;
        self.search.validate()?;
        crate::error::check::non_negative("min_base_distance_m", self.min_base_distance_m)?;
        self.pose_graph.validate()?;
        Ok(())
    }
}

/// The result of [`calibrate`].
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The reference robot's name (base1).
    pub reference: String,
    /// The other robot's name (base2).
    pub other: String,
    /// `T_base1_base2`: maps the other robot's base coordinates into the reference robot's base (metres).
    pub transform: Isometry3<f64>,
    /// Covariance of `[rx, ry, rz (rad), tx, ty, tz (m)]`, a left increment in the reference base frame.
    pub covariance: Matrix6<f64>,
    /// The initialiser's estimate before refinement.
    pub initial: InitialGuess,
    /// Initialiser name.
    pub method: String,
    /// Trimmed robust ICP refined the initial estimate (false with `--no-refine`: then the quality
    /// figures below are `None`, `converged` is false and the degeneracy empty).
    pub refined: bool,
    /// Fraction of the other robot's points with a reference point within the final correspondence
    /// distance (`None` when not refined).
    pub fitness: Option<f64>,
    /// RMS distance of those pairs, metres (`None` when not refined).
    pub inlier_rmse: Option<f64>,
    /// Overlap estimated by the trimmed ICP, a fraction (`None` when not refined).
    pub overlap: Option<f64>,
    /// ICP's finest level met its tolerances (after a second run from where it stopped, when the first ran out).
    pub converged: bool,
    /// Degeneracy analysis of the final ICP.
    pub degeneracy: Degeneracy,
    /// Priors used, in words.
    pub priors_used: Vec<String>,
    /// Fused points per robot (reference, other).
    pub fused_points: [usize; 2],
    /// Frames per robot (reference, other).
    pub frames: [usize; 2],
    /// Errors against `ground_truth.json` when the cell has one: (degrees, metres).
    pub error_vs_truth: Option<(f64, f64)>,
    /// The same for the initial estimate.
    pub initial_error_vs_truth: Option<(f64, f64)>,
    /// Wall time per stage, milliseconds.
    pub timings_ms: Vec<(String, f64)>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
    /// The priors were assumed (the cell did not state them), not read.
    pub priors_assumed: bool,
    /// Free-space violation of the final transform (mean of both ways, 0–1) and the margin used (m),
    /// when the fused clouds carry their depth views.
    pub free_space: Option<FreeSpaceCheck>,
    /// A far-away second answer of the initialiser that scored almost as well, if any.
    pub ambiguity: Option<crate::registration::pipeline::Ambiguity>,
    /// Whether the result can be trusted, and why not.
    pub trust: Trust,
    /// The part of `covariance` that the cell's inputs (hand-eyes, pose repeatability, depth scale) add
    /// ([`crate::calibration::uncertainty`]).
    pub inputs_covariance: Matrix6<f64>,
    /// The error against the ground truth normalised by `covariance`, when the cell has a truth.
    pub normalised_error: Option<NormalisedError>,
    /// Each robot's own frames against each other (reference, other), when the clouds were fused.
    pub consistency: Vec<RobotConsistency>,
    /// Each robot's stated hand-eye against its own depth frames (reference, other), when the clouds were
    /// fused and `hand_eye_check.enabled`.
    pub hand_eye_checks: Vec<HandEyeCheck>,
    /// The refinement's ICP levels, coarse to fine, with each iteration's residuals (metres) and inliers
    /// (empty when not refined).
    pub icp_levels: Vec<crate::registration::IcpLevelTrace>,
    /// The hypotheses the refinement refined and judged at full resolution, in the initialiser's order
    /// ([`crate::calibration::hypotheses`]): one for an initialiser with one answer, none without
    /// refinement.
    pub hypotheses: Vec<crate::calibration::hypotheses::JudgedSummary>,
    /// Each robot's pose scatter from its own frames (reference, other), when the clouds were fused and
    /// `pose_scatter.enabled`.
    pub pose_scatter: Vec<PoseScatter>,
}

/// The free-space test of the final transform.
#[derive(Clone, Debug, Serialize)]
pub struct FreeSpaceCheck {
    /// Mean of both ways' violation fractions at the final transform, 0–1.
    pub violation: f64,
    /// The worse of the two robots' own clouds against their own frames at the same margin, 0–1.
    pub own_violation: f64,
    /// The margin, metres.
    pub margin_m: f64,
}

/// The two robots of a cell: the reference and the first other one.
pub fn robot_pair(cell: &Cell) -> Result<(&CellRobot, &CellRobot)> {
    let reference = cell.reference();
    let other = cell
        .robots
        .iter()
        .find(|r| r.name != reference.name)
        .ok_or_else(|| {
            Error::InvalidInput(format!(
                "{}: the cell needs two robots, it names only {:?}",
                cell.dir.join("cell.toml").display(),
                reference.name
            ))
        })?;
    Ok((reference, other))
}

/// Both robots' fused clouds and the cell's priors: what [`refine_cell`] and the initialisers work on.
/// Fuse once with [`fuse_cell`] to compare several initialisers on the same clouds.
#[derive(Clone, Debug)]
pub struct FusedCell {
    /// The reference robot's fused cloud (base1 frame, metres).
    pub reference: FusedCloud,
    /// The other robot's fused cloud (base2 frame, metres).
    pub other: FusedCloud,
    /// The priors used (empty when `use_priors` is off).
    pub priors: CellPriors,
    /// Wall time of the fusion, milliseconds.
    pub fuse_ms: f64,
    /// Each robot's stated hand-eye against its own depth frames (reference, other; empty when
    /// `hand_eye_check.enabled` is off).
    pub hand_eye_checks: Vec<HandEyeCheck>,
    /// Wall time of those checks, milliseconds.
    pub hand_eye_check_ms: f64,
    /// Each robot's pose scatter (reference, other; empty when `pose_scatter.enabled` is off or nothing
    /// was fused).
    pub pose_scatter: Vec<PoseScatter>,
    /// Wall time of the pose scatter estimates and the fusion again of moved frames, milliseconds.
    pub pose_scatter_ms: f64,
    /// The robots as fused (reference, other): the cell's, with the frames moved by their pose
    /// corrections and the pose 1-σ widened to the scatter where it was applied; empty when nothing was
    /// fused.
    pub robots: Vec<CellRobot>,
}

impl FusedCell {
    /// No clouds, only the priors: for initialisers that do not need the clouds, without refinement.
    pub fn without_clouds(cell: &Cell, cfg: &CalibrateConfig) -> Result<Self> {
        Ok(FusedCell::from_clouds(
            FusedCloud::default(),
            FusedCloud::default(),
            read_priors(cell, cfg)?,
        ))
    }

    /// Clouds fused elsewhere (each in its own robot's base frame) with `priors`: no hand-eye checks, no
    /// pose scatter, the cell's robots as they are.
    pub fn from_clouds(reference: FusedCloud, other: FusedCloud, priors: CellPriors) -> Self {
        FusedCell {
            reference,
            other,
            priors,
            fuse_ms: 0.0,
            hand_eye_checks: Vec::new(),
            hand_eye_check_ms: 0.0,
            pose_scatter: Vec::new(),
            pose_scatter_ms: 0.0,
            robots: Vec::new(),
        }
    }
}

/// The `[priors]` of `cell.toml`, or none when `cfg.use_priors` is off.
pub(crate) fn read_priors(cell: &Cell, cfg: &CalibrateConfig) -> Result<CellPriors> {
    if cfg.use_priors {
        CellPriors::from_manifest_extra(&cell.manifest.extra, &cell.dir.join("cell.toml"))
    } else {
        Ok(CellPriors::none())
    }
}

/// Fuses both robots' frames in their own base frames (in parallel), reads the priors, and checks each
/// robot's hand-eye against its depth frames (`cfg.hand_eye_check`).
pub fn fuse_cell(cell: &Cell, cfg: &CalibrateConfig) -> Result<FusedCell> {
    let (reference, other) = robot_pair(cell)?;
    let priors = read_priors(cell, cfg)?;
    let fused = fuse_robots(&[reference, other], cfg)?;
    Ok(fused.pair(0, 1, priors))
}

/// Each robot's fused cloud (its own base frame) with what was learnt on the way: the output of
/// [`fuse_robots`], from which [`FusedRobots::pair`] makes the [`FusedCell`] of any two robots.
#[derive(Clone, Debug)]
pub struct FusedRobots {
    /// One fused cloud per robot, in the order given.
    pub clouds: Vec<FusedCloud>,
    /// Each robot's stated hand-eye against its own depth frames (empty when `hand_eye_check.enabled` is
    /// off).
    pub hand_eye_checks: Vec<HandEyeCheck>,
    /// Each robot's pose scatter (empty when `pose_scatter.enabled` is off or a robot has no depth views).
    pub pose_scatter: Vec<PoseScatter>,
    /// The robots as fused: with the frames moved by their pose corrections and the pose 1-σ widened to the
    /// scatter where it was applied.
    pub robots: Vec<CellRobot>,
    /// Wall times of the fusion, the pose scatter and the hand-eye checks, milliseconds.
    pub fuse_ms: f64,
    /// See `fuse_ms`.
    pub pose_scatter_ms: f64,
    /// See `fuse_ms`.
    pub hand_eye_check_ms: f64,
}

impl FusedRobots {
    /// The fused cell of robots `i` (the pair's reference) and `j` with `priors`.
    pub fn pair(&self, i: usize, j: usize, priors: CellPriors) -> FusedCell {
        FusedCell {
            reference: self.clouds[i].clone(),
            other: self.clouds[j].clone(),
            priors,
            fuse_ms: self.fuse_ms,
            hand_eye_checks: pick_two(&self.hand_eye_checks, i, j),
            hand_eye_check_ms: self.hand_eye_check_ms,
            pose_scatter: pick_two(&self.pose_scatter, i, j),
            pose_scatter_ms: self.pose_scatter_ms,
            robots: pick_two(&self.robots, i, j),
        }
    }
}

/// Items `i` and `j` of `v`, or none when `v` is empty.
fn pick_two<T: Clone>(v: &[T], i: usize, j: usize) -> Vec<T> {
    if v.is_empty() {
        Vec::new()
    } else {
        vec![v[i].clone(), v[j].clone()]
    }
}

/// Fuses each robot's frames in its own base frame (the robots in parallel, stage by stage): the fusion,
/// each robot's pose scatter from its own frames (the frames moved by it and fused again where it is
/// applied), the side each surface was seen from, the range cut ([`CalibrateConfig::max_range_factor`]),
/// and the check of each robot's stated hand-eye against its depth frames (`cfg.hand_eye_check`).
pub fn fuse_robots(robots: &[&CellRobot], cfg: &CalibrateConfig) -> Result<FusedRobots> {
    use rayon::prelude::*;
    let t0 = Instant::now();
    // Each fusion has sequential parts (index builds, voxel merges): the robots run side by side.
    let mut clouds: Vec<FusedCloud> = robots
        .par_iter()
        .map(|r| fuse_robot(*r, &cfg.fuse, &|_| {}))
        .collect::<Result<_>>()?;
    let fuse_ms = t0.elapsed().as_secs_f64() * 1e3;
    // Each robot's frames moved to agree with each other where their poses scatter, then fused again.
    let t_scatter = Instant::now();
    let mut pose_scatter = Vec::new();
    let mut fused_robots: Vec<CellRobot> = robots.iter().map(|r| (*r).clone()).collect();
    if cfg.pose_scatter.enabled && clouds.iter().all(|c| !c.views.is_empty()) {
        let estimates: Vec<(PoseScatter, Option<FusedCloud>)> = robots
            .par_iter()
            .zip(clouds.par_iter())
            .map(|(r, c)| {
                let s = estimate_pose_scatter(r, &c.views, &cfg.pose_scatter)?;
                let refused = if s.applied {
                    Some(fuse_robot(&s.corrected(r), &cfg.fuse, &|_| {})?)
                } else {
                    None
                };
                Ok((s, refused))
            })
            .collect::<Result<_>>()?;
        for (k, (s, cloud)) in estimates.into_iter().enumerate() {
            if let Some(c) = cloud {
                log::info!(
                    "robot {}: poses scatter {:.2} mm / {:.3}° (RMS per axis); frames moved and fused again",
                    s.robot,
                    s.scatter_mm,
                    s.scatter_deg
                );
                clouds[k] = c;
            }
            fused_robots[k] = s.corrected(&fused_robots[k]);
            pose_scatter.push(s);
        }
    }
    let pose_scatter_ms = t_scatter.elapsed().as_secs_f64() * 1e3;
    for (c, r) in clouds.iter_mut().zip(robots) {
        // The side each surface was seen from travels with the points as their normals.
        c.make_sided();
        if let Some(f) = cfg.max_range_factor {
            let dropped = keep_within_range(c, f);
            if dropped > 0 {
                log::info!(
                    "{}: {dropped} fused points beyond {f} x the median range left out of the registration",
                    r.name
                );
            }
        }
    }
    let t1 = Instant::now();
    let hand_eye_checks = if cfg.hand_eye_check.enabled {
        // On the cell's own poses: the moved frames could hide a hand-eye that is off. Where the poses
        // scatter, the test allows for what the scatter alone makes the depth ask for.
        (0..robots.len())
            .into_par_iter()
            .map(|k| {
                let c = &clouds[k];
                let views = (!c.views.is_empty()).then_some(c.views.as_slice());
                let scatter = pose_scatter
                    .get(k)
                    .and_then(|s: &PoseScatter| s.hand_eye_covariance.as_ref());
                check_hand_eye_under_scatter(robots[k], views, &cfg.hand_eye_check, scatter)
            })
            .collect::<Result<Vec<_>>>()?
    } else {
        Vec::new()
    };
    Ok(FusedRobots {
        clouds,
        hand_eye_checks,
        pose_scatter,
        robots: fused_robots,
        fuse_ms,
        pose_scatter_ms,
        hand_eye_check_ms: t1.elapsed().as_secs_f64() * 1e3,
    })
}

/// Drops the points of `cloud` farther than `factor` times its median range from the cameras that saw them
/// ([`CalibrateConfig::max_range_factor`]); returns the number dropped. The median is over the depth
/// samples (each point weighted by the samples fused into it), i.e. about the median depth of the frames:
/// per point, a wide far floor fills most voxels of the fused cloud while the cameras look at the workspace.
fn keep_within_range(cloud: &mut FusedCloud, factor: f64) -> usize {
    let ranges = cloud.ranges();
    if ranges.is_empty() || cloud.counts.len() != ranges.len() {
        return 0;
    }
    let mut order: Vec<(f32, u32)> = ranges
        .iter()
        .copied()
        .zip(cloud.counts.iter().copied())
        .collect();
    order.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: u64 = order.iter().map(|&(_, c)| c as u64).sum();
    let mut acc = 0u64;
    let median = order
        .iter()
        .find(|&&(_, c)| {
            acc += c as u64;
            2 * acc >= total
        })
        .map_or(f32::INFINITY, |&(r, _)| r);
    let limit = (factor * median as f64) as f32;
    cloud.retain_points(|i| ranges[i] <= limit)
}

/// What to calibrate and how: the one entry point [`calibrate_request`] takes it; [`calibrate`] is the
/// common case.
pub struct CalibrateRequest<'a> {
    /// The cell dataset.
    pub cell: &'a Cell,
    /// Where the first estimate of `T_base1_base2` comes from.
    pub initializer: &'a dyn Initializer,
    /// The settings.
    pub config: &'a CalibrateConfig,
    /// Refine the initialiser's estimate with trimmed robust ICP (default true). Without it the result is
    /// the initialiser's estimate and its 1-σ (`calibrate --no-refine`), and an initialiser that does not
    /// need the clouds ([`Initializer::needs_clouds`]) fuses none.
    pub refine: bool,
    /// Called with a stage description as each stage starts.
    pub progress: Option<&'a mut dyn FnMut(&str)>,
}

impl<'a> CalibrateRequest<'a> {
    /// The cell with `initializer` under `config`, refined, without progress reports.
    pub fn new(
        cell: &'a Cell,
        initializer: &'a dyn Initializer,
        config: &'a CalibrateConfig,
    ) -> Self {
        CalibrateRequest {
            cell,
            initializer,
            config,
            refine: true,
            progress: None,
        }
    }
}

/// Calibrates the cell: `T_base1_base2` between the reference robot and the other robot.
///
/// `progress` is called with a stage description as each stage starts. The same as [`calibrate_request`]
/// with refinement, without the fused clouds.
pub fn calibrate(
    cell: &Cell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let mut req = CalibrateRequest::new(cell, initializer, cfg);
    req.progress = Some(progress);
    calibrate_request(req).map(|(c, _)| c)
}

/// Calibrates the cell as `req` asks: fuse → initialise → refine (unless `req.refine` is false) → the
/// checks. Returns the result and the fused clouds it registered (each in its own robot's base frame, e.g.
/// to write them out; empty when none were needed).
pub fn calibrate_request(req: CalibrateRequest) -> Result<(Calibration, FusedCell)> {
    let CalibrateRequest {
        cell,
        initializer,
        config: cfg,
        refine,
        progress,
    } = req;
    let mut quiet = |_: &str| {};
    let progress: &mut dyn FnMut(&str) = match progress {
        Some(p) => p,
        None => &mut quiet,
    };
    cfg.validate()?;
    let fuse = refine || initializer.needs_clouds();
    let fused = if fuse {
        if refine {
            let (reference, other) = robot_pair(cell)?;
            progress(&format!(
                "fusing {} frames of {} and {} of {}",
                reference.frames.len(),
                reference.name,
                other.frames.len(),
                other.name
            ));
        } else {
            progress("fusing both robots' frames");
        }
        fuse_cell(cell, cfg)?
    } else {
        FusedCell::without_clouds(cell, cfg)?
    };
    let mut c = refine_cell(cell, &fused, initializer, cfg, refine, progress)?;
    // One pair is calibrated; a robot beyond it is named, not dropped in silence.
    let left_out: Vec<&str> = cell
        .robots
        .iter()
        .map(|r| r.name.as_str())
        .filter(|n| *n != c.reference && *n != c.other)
        .collect();
    if !left_out.is_empty() {
        c.warnings.push(format!(
            "the cell names {} robots and this call solves one pair: {:?} against the reference {:?}; not calibrated: {:?} (`depthcal calibrate` and calibration::multi_robot solve every robot)",
            cell.robots.len(),
            c.other,
            c.reference,
            left_out
        ));
    }
    if fuse {
        c.timings_ms.insert(0, ("fuse".into(), fused.fuse_ms));
        if !fused.pose_scatter.is_empty() {
            c.timings_ms
                .insert(1, ("pose_scatter".into(), fused.pose_scatter_ms));
        }
        if !fused.hand_eye_checks.is_empty() {
            let at = c.timings_ms.len().min(2);
            c.timings_ms
                .insert(at, ("hand_eye_check".into(), fused.hand_eye_check_ms));
        }
    }
    Ok((c, fused))
}

/// Runs `initializer` on the fused cell (the timings exclude the fusion) and, when `refine` is set, refines its estimate with trimmed robust
/// ICP; without refinement the result is the initial estimate with a covariance from its stated 1-σ and
/// no cloud quality figures (NaN).
pub fn refine_cell(
    cell: &Cell,
    fused: &FusedCell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    refine: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let pair = match fused.robots.as_slice() {
        [a, b] => (a, b),
        _ => robot_pair(cell)?,
    };
    let truth = cell.ground_truth()?.and_then(|g| g.t_base1_base2);
    refine_pair(pair, fused, initializer, cfg, refine, truth, progress)
}

/// [`refine_cell`] for any two robots of a cell: `pair` is (the pair's reference, the other) as fused in
/// `fused`, `truth` their true `T_reference_other` when known.
pub fn refine_pair(
    pair: (&CellRobot, &CellRobot),
    fused: &FusedCell,
    initializer: &dyn Initializer,
    cfg: &CalibrateConfig,
    refine: bool,
    truth: Option<Isometry3<f64>>,
    progress: &mut dyn FnMut(&str),
) -> Result<Calibration> {
    let (reference, other) = pair;
    let mut timer = StageTimer::new();
    let priors = fused.priors.constraint();
    // The search also drops hypotheses whose bases would share one footprint.
    let constraint = priors.clone().with_min_translation(cfg.min_base_distance_m);
    let (ref_cloud, other_cloud) = (&fused.reference, &fused.other);
    progress(&format!("initialising ({})", initializer.name()));
    let initial = initializer.initialize(&InitializerInput {
        reference: ref_cloud,
        other: other_cloud,
        constraint: &constraint,
        seed: cfg.seed,
    })?;
    timer.lap("initialize");
    let mut out = Calibration {
        reference: reference.name.clone(),
        other: other.name.clone(),
        transform: initial.transform,
        covariance: initial.covariance(),
        method: initializer.name().to_string(),
        refined: false,
        fitness: None,
        inlier_rmse: None,
        overlap: None,
        converged: false,
        degeneracy: Degeneracy {
            condition: f64::NAN,
            weak: Vec::new(),
            held: Vec::new(),
        },
        priors_used: fused.priors.describe(),
        fused_points: [ref_cloud.cloud.len(), other_cloud.cloud.len()],
        frames: [reference.frames.len(), other.frames.len()],
        error_vs_truth: truth.map(|t| pose_error(&initial.transform, &t)),
        initial_error_vs_truth: truth.map(|t| pose_error(&initial.transform, &t)),
        ambiguity: initial.ambiguity.clone(),
        initial,
        timings_ms: Vec::new(),
        warnings: Vec::new(),
        priors_assumed: fused.priors.level_assumed() && cfg.use_priors,
        free_space: None,
        trust: Trust::new(),
        inputs_covariance: Matrix6::zeros(),
        normalised_error: None,
        consistency: Vec::new(),
        hand_eye_checks: fused.hand_eye_checks.clone(),
        icp_levels: Vec::new(),
        hypotheses: Vec::new(),
        pose_scatter: fused.pose_scatter.clone(),
    };
    if !ref_cloud.views.is_empty() && !other_cloud.views.is_empty() {
        let (a, b) = rayon::join(
            || robot_consistency(reference, ref_cloud, &cfg.consistency),
            || robot_consistency(other, other_cloud, &cfg.consistency),
        );
        out.consistency = vec![a, b];
        timer.lap("consistency");
    }
    let inputs = |t: &nalgebra::Isometry3<f64>| {
        inputs_covariance(
            t,
            &cloud_motion_covariance(reference, &ref_cloud.views),
            &cloud_motion_covariance(other, &other_cloud.views),
        )
    };
    if !refine {
        out.inputs_covariance = inputs(&out.transform);
        out.covariance += out.inputs_covariance;
        out.normalised_error =
            truth.and_then(|t| normalised_error(&out.transform, &t, &out.covariance));
        out.trust = calibration_trust(&out, &priors, cfg.min_base_distance_m, None);
        out.timings_ms = timer.wall_ms();
        return Ok(out);
    }
    progress("refining (trimmed robust ICP)");
    let mut rcfg = cfg.register.clone();
    rcfg.seed = cfg.seed;
    // The hold test of weak directions runs once, on the answer kept (below), not on every hypothesis:
    // these only collect its candidates.
    rcfg.degeneracy_threshold = cfg.register.degeneracy_candidate_threshold();
    rcfg.degeneracy_slide_voxels = 0.0;
    // The initialiser's answer and its alternatives, each refined and judged at full resolution.
    let starts: Vec<nalgebra::Isometry3<f64>> = std::iter::once(out.initial.transform)
        .chain(out.initial.alternatives.iter().copied())
        .collect();
    let test = FreeSpaceTest::new(fused, &cfg.visibility);
    let mut judged = refine_and_judge(fused, &starts, &rcfg, &cfg.visibility, test.as_ref())?;
    let summaries: Vec<_> = judged
        .iter()
        .map(|j| j.summary(cfg.visibility.choice_penalty_scale))
        .collect();
    let (best, rival) = choose(&summaries, judged[0].registration.voxel, &rcfg);
    for (k, j) in judged.iter().enumerate() {
        log::info!(
            "hypothesis {k}{}: score {:.3}, agreement {:.3}, fitness {:.3}, free space {}{}",
            if k == best { " (chosen)" } else { "" },
            summaries[k].score,
            j.agreement(),
            j.registration.fitness,
            j.free_space
                .as_ref()
                .map_or("untested".to_string(), |f| format!(
                    "{:.1}%",
                    f.violation * 1e2
                )),
            truth.map_or(String::new(), |t| {
                let (r, m) = pose_error(&j.registration.transform, &t);
                format!(", {r:.3}° / {:.2} mm from the truth", m * 1e3)
            })
        );
    }
    // The search's own coarse ambiguity gives way to the judgement at full resolution.
    out.ambiguity = rival;
    out.hypotheses = summaries;
    out.hypotheses[best].chosen = true;
    let mut chosen = judged.swap_remove(best);
    // A refinement that ran out of iterations gets them: once more, from where it stopped, with the whole
    // budget again. Its answer replaces the first only if it converged; otherwise the result stays
    // unconverged (and untrusted).
    if !chosen.registration.converged {
        let from = chosen.registration.transform;
        let again = refine_and_judge(fused, &[from], &rcfg, &cfg.visibility, test.as_ref())?;
        if let Some(j) = again.into_iter().next() {
            let (r, m) = pose_error(&j.registration.transform, &from);
            log::info!(
                "the chosen hypothesis ran out of ICP iterations; continued: moved {r:.4}° / {:.3} mm, converged {}",
                m * 1e3,
                j.registration.converged
            );
            if j.registration.converged {
                chosen = j;
            }
        }
    }
    let mut reg = chosen.registration;
    if reg.degeneracy.is_degenerate() {
        let (reference, other) = without_robot_bodies(fused, &chosen.start, &cfg.visibility);
        let hold = RegisterConfig {
            degeneracy_slide_voxels: cfg.register.degeneracy_slide_voxels,
            ..rcfg.clone()
        };
        recheck_weak_directions(&mut reg, other, reference, &hold)?;
    }
    timer.lap("refine");
    out.warnings = reg.warnings.clone();
    out.transform = reg.transform;
    out.inputs_covariance = inputs(&reg.transform);
    out.covariance = reg.covariance + out.inputs_covariance;
    out.normalised_error =
        truth.and_then(|t| normalised_error(&out.transform, &t, &out.covariance));
    out.refined = true;
    out.fitness = Some(reg.fitness);
    out.inlier_rmse = Some(reg.inlier_rmse);
    out.overlap = Some(reg.overlap);
    out.converged = reg.converged;
    out.degeneracy = reg.degeneracy;
    out.error_vs_truth = truth.map(|t| pose_error(&reg.transform, &t));
    out.free_space = chosen.free_space;
    out.icp_levels = reg.icp_levels;
    timer.lap("checks");
    out.trust = calibration_trust(&out, &priors, cfg.min_base_distance_m, Some(&reg.trust));
    out.timings_ms = timer.wall_ms();
    Ok(out)
}

/// The quality gate of a calibration: the registration's own checks, the priors, the bases' distance
/// (`min_base_distance_m`, metres), the initialiser's ambiguity and the free-space test.
fn calibration_trust(
    c: &Calibration,
    constraint: &crate::registration::PoseConstraint,
    min_base_distance_m: f64,
    registration: Option<&Trust>,
) -> Trust {
    let mut t = Trust::new();
    if let Some(r) = registration {
        t.merge(r);
    }
    let distance = c.transform.translation.vector.norm();
    if distance < min_base_distance_m {
        t.fail(
            format!(
                "robot {:?}'s base would stand {:.3} m from robot {:?}'s, closer than two robots' bases can (min_base_distance_m {:.2} m)",
                c.other, distance, c.reference, min_base_distance_m
            ),
            "capture views of the part of the workspace both robots see, or state [priors] base_distance_m in cell.toml",
        );
    }
    if !constraint.is_empty() && !constraint.accepts(&c.transform) {
        let z = c.transform.rotation * nalgebra::Vector3::z();
        t.fail(
            format!(
                "the result violates the priors ({}): tilt {:.2}°, base distance {:.3} m",
                c.priors_used.join(", "),
                z.z.clamp(-1.0, 1.0).acos().to_degrees(),
                c.transform.translation.vector.norm()
            ),
            "check [priors] in cell.toml; if a base really is tilted, state bases_level = false (or use --no-priors)",
        );
    }
    for r in c.consistency.iter().filter(|r| !r.consistent) {
        t.fail(
            format!(
                "robot {:?}'s own frames are not consistent: {}",
                r.robot,
                r.findings.join("; ")
            ),
            format!(
                "check robot {:?}'s intrinsics (focal length, principal point, depth scale), hand-eye and pose file",
                r.robot
            ),
        );
    }
    for h in c.hand_eye_checks.iter().filter(|h| !h.consistent) {
        t.fail(h.reason(), h.suggestion());
    }
    if let Some(a) = &c.ambiguity {
        let what = if c.refined {
            format!(
                "a second answer {:.2}° / {:.1} mm away, refined at full resolution, explains the data {:.0}% as well (surface agreement over the surfaces' directions, weighed by the free-space test: {:.3} against {:.3}) and passes the free-space test",
                a.rotation_deg,
                a.translation * 1e3,
                a.score_ratio * 1e2,
                a.score_ratio * a.best_score,
                a.best_score
            )
        } else {
            format!(
                "a second answer {:.2}° / {:.1} mm from the initial estimate scores {:.0}% of it in the global stage's verification",
                a.rotation_deg,
                a.translation * 1e3,
                a.score_ratio * 1e2
            )
        };
        t.fail(
            format!("ambiguous: {what}"),
            "give an initialiser (--method marker|checkerboard|features or --init), a crop box around the shared part, or more views of distinctive shared objects",
        );
    }
    if let Some(f) = &c.free_space {
        if !f.passes() {
            t.fail(
                format!(
                    "free-space test failed: {:.1}% of the surfaces land where the other robot's cameras saw through them or saw them from behind (each robot's own frames: {:.1}%)",
                    f.violation * 1e2,
                    f.own_violation * 1e2
                ),
                "the clouds overlap in a wrong pose: try an initialiser (--init or an image method) and check the hand-eyes and intrinsics",
            );
        }
    }
    t
}
