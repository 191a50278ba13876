//! Profiling the registration pipeline (`depthcal profile`): each stage's wall and CPU time, items in
//! and out, throughput, each ICP iteration's time, residual and inliers, and the peak memory, over
//! repeated runs; on clouds from files or on a generated pair of any size ([`synthetic_pair`]).

use crate::error::{Error, Result};
use crate::geometry::transform::{pose_error, random_isometry};
use crate::geometry::{PointCloud, Rng};
use crate::registration::{register, RegisterConfig, Registration};
use crate::report::{ErrorReport, PoseReport};
use crate::timing::{peak_memory_bytes, reset_peak_memory, StageRecord};
use serde::Serialize;
use std::time::Instant;

/// The schema name and version of [`ProfileReport`].
pub const PROFILE_SCHEMA: &str = "depthcal.profile/1";

/// The stages of the pipeline that can be asked for, in order (`read` is the loading of the clouds).
pub const STAGES: [&str; 10] = [
    "read",
    "scale",
    "downsample_normals",
    "fpfh",
    "match",
    "ransac",
    "verify",
    "icp",
    "quality",
    "total",
];

/// The global stages: with none of them asked for, only the fine registration runs (from an initial
/// guess; `downsample_normals` then prepares its first level).
const GLOBAL_STAGES: [&str; 4] = ["fpfh", "match", "ransac", "verify"];

/// How to profile.
#[derive(Clone, Debug)]
pub struct ProfileConfig {
    /// Runs of the whole pipeline (default 3); the report gives each stage's median and minimum.
    pub repeat: usize,
    /// The stages to report (names of [`STAGES`]); empty: all.
    pub stages: Vec<String>,
}

impl Default for ProfileConfig {
    fn default() -> Self {
        ProfileConfig {
            repeat: 3,
            stages: Vec::new(),
        }
    }
}

impl ProfileConfig {
    /// Checks the repeat count and the stage names; the error names the unknown stage.
    pub fn validate(&self) -> Result<()> {
        if self.repeat == 0 || self.repeat > 1000 {
            return Err(Error::Config {
                field: "repeat".into(),
                msg: format!("must be 1 to 1000, got {}", self.repeat),
            });
        }
        for s in &self.stages {
            if !STAGES.contains(&s.as_str()) {
                return Err(Error::Config {
                    field: "stages".into(),
                    msg: format!(
                        "unknown stage {s:?}: expected some of {}",
                        STAGES.join(", ")
                    ),
                });
            }
        }
        Ok(())
    }

    /// Only the fine registration is asked for: no global stage among the stages.
    pub fn fine_only(&self) -> bool {
        !self.stages.is_empty()
            && !self
                .stages
                .iter()
                .any(|s| GLOBAL_STAGES.contains(&s.as_str()))
    }
}

/// One stage over the runs.
#[derive(Clone, Debug, Serialize)]
pub struct StageProfile {
    /// The stage.
    pub name: String,
    /// Median wall time, milliseconds.
    pub wall_ms: f64,
    /// Fastest run's wall time, milliseconds.
    pub wall_ms_min: f64,
    /// Median CPU time of the process over the stage (all threads), milliseconds.
    pub cpu_ms: Option<f64>,
    /// CPU over wall time: the threads kept busy on average.
    pub parallelism: Option<f64>,
    /// Items in (points, descriptors, correspondences, hypotheses; for `icp` the nearest-neighbour
    /// queries, source points × iterations).
    pub items_in: Option<usize>,
    /// Items out.
    pub items_out: Option<usize>,
    /// Items in per second of median wall time.
    pub items_per_s: Option<f64>,
}

/// One ICP iteration (of the last run).
#[derive(Clone, Debug, Serialize)]
pub struct IterationProfile {
    /// Wall time, milliseconds.
    pub time_ms: f64,
    /// Pairs within the correspondence distance.
    pub pairs: usize,
    /// Pairs kept by the trimming.
    pub kept: usize,
    /// RMS of the kept residuals (cloud units).
    pub residual: f64,
    /// Rotation of the step taken after the iteration, degrees (`None` for a level's last record).
    pub step_deg: Option<f64>,
    /// Translation of that step (cloud units; `None` for a level's last record).
    pub step_translation: Option<f64>,
}

/// One ICP level (of the last run).
#[derive(Clone, Debug, Serialize)]
pub struct LevelProfile {
    /// The level's voxel (cloud units).
    pub voxel: f64,
    /// Source points (queries per iteration).
    pub source_points: usize,
    /// Target points (in the kd-tree).
    pub target_points: usize,
    /// The level met its tolerances.
    pub converged: bool,
    /// Wall time preparing the level's clouds (downsampling, normals, kd-tree; for the first level the
    /// `downsample_normals` stage), milliseconds.
    pub prepare_ms: f64,
    /// Wall time of its iterations, milliseconds.
    pub iterate_ms: f64,
    /// Nearest-neighbour queries per second over the level's iterations.
    pub queries_per_s: f64,
    /// Every iteration.
    pub iterations: Vec<IterationProfile>,
}

/// The result of [`profile`], as `depthcal profile --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct ProfileReport {
    /// [`PROFILE_SCHEMA`].
    pub schema: &'static str,
    /// Where the clouds came from (two files, or `synthetic N`).
    pub input: String,
    /// Points of the source and target clouds.
    pub points: [usize; 2],
    /// Worker threads.
    pub threads: usize,
    /// Runs.
    pub repeat: usize,
    /// Only the fine registration ran (from an initial guess).
    pub fine_only: bool,
    /// The stages asked for, over the runs.
    pub stages: Vec<StageProfile>,
    /// The ICP levels of the last run, coarse to fine.
    pub icp_levels: Vec<LevelProfile>,
    /// Peak resident memory of the process during the runs, bytes (Linux).
    pub peak_memory_bytes: Option<u64>,
    /// The last run's transform.
    pub transform: PoseReport,
    /// Its ICP converged.
    pub converged: bool,
    /// Its fitness, 0–1.
    pub fitness: f64,
    /// Its error against the known transform (synthetic pairs, `--truth`).
    pub error_vs_truth: Option<ErrorReport>,
    /// The runs gave bit-identical transforms.
    pub deterministic: bool,
}

/// A generated pair of about `n` points a side: an indoor-like scene of planes, boxes, spheres and
/// cylinders ([`crate::sim::demo_scene`], about 3 m across, metres), split into two partially overlapping
/// views with 1 mm noise, the source moved by a random pose (up to 30° and 0.5 m). Returns the source, the
/// target and the true transform mapping the source into the target's frame.
pub fn synthetic_pair(
    n: usize,
    seed: u64,
) -> Result<(PointCloud, PointCloud, nalgebra::Isometry3<f64>)> {
    if !(100..=100_000_000).contains(&n) {
        return Err(Error::InvalidInput(format!(
            "a synthetic pair needs 100 to 100000000 points a side, got {n}"
        )));
    }
    // Each view keeps about half of its part of the scene (see split_overlapping).
    let scene = crate::sim::demo_scene(seed, n * 3);
    let (source, target, _) = crate::sim::split_overlapping(&scene, seed ^ 0x5eed, 0.6, 0.001);
    let mut rng = Rng::new(seed.wrapping_add(17));
    let pose = random_isometry(&mut rng, 30f64.to_radians(), 0.5);
    // The source is seen from elsewhere: its points are moved by pose⁻¹, the truth maps them back.
    Ok((source.transformed(&pose.inverse()), target, pose))
}

/// An initial guess near `truth` (3° and 5 cm off, a fixed direction), for profiling the fine stage of a
/// synthetic pair alone.
pub fn nearby_guess(truth: &nalgebra::Isometry3<f64>) -> nalgebra::Isometry3<f64> {
    let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(1.0, 2.0, 3.0));
    let off = nalgebra::Isometry3::from_parts(
        nalgebra::Translation3::new(0.03, -0.03, 0.028),
        nalgebra::UnitQuaternion::from_axis_angle(&axis, 3f64.to_radians()),
    );
    off * truth
}

/// Runs `load` and the registration pipeline `pcfg.repeat` times and reports each stage.
///
/// `load` gives the clouds (read from files, or generated) and is timed as the `read` stage. With
/// [`ProfileConfig::fine_only`], `init` is required and only the fine registration runs.
pub fn profile(
    input: &str,
    load: &mut dyn FnMut() -> Result<(PointCloud, PointCloud)>,
    init: Option<&nalgebra::Isometry3<f64>>,
    truth: Option<&nalgebra::Isometry3<f64>>,
    cfg: &RegisterConfig,
    pcfg: &ProfileConfig,
) -> Result<ProfileReport> {
    pcfg.validate()?;
    let init = if pcfg.fine_only() {
        Some(init.ok_or_else(|| {
            Error::InvalidInput(
                "profiling the fine stage alone (no global stage in --stages) needs an initial guess \
                 (--init FILE; synthetic pairs make one 3° / 5 cm from the truth)"
                    .into(),
            )
        })?)
    } else {
        init
    };
    let reset = reset_peak_memory();
    let mut runs: Vec<Vec<StageRecord>> = Vec::new();
    let mut last: Option<(Registration, [usize; 2])> = None;
    let mut deterministic = true;
    for _ in 0..pcfg.repeat {
        let t0 = Instant::now();
        let cpu0 = crate::timing::process_cpu_ms();
        let (s, t) = load()?;
        let read = StageRecord {
            name: "read".into(),
            wall_ms: t0.elapsed().as_secs_f64() * 1e3,
            cpu_ms: crate::timing::process_cpu_ms()
                .zip(cpu0)
                .map(|(b, a)| b - a),
            items_in: None,
            items_out: Some(s.len() + t.len()),
        };
        let reg = register(&s, &t, init, cfg)?;
        let mut stages = vec![read];
        stages.extend(reg.stages.iter().cloned());
        let total = StageRecord {
            name: "total".into(),
            wall_ms: t0.elapsed().as_secs_f64() * 1e3,
            cpu_ms: crate::timing::process_cpu_ms()
                .zip(cpu0)
                .map(|(b, a)| b - a),
            items_in: Some(s.len() + t.len()),
            items_out: None,
        };
        stages.push(total);
        if let Some((prev, _)) = &last {
            deterministic &= prev.transform == reg.transform;
        }
        runs.push(stages);
        last = Some((reg, [s.len(), t.len()]));
    }
    let (reg, points) = last.expect("at least one run");
    let wanted = |name: &str| pcfg.stages.is_empty() || pcfg.stages.iter().any(|s| s == name);
    let stages = runs[0]
        .iter()
        .map(|r| r.name.clone())
        .filter(|n| wanted(n))
        .map(|name| summarise(&name, &runs))
        .collect();
    let first_prepare = reg
        .stages
        .iter()
        .find(|s| s.name == "downsample_normals")
        .map_or(0.0, |s| s.wall_ms);
    let icp_levels = reg
        .icp_levels
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let ms: f64 = l.iterations.iter().map(|i| i.time_ms).sum();
            LevelProfile {
                voxel: l.voxel,
                source_points: l.source_points,
                target_points: l.target_points,
                converged: l.converged,
                prepare_ms: if k == 0 { first_prepare } else { l.prepare_ms },
                iterate_ms: ms,
                queries_per_s: (l.source_points * l.iterations.len()) as f64
                    / (ms * 1e-3).max(1e-9),
                iterations: l
                    .iterations
                    .iter()
                    .map(|i| IterationProfile {
                        time_ms: i.time_ms,
                        pairs: i.pairs,
                        kept: i.kept,
                        residual: i.residual_sigma,
                        step_deg: i.step_rotation.map(f64::to_degrees),
                        step_translation: i.step_translation,
                    })
                    .collect(),
            }
        })
        .collect();
    Ok(ProfileReport {
        schema: PROFILE_SCHEMA,
        input: input.to_string(),
        points,
        threads: rayon::current_num_threads(),
        repeat: pcfg.repeat,
        fine_only: pcfg.fine_only(),
        stages,
        icp_levels,
        peak_memory_bytes: if reset { peak_memory_bytes() } else { None },
        transform: PoseReport::new(&reg.transform),
        converged: reg.converged,
        fitness: reg.fitness,
        error_vs_truth: truth.map(|t| ErrorReport::new(pose_error(&reg.transform, t))),
        deterministic,
    })
}

fn median(v: Vec<f64>) -> f64 {
    crate::stats::median(&v)
}

/// One stage's figures over the runs (a stage missing from a run counts as absent there).
fn summarise(name: &str, runs: &[Vec<StageRecord>]) -> StageProfile {
    let recs: Vec<&StageRecord> = runs
        .iter()
        .filter_map(|r| r.iter().find(|s| s.name == name))
        .collect();
    let wall: Vec<f64> = recs.iter().map(|r| r.wall_ms).collect();
    let cpu: Option<Vec<f64>> = recs.iter().map(|r| r.cpu_ms).collect();
    let wall_ms = median(wall.clone());
    let cpu_ms = cpu.map(median);
    let items_in = recs.last().and_then(|r| r.items_in);
    StageProfile {
        name: name.to_string(),
        wall_ms,
        wall_ms_min: wall.iter().cloned().fold(f64::INFINITY, f64::min),
        cpu_ms,
        parallelism: cpu_ms.filter(|_| wall_ms > 0.0).map(|c| c / wall_ms),
        items_in,
        items_out: recs.last().and_then(|r| r.items_out),
        items_per_s: items_in
            .filter(|_| wall_ms > 0.0)
            .map(|n| n as f64 / (wall_ms * 1e-3)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_synthetic_pair_registers_to_its_truth_and_every_stage_is_reported() {
        let (s, t, truth) = synthetic_pair(20_000, 3).unwrap();
        assert!(
            s.len() > 10_000 && t.len() > 10_000,
            "{} {}",
            s.len(),
            t.len()
        );
        let r = profile(
            "synthetic",
            &mut || Ok((s.clone(), t.clone())),
            None,
            Some(&truth),
            &RegisterConfig::default(),
            &ProfileConfig {
                repeat: 2,
                stages: Vec::new(),
            },
        )
        .unwrap();
        let e = r.error_vs_truth.unwrap();
        assert!(e.rotation_deg < 0.5 && e.translation_m < 0.01, "{e:?}");
        assert!(r.deterministic);
        let names: Vec<&str> = r.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, STAGES.to_vec());
        let icp = r.stages.iter().find(|s| s.name == "icp").unwrap();
        let queries: usize = r
            .icp_levels
            .iter()
            .map(|l| l.source_points * l.iterations.len())
            .sum();
        assert_eq!(icp.items_in, Some(queries));
        assert!(r.icp_levels.iter().all(|l| !l.iterations.is_empty()));
    }

    #[test]
    fn the_fine_stage_alone_needs_a_guess_and_reports_only_what_was_asked() {
        let (s, t, truth) = synthetic_pair(5_000, 4).unwrap();
        let pcfg = ProfileConfig {
            repeat: 1,
            stages: vec!["icp".into()],
        };
        let mut load = || Ok((s.clone(), t.clone()));
        let e = profile(
            "x",
            &mut load,
            None,
            None,
            &RegisterConfig::default(),
            &pcfg,
        )
        .unwrap_err();
        assert!(e.to_string().contains("initial guess"), "{e}");
        let guess = nearby_guess(&truth);
        let r = profile(
            "x",
            &mut load,
            Some(&guess),
            Some(&truth),
            &RegisterConfig::default(),
            &pcfg,
        )
        .unwrap();
        assert!(r.fine_only);
        assert_eq!(r.stages.len(), 1);
        assert!(r.error_vs_truth.unwrap().rotation_deg < 0.5);
        let bad = ProfileConfig {
            repeat: 1,
            stages: vec!["icpp".into()],
        };
        assert!(
            profile("x", &mut load, None, None, &RegisterConfig::default(), &bad)
                .unwrap_err()
                .to_string()
                .contains("icpp")
        );
        assert!(synthetic_pair(10, 0).is_err());
    }
}
