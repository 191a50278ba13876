//! Each robot's frames fused into one cloud in its own base frame, with what the fusion learns on the way
//! (pose scatter, hand-eye check, the range cut): [`fuse_robots`] for any number of robots,
//! [`FusedRobots::pair`] and [`fuse_cell`] for the two robots one calibration registers ([`FusedCell`]).

use crate::calibration::config::CalibrateConfig;
use crate::calibration::handeye::depth::check::{check_hand_eye_under_scatter, HandEyeCheck};
use crate::calibration::pose_scatter::{estimate_pose_scatter, PoseScatter};
use crate::calibration::priors::CellPriors;
use crate::cell::{Cell, CellRobot};
use crate::error::Result;
use crate::fusion::{fuse_robot, FuseConfig, FusedCloud};
use std::time::Instant;

/// Both robots' fused clouds and the cell's priors: what [`crate::calibration::robot_to_robot::refine_cell`] and the initialisers work on.
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
    let (reference, other) = cell.robot_pair()?;
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
    // The range cut happens inside the fusion, before its costly surface fit.
    let fuse_cfg = FuseConfig {
        max_range_factor: cfg.max_range_factor,
        ..cfg.fuse.clone()
    };
    // Each fusion has sequential parts (index builds, voxel merges): the robots run side by side.
    let mut clouds: Vec<FusedCloud> = robots
        .par_iter()
        .map(|r| fuse_robot(*r, &fuse_cfg, &|_| {}))
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
                    Some(fuse_robot(&s.corrected(r), &fuse_cfg, &|_| {})?)
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
        if let (Some(f), dropped @ 1..) = (cfg.max_range_factor, c.stats.range_cut) {
            log::info!(
                "{}: {dropped} fused points beyond {f} x the median range left out of the registration",
                r.name
            );
        }
    }
    let t1 = Instant::now();
    let hand_eye_checks = if cfg.hand_eye_check.enabled {
        // On the cell's own poses: the moved frames could hide a hand-eye that is off. Where the poses
        // scatter, the test allows for what pose errors of the scatter's size make its fit ask for.
        (0..robots.len())
            .into_par_iter()
            .map(|k| {
                let c = &clouds[k];
                let views = (!c.views.is_empty()).then_some(c.views.as_slice());
                let scatter = pose_scatter
                    .get(k)
                    .filter(|s: &&PoseScatter| s.widened)
                    .map(|s| {
                        (
                            s.beyond_hand_eye_deg.to_radians(),
                            s.beyond_hand_eye_mm * 1e-3,
                        )
                    });
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
