//! Each robot's pose scatter, from its own frames: how far each frame's flange pose is from where its depth
//! says it is, and the frames moved there before they are fused.
//!
//! A robot's frames all show one static scene, so under exact poses every frame's surfaces land on every
//! other frame's. Robot poses are not exact: an arm's repeatability is 0.03–0.1 mm, but its absolute pose
//! (what the controller reports after a move) scatters by tenths of a millimetre to millimetres, more on
//! worn or lightly built arms and on tracked cameras. Each frame sees its own part of the scene, so that
//! scatter does not average out in the fused cloud: the surfaces a registration leans on (a few objects
//! that pin the yaw) are each placed by the two or three frames that saw them, and a millimetre there is
//! tenths of a degree of `T_base1_base2`.
//!
//! So every frame gets a correction `C_i` (a left increment in the robot's base frame, `T_base_cam' = C_i
//! · T_base_cam`), all at once, by Gauss-Newton on the point-to-plane residuals of every frame's sampled
//! surface points against every other frame's depth (the hand-eye check's association:
//! [`crate::calibration::handeye::depth::residuals`]), with
//! - a Gaussian prior on each correction (`prior_mm`, `prior_deg`): a direction the depth does not see keeps
//!   the pose's value;
//! - the gauge fixed by a zero mean of the corrections: the frames move to agree with each other, the cloud
//!   as a whole stays where the mean pose puts it (an error shared by all frames, a hand-eye or a base
//!   offset, is not the poses' scatter and is left to the hand-eye check);
//! - a frame whose correction stands out of the others' scatter left as it is (a wrong pose row), so that
//!   the frames' consistency check still names it.
//!
//! The scatter (RMS of the corrections) is reported per robot; when it exceeds the robot's stated pose
//! repeatability it replaces it in the covariance of `T_base1_base2` ([`crate::calibration::uncertainty`]).

use crate::calibration::consistency::ConsistencyConfig;
use crate::calibration::handeye::depth::residuals::{Association, FrameMap, FramePoints, Problem};
use crate::calibration::uncertainty::adjoint;
use crate::camera::DepthView;
use crate::cell::CellRobot;
use crate::error::Result;
use crate::geometry::outer::OuterSum6;
use crate::registration::RobustKernel;
use crate::stats::median;
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`estimate_pose_scatter`]. Lengths in metres unless named `_mm`, angles in degrees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseScatterConfig {
    /// Estimate the scatter and move the frames (default true).
    pub enabled: bool,
    /// Frames a robot needs for the estimate (default 4): with fewer, the frames' overlaps say little.
    pub min_frames: usize,
    /// Depth blocks sampled per frame at most (default 600) ...
    pub sample_points: usize,
    /// ... and point tests over all frame pairs at most (default 300 000: 394 samples a frame at 20
    /// frames): fewer samples per frame on robots with many frames.
    pub max_pair_tests: usize,
    /// Association gates, coarse to fine, metres (default `[0.02, 0.008]`).
    pub gates_m: Vec<f64>,
    /// Gauss-Newton iterations per gate at most (default 3) ...
    pub iterations: usize,
    /// ... fewer at a gate once a step moves no frame's scene by more than this, millimetres (default
    /// 0.001, a micrometre: a tenth of the reported scatter's last digit). On exact poses the steps fall
    /// below it after one or two iterations at each gate; on scattered poses they stay above it.
    pub step_tolerance_mm: f64,
    /// 1-σ of the loose prior on each correction with which the scatter is first estimated, millimetres
    /// (default 20) ...
    pub prior_mm: f64,
    /// ... and degrees (default 2).
    pub prior_deg: f64,
    /// The frames are moved only when the scatter is below this, millimetres (default 4.5) ...
    pub max_moved_mm: f64,
    /// ... and degrees (default 0.45): frames that disagree by centimetres (the 7-Scenes cell's tracked
    /// poses) are also warped by depth distortion and drift, which one rigid correction per frame does
    /// not undo: moving them cost that cell 0.14° / 4 mm.
    pub max_moved_deg: f64,
    /// The frames are moved only when their corrections displace the scene by more than this (RMS per
    /// axis), millimetres (default 0.5). Frames of RealSense-like depth whose poses scatter by 0.01–0.1 mm
    /// still ask for 0.1–0.34 mm (their depth noise is not all independent per pixel), and moving them
    /// by that cost up to 0.05° on those cells; 0.93 mm of pose noise asks for 0.97–1.30 mm (the trust
    /// sweep, docs/accuracy.md).
    pub apply_above_mm: f64,
    /// A frame whose displacement exceeds `outlier_factor` x the robust scatter of all frames' ...
    pub outlier_factor: f64,
    /// ... and this, millimetres, is left as it is (default 4 and 3 mm).
    pub outlier_floor_mm: f64,
    /// The sampled blocks are spread over the directions of their normals, in this many bins per axis
    /// of the normal (default 2: the eight octants; 0 samples uniformly, as the consistency check does).
    /// Uniformly, most samples of a frame lie on table and floor, and the corrections of the directions
    /// only the objects' sides pin (yaw, horizontal shifts) stay noisy: on the pose-noise cells of the
    /// trust sweep the octants brought `T_base1_base2` to what a perfect correction would leave
    /// (docs/accuracy.md, "Pose scatter").
    pub normal_bins: u32,
}

impl Default for PoseScatterConfig {
    fn default() -> Self {
        PoseScatterConfig {
            enabled: true,
            min_frames: 4,
            sample_points: 600,
            max_pair_tests: 300_000,
            gates_m: vec![0.02, 0.008],
            iterations: 3,
            step_tolerance_mm: 0.001,
            prior_mm: 20.0,
            prior_deg: 2.0,
            max_moved_mm: 4.5,
            max_moved_deg: 0.45,
            apply_above_mm: 0.5,
            outlier_factor: 4.0,
            outlier_floor_mm: 3.0,
            normal_bins: 2,
        }
    }
}

impl PoseScatterConfig {
    /// Checks the ranges; the error names the field (`pose_scatter.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        check::at_least("pose_scatter.min_frames", self.min_frames, 2)?;
        check::at_least("pose_scatter.sample_points", self.sample_points, 10)?;
        check::at_least("pose_scatter.max_pair_tests", self.max_pair_tests, 1)?;
        check::at_least("pose_scatter.gates_m", self.gates_m.len(), 1)?;
        for g in &self.gates_m {
            check::positive("pose_scatter.gates_m", *g)?;
        }
        check::at_least("pose_scatter.iterations", self.iterations, 1)?;
        check::non_negative("pose_scatter.step_tolerance_mm", self.step_tolerance_mm)?;
        check::positive("pose_scatter.prior_mm", self.prior_mm)?;
        check::positive("pose_scatter.prior_deg", self.prior_deg)?;
        check::non_negative("pose_scatter.max_moved_mm", self.max_moved_mm)?;
        check::non_negative("pose_scatter.max_moved_deg", self.max_moved_deg)?;
        check::non_negative("pose_scatter.apply_above_mm", self.apply_above_mm)?;
        check::positive("pose_scatter.outlier_factor", self.outlier_factor)?;
        check::non_negative("pose_scatter.outlier_floor_mm", self.outlier_floor_mm)
    }
}

/// One robot's pose scatter and the corrections of its frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PoseScatter {
    /// The robot.
    pub robot: String,
    /// Whether it was estimated (enough frames, enough overlap between them).
    pub estimated: bool,
    /// Why not, when it was not.
    pub note: Option<String>,
    /// RMS per axis of the frames' corrections: translation at the scene's centre, millimetres ...
    pub scatter_mm: f64,
    /// ... and rotation, degrees.
    pub scatter_deg: f64,
    /// RMS per axis of the displacement the corrections cause at the frames' sampled points, millimetres
    /// (what `apply_above_mm` is compared with).
    pub displacement_mm: f64,
    /// Whether the frames were moved by their corrections before fusion: the scatter is significant
    /// (`displacement_mm` above `apply_above_mm`) and within what the corrections model (`max_moved_mm`,
    /// `max_moved_deg`).
    pub applied: bool,
    /// Whether the scatter is significant: it then replaces the stated pose repeatability in the covariance
    /// where it is larger, and the hand-eye check allows for it (moved or not).
    pub widened: bool,
    /// Frames whose correction stands out of the others' scatter (left as they are), by frame id.
    pub outliers: Vec<String>,
    /// The scatter a change of the hand-eye does not explain, RMS per axis at the scene: translation,
    /// millimetres ...
    #[serde(skip)]
    pub beyond_hand_eye_mm: f64,
    /// ... and rotation, degrees. A hand-eye change `δ` asks each frame for the correction
    /// `Ad(T_base_cam_i) δ` less the mean (the gauge); the corrections less the best-fitting such pattern
    /// are the poses' own scatter. The hand-eye check allows for this one, so that a hand-eye that is off,
    /// which the corrections also absorb, does not widen its own allowance.
    #[serde(skip)]
    pub beyond_hand_eye_deg: f64,
    /// Each frame's correction, a left increment in the base frame (identity where not applied).
    #[serde(skip)]
    pub corrections: Vec<Isometry3<f64>>,
}

impl PoseScatter {
    fn not_estimated(robot: &CellRobot, note: String) -> Self {
        PoseScatter {
            robot: robot.name.clone(),
            estimated: false,
            note: Some(note),
            scatter_mm: 0.0,
            scatter_deg: 0.0,
            displacement_mm: 0.0,
            applied: false,
            widened: false,
            outliers: Vec::new(),
            beyond_hand_eye_mm: 0.0,
            beyond_hand_eye_deg: 0.0,
            corrections: vec![Isometry3::identity(); robot.frames.len()],
        }
    }

    /// `robot` with its frames moved by the corrections and, where the scatter exceeds its stated pose
    /// repeatability, the scatter as its pose 1-σ (the corrections leave less, but the covariance
    /// propagation weighs every point alike while a registration leans on a few surfaces).
    pub fn corrected(&self, robot: &CellRobot) -> CellRobot {
        let mut r = robot.clone();
        if self.applied {
            for (f, c) in r.frames.iter_mut().zip(&self.corrections) {
                f.t_base_ee = c * f.t_base_ee;
            }
        }
        if !self.widened {
            return r;
        }
        let u = &mut r.uncertainty;
        u.pose_translation_m = u.pose_translation_m.max(self.scatter_mm * 1e-3);
        u.pose_rotation_rad = u.pose_rotation_rad.max(self.scatter_deg.to_radians());
        r
    }
}

/// Twist `[ω, v]` about `c` as an isometry: `x ↦ c + exp(ω)(x − c) + v`.
fn about(c: &Vector3<f64>, d: &Vector6<f64>) -> Isometry3<f64> {
    let r = UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2]));
    let v = Vector3::new(d[3], d[4], d[5]);
    Isometry3::from_parts(Translation3::from(c - r * c + v), r)
}

/// A frame-to-frame map as the isometry itself (`q = a · p`, quaternion rotation), as the scatter's
/// equations have always moved the points, with its rotation as a matrix for the side-of-surface rule.
struct IsometryMap {
    a: Isometry3<f64>,
    r: Matrix3<f64>,
}

impl IsometryMap {
    fn of(a: Isometry3<f64>) -> Self {
        IsometryMap {
            r: *a.rotation.to_rotation_matrix().matrix(),
            a,
        }
    }
}

impl FrameMap for IsometryMap {
    fn rotation(&self) -> &Matrix3<f64> {
        &self.r
    }
    #[inline]
    fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        (self.a * nalgebra::Point3::from(*p)).coords
    }
}

/// The normal equations of all frames' corrections at the current poses, added in a fixed order.
fn normal_equations(
    problem: &Problem,
    cams: &[Isometry3<f64>],
    centre: &Vector3<f64>,
    asn: &Association,
) -> (DMatrix<f64>, DVector<f64>, Stats) {
    let n = cams.len();
    let map = |i: usize, j: usize| IsometryMap::of(cams[j].inverse() * cams[i]);
    let tests = problem.test_pairs(asn, map);
    // Per frame i: for each other frame j, the 6x6 block JᵀWJ and the 6-vector JᵀWr of i's points
    // against j's surfaces.
    #[allow(clippy::type_complexity)]
    let per_frame: Vec<(Vec<(usize, Matrix6<f64>, Vector6<f64>, usize)>, Stats)> = tests
        .into_par_iter()
        .enumerate()
        .map(|(i, pairs)| {
            let fp: &FramePoints = &problem.points[i];
            let mut out = Vec::new();
            let mut stats = Stats::default();
            let mut used = vec![false; fp.points.len()];
            // Each sampled point about the centre, once (not once per other frame that sees it).
            let about_centre: Vec<Vector3<f64>> = fp
                .points
                .iter()
                .map(|p| (cams[i] * nalgebra::Point3::from(*p)).coords - centre)
                .collect();
            for (j, pt) in pairs.iter().enumerate().filter(|&(j, _)| j != i) {
                let rj = *cams[j].rotation.to_rotation_matrix().matrix();
                let (mut h, mut g, mut k) = (OuterSum6::default(), Vector6::zeros(), 0usize);
                for f in &pt.hits {
                    let big_n = rj * f.nj;
                    let pc = &about_centre[f.k as usize];
                    let jw = pc.cross(&big_n);
                    let row = Vector6::new(jw.x, jw.y, jw.z, big_n.x, big_n.y, big_n.z);
                    let ws = f.weight / (f.sigma * f.sigma);
                    h.add(&row, ws);
                    g += row * (f.res * ws);
                    k += 1;
                    stats.chi2 += f.weight * (f.res / f.sigma).powi(2);
                    stats.weight += f.weight;
                    used[f.k as usize] = true;
                }
                if k > 0 {
                    out.push((j, h.matrix(), g, k));
                }
                stats.tests += k;
            }
            stats.samples = used.iter().filter(|&&u| u).count();
            (out, stats)
        })
        .collect();
    let mut hh = DMatrix::<f64>::zeros(6 * n, 6 * n);
    let mut gg = DVector::<f64>::zeros(6 * n);
    let mut stats = Stats::default();
    for (i, (pairs, st)) in per_frame.iter().enumerate() {
        stats.add(st);
        for (j, h, g, _) in pairs {
            let j = *j;
            // r(ε_i, ε_j) ≈ r + J ε_i − J ε_j.
            let mut add = |a: usize, b: usize, m: &Matrix6<f64>| {
                let mut blk = hh.view_mut((6 * a, 6 * b), (6, 6));
                blk += m;
            };
            add(i, i, h);
            add(j, j, h);
            add(i, j, &(-h));
            add(j, i, &(-h));
            let mut gi = gg.rows_mut(6 * i, 6);
            gi += g;
            let mut gj = gg.rows_mut(6 * j, 6);
            gj -= g;
        }
    }
    (hh, gg, stats)
}

/// Residual statistics of one evaluation of the normal equations.
#[derive(Clone, Copy, Debug, Default)]
struct Stats {
    /// Point tests counted.
    tests: usize,
    /// Sampled points that took part in at least one test.
    samples: usize,
    /// `Σ w r² / σ²`.
    chi2: f64,
    /// `Σ w`.
    weight: f64,
}

impl Stats {
    fn add(&mut self, o: &Stats) {
        self.tests += o.tests;
        self.samples += o.samples;
        self.chi2 += o.chi2;
        self.weight += o.weight;
    }

    /// How much larger the corrections' variance is than `H⁻¹` says: the robust variance factor `s²`
    /// times the tests per sampled point (each point is tested against several frames, which are not
    /// independent measurements of it), at least 1.
    fn inflation(&self) -> f64 {
        if self.samples == 0 || self.weight <= 0.0 {
            return 1.0;
        }
        let k = self.tests as f64 / self.samples as f64;
        (k * self.chi2 / self.weight).max(1.0)
    }
}

/// One solve's outcome: each frame's correction and its variances (6 per frame, inflated), and the
/// residual statistics.
struct Solved {
    eps: Vec<Vector6<f64>>,
    var: Vec<Vector6<f64>>,
    stats: Stats,
}

/// Estimates the pose scatter of `robot` from its frames' depth `views` (frame order, as fused), and the
/// correction of each frame.
pub fn estimate_pose_scatter(
    robot: &CellRobot,
    views: &[DepthView],
    cfg: &PoseScatterConfig,
) -> Result<PoseScatter> {
    cfg.validate()?;
    let n = robot.frames.len();
    if n < cfg.min_frames || views.len() != n {
        return Ok(PoseScatter::not_estimated(
            robot,
            format!("{n} frames: the estimate needs at least {}", cfg.min_frames),
        ));
    }
    let ccfg = ConsistencyConfig {
        sample_points: (cfg.max_pair_tests / (n * (n - 1))).clamp(10, cfg.sample_points),
        block: views[0].block,
        ..ConsistencyConfig::default()
    };
    let cams0: Vec<Isometry3<f64>> = views.iter().map(|v| v.t_cam_base.inverse()).collect();
    let problem = Problem::with_sampling(
        cams0.clone(),
        views,
        &robot.intrinsics,
        &ccfg,
        cfg.normal_bins,
    );
    let all: Vec<Vector3<f64>> = problem
        .points
        .iter()
        .zip(&cams0)
        .flat_map(|(f, c)| {
            f.points
                .iter()
                .map(move |p| (c * nalgebra::Point3::from(*p)).coords)
        })
        .collect();
    if all.len() < 10 * n {
        return Ok(PoseScatter::not_estimated(
            robot,
            "too few smooth surface samples in the frames".into(),
        ));
    }
    let centre = all.iter().sum::<Vector3<f64>>() / all.len() as f64;
    let range = (all.iter().map(|p| (p - centre).norm_squared()).sum::<f64>() / all.len() as f64)
        .sqrt()
        .max(0.05);
    let displacement = |e: &Vector6<f64>| -> f64 {
        // RMS displacement at the scene: translation plus rotation at the scene's RMS radius.
        (Vector3::new(e[3], e[4], e[5]).norm_squared()
            + (Vector3::new(e[0], e[1], e[2]).norm() * range).powi(2))
        .sqrt()
    };
    let solve = |fixed: &[bool], pr: f64, pt: f64| -> Option<Solved> {
        let mut eps = vec![Vector6::<f64>::zeros(); n];
        let mut last = None;
        for &gate in &cfg.gates_m {
            let asn = Association {
                gate_m: gate,
                min_normal_cos: 45f64.to_radians().cos(),
                kernel: RobustKernel::Huber,
                kernel_sigmas: 2.0,
            };
            for _ in 0..cfg.iterations {
                let cams: Vec<Isometry3<f64>> = cams0
                    .iter()
                    .zip(&eps)
                    .map(|(c, e)| about(&centre, e) * c)
                    .collect();
                let (mut h, mut g, stats) = normal_equations(&problem, &cams, &centre, &asn);
                // Prior on each correction (a fixed frame: a very tight one), and the gauge: the mean
                // correction is zero.
                let mut gauge = Vector6::<f64>::zeros();
                for i in 0..n {
                    let scale = if fixed[i] { 1e-6 } else { 1.0 };
                    let (r, t) = (1.0 / (pr * scale).powi(2), 1.0 / (pt * scale).powi(2));
                    let w = Vector6::new(r, r, r, t, t, t);
                    for d in 0..6 {
                        h[(6 * i + d, 6 * i + d)] += w[d];
                        g[6 * i + d] += w[d] * eps[i][d];
                        gauge[d] = gauge[d].max(h[(6 * i + d, 6 * i + d)]);
                    }
                }
                let free: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
                let mut sum = Vector6::<f64>::zeros();
                for &i in &free {
                    sum += eps[i];
                }
                for &a in &free {
                    for &b in &free {
                        for d in 0..6 {
                            h[(6 * a + d, 6 * b + d)] += 10.0 * gauge[d];
                        }
                    }
                    for d in 0..6 {
                        g[6 * a + d] += 10.0 * gauge[d] * sum[d];
                    }
                }
                let chol = h.cholesky()?;
                let step = chol.solve(&(-g));
                let mut largest: f64 = 0.0;
                for (i, e) in eps.iter_mut().enumerate() {
                    let d: Vector6<f64> = step.fixed_rows::<6>(6 * i).into_owned();
                    largest = largest.max(displacement(&d));
                    *e += d;
                }
                last = Some((chol, stats));
                if largest * 1e3 <= cfg.step_tolerance_mm {
                    break;
                }
            }
        }
        let (chol, stats) = last?;
        let inv = chol.inverse();
        let f = stats.inflation();
        let var = (0..n)
            .map(|i| Vector6::from_fn(|d, _| inv[(6 * i + d, 6 * i + d)] * f))
            .collect();
        Some(Solved { eps, var, stats })
    };
    // The scatter by components (rotation, translation about the scene's centre): the corrections' mean
    // square less what their own noise explains (empirical Bayes), at least the stated repeatability.
    let scatter = |s: &Solved, fixed: &[bool], k: usize, floor: f64| -> f64 {
        let kept: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
        let m = (3 * kept.len()).max(1) as f64;
        let (mut sq, mut var) = (0.0, 0.0);
        for &i in &kept {
            for d in k..k + 3 {
                sq += s.eps[i][d].powi(2);
                var += s.var[i][d];
            }
        }
        ((sq - var) / m).max(floor * floor).sqrt()
    };
    // RMS per axis over the frames not fixed.
    let rms_displacement = |eps: &[Vector6<f64>], fixed: &[bool]| -> f64 {
        let kept: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
        let m = kept.len().max(1) as f64;
        (kept
            .iter()
            .map(|&i| displacement(&eps[i]).powi(2))
            .sum::<f64>()
            / (3.0 * m))
            .sqrt()
    };
    let u = &robot.uncertainty;
    // At the scene's centre, a flange rotation also shifts: the repeatability there.
    let floor_r = u.pose_rotation_rad;
    let floor_t = (u.pose_translation_m.powi(2) + (u.pose_rotation_rad * range).powi(2)).sqrt();
    let loose = (cfg.prior_deg.to_radians(), cfg.prior_mm * 1e-3);
    // Round 1 with the loose prior finds the scatter; round 2 solves again with the scatter as the prior,
    // so that corrections the frames' own noise explains shrink away.
    // When even the loose prior's corrections stay below `apply_above_mm`, the second round (which only
    // shrinks them) cannot make the scatter significant, and is skipped.
    let rounds = |fixed: &[bool]| -> Option<(Solved, f64, f64)> {
        let first = solve(fixed, loose.0, loose.1)?;
        let sr = scatter(&first, fixed, 0, floor_r).min(loose.0);
        let st = scatter(&first, fixed, 3, floor_t).min(loose.1);
        if rms_displacement(&first.eps, fixed) * 1e3 <= cfg.apply_above_mm {
            return Some((first, sr, st));
        }
        Some((solve(fixed, sr, st)?, sr, st))
    };
    let mut fixed = vec![false; n];
    let Some((mut solved, mut sr, mut st)) = rounds(&fixed) else {
        return Ok(PoseScatter::not_estimated(
            robot,
            "the frames' normal equations are not positive definite".into(),
        ));
    };
    // A frame far out of the others' scatter is a wrong pose row, not scatter: leave it as it is (the
    // consistency check names it) and solve again without it.
    let d: Vec<f64> = solved.eps.iter().map(displacement).collect();
    let robust = 1.4826 * median(&d);
    let limit = (cfg.outlier_factor * robust).max(cfg.outlier_floor_mm * 1e-3);
    for i in 0..n {
        fixed[i] = d[i] > limit;
    }
    if fixed.iter().any(|&f| f) {
        match rounds(&fixed) {
            Some(s) => (solved, sr, st) = s,
            None => {
                return Ok(PoseScatter::not_estimated(
                    robot,
                    "the frames' normal equations are not positive definite".into(),
                ))
            }
        }
    }
    let tests = solved.stats.tests;
    if tests < 20 * n {
        return Ok(PoseScatter::not_estimated(
            robot,
            format!("the frames overlap too little ({tests} point tests)"),
        ));
    }
    let eps = &solved.eps;
    let displacement_mm = rms_displacement(eps, &fixed) * 1e3;
    let (scatter_mm, scatter_deg) = (st * 1e3, sr.to_degrees());
    let kept: Vec<usize> = (0..n).filter(|&i| !fixed[i]).collect();
    let (beyond_r, beyond_t) = scatter_beyond_hand_eye(
        &solved,
        &kept,
        &cams0,
        &centre,
        (sr, st),
        (floor_r, floor_t),
    );
    log::debug!(
        "robot {}: pose scatter {scatter_mm:.3} mm / {scatter_deg:.4}° at the scene, corrections {displacement_mm:.3} mm RMS, {tests} tests, inflation {:.2}",
        robot.name,
        solved.stats.inflation()
    );
    let widened = displacement_mm > cfg.apply_above_mm;
    let modelled = scatter_mm < cfg.max_moved_mm && scatter_deg < cfg.max_moved_deg;
    let applied = widened && modelled;
    let note = (widened && !modelled).then(|| {
        format!(
            "the frames disagree by more than one rigid correction per frame models ({:.1} mm / {:.2}° or more): \
             not moved, the 1-σ widened",
            cfg.max_moved_mm, cfg.max_moved_deg
        )
    });
    let corrections = (0..n)
        .map(|i| {
            if applied && !fixed[i] {
                about(&centre, &eps[i])
            } else {
                Isometry3::identity()
            }
        })
        .collect();
    Ok(PoseScatter {
        robot: robot.name.clone(),
        estimated: true,
        note,
        scatter_mm,
        scatter_deg,
        displacement_mm,
        applied,
        widened,
        outliers: (0..n)
            .filter(|&i| fixed[i])
            .map(|i| robot.frames[i].id.clone())
            .collect(),
        beyond_hand_eye_mm: beyond_t * 1e3,
        beyond_hand_eye_deg: beyond_r.to_degrees(),
        corrections,
    })
}

/// The scatter of `s`'s corrections (frames `kept`, cameras `cams` in the base frame) that no change of the
/// hand-eye explains: the hand-eye pattern `(Ad(T_base_cam_i) − mean) δ` (twists about `centre`) fitted to
/// the corrections by least squares weighted with the scatter `(sr, st)`, and the rest's mean square less
/// what the corrections' own noise explains, over the degrees of freedom left (3 per frame and component,
/// less the 3 of `δ`), at least the floors. Returns (rotation in radians, translation in metres).
fn scatter_beyond_hand_eye(
    s: &Solved,
    kept: &[usize],
    cams: &[Isometry3<f64>],
    centre: &Vector3<f64>,
    (sr, st): (f64, f64),
    (floor_r, floor_t): (f64, f64),
) -> (f64, f64) {
    let ms: Vec<Matrix6<f64>> = kept
        .iter()
        .map(|&i| adjoint(&(Isometry3::translation(-centre.x, -centre.y, -centre.z) * cams[i])))
        .collect();
    let mean = ms.iter().sum::<Matrix6<f64>>() / ms.len().max(1) as f64;
    let (wr, wt) = (1.0 / (sr * sr), 1.0 / (st * st));
    let w = Matrix6::from_diagonal(&Vector6::new(wr, wr, wr, wt, wt, wt));
    let mut info = Matrix6::zeros();
    let mut rhs = Vector6::zeros();
    for (m, &i) in ms.iter().zip(kept) {
        let a = m - mean;
        info += a.transpose() * w * a;
        rhs += a.transpose() * w * s.eps[i];
    }
    // Directions no frame motion sees carry nothing: a tiny ridge keeps the solve finite.
    let delta = (info + Matrix6::identity() * (info.trace() * 1e-9))
        .try_inverse()
        .map_or_else(Vector6::zeros, |inv| inv * rhs);
    let dof = (3 * kept.len()).saturating_sub(3).max(1) as f64;
    let part = |k: usize, floor: f64| -> f64 {
        let (mut sq, mut var) = (0.0, 0.0);
        for (m, &i) in ms.iter().zip(kept) {
            let e = s.eps[i] - (m - mean) * delta;
            for d in k..k + 3 {
                sq += e[d].powi(2);
                var += s.var[i][d];
            }
        }
        ((sq - var) / dof).max(floor * floor).sqrt()
    };
    (part(0, floor_r), part(3, floor_t))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{DepthImage, Intrinsics};
    use crate::geometry::Rng;
    use nalgebra::Point3;

    /// A corner of a room (floor z = 0, walls x = 1.2 and y = 0.5, metres) seen from `t_base_cam`.
    fn render(intr: &Intrinsics, t_base_cam: &Isometry3<f64>) -> DepthImage {
        let (w, h) = (intr.width, intr.height);
        let mut img = DepthImage::zeros(w, h);
        let o = t_base_cam.translation.vector;
        for v in 0..h {
            for u in 0..w {
                let d = intr.deproject([u as f64, v as f64], 1.0);
                let ray = t_base_cam.rotation * Vector3::new(d[0], d[1], d[2]);
                let mut best = f64::INFINITY;
                for (axis, at) in [(2, 0.0), (0, 1.2), (1, 0.5)] {
                    if ray[axis].abs() < 1e-9 {
                        continue;
                    }
                    let t = (at - o[axis]) / ray[axis];
                    let p = o + ray * t;
                    let inside = p.x <= 1.2 + 1e-9 && p.y <= 0.5 + 1e-9 && p.z >= -1e-9;
                    if t > 0.0 && inside && t < best {
                        best = t;
                    }
                }
                if best.is_finite() {
                    // Depth along the optical axis, 0.1 mm units.
                    img.data[(v * w + u) as usize] = (best * 1e4).round() as u16;
                }
            }
        }
        img
    }

    /// Cameras round the corner, looking at it from about a metre.
    fn cameras(n: usize) -> Vec<Isometry3<f64>> {
        let target = Point3::new(1.0, 0.3, 0.1);
        (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * 1.2 - 0.6;
                let eye = Point3::new(
                    0.2 + 0.15 * a.cos(),
                    -0.2 + 0.5 * a,
                    0.7 + 0.1 * (2.0 * a).sin(),
                );
                // Camera z toward the target, y roughly down.
                let z = (target - eye).normalize();
                let x = z.cross(&Vector3::z()).normalize();
                let y = z.cross(&x);
                let r = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
                Isometry3::from_parts(
                    Translation3::from(eye.coords),
                    UnitQuaternion::from_rotation_matrix(&r),
                )
            })
            .collect()
    }

    /// The robot with `poses` as flange poses (hand-eye identity) and the views fused from the true
    /// cameras' depth under those poses.
    fn cell(truth: &[Isometry3<f64>], poses: &[Isometry3<f64>]) -> (CellRobot, Vec<DepthView>) {
        let mut intr = Intrinsics::pinhole(160, 120, 120.0, 120.0, 79.5, 59.5);
        intr.depth_scale = 1e-4;
        let robot = CellRobot::for_tests("arm", intr.clone(), Isometry3::identity(), poses);
        let views = truth
            .iter()
            .zip(poses)
            .map(|(t, p)| DepthView::new(&render(&intr, t), &intr, p, 4))
            .collect();
        (robot, views)
    }

    /// RMS over frame pairs of the relative poses' error, millimetres at the scene (rotation at 1 m).
    fn pair_error(a: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
        let mut sum = 0.0;
        let mut k = 0;
        for i in 0..a.len() {
            for j in (i + 1)..a.len() {
                let e = (a[i].inverse() * a[j]) * (truth[i].inverse() * truth[j]).inverse();
                sum += (e.translation.vector.norm() + e.rotation.angle()).powi(2);
                k += 1;
            }
        }
        (sum / k as f64).sqrt() * 1e3
    }

    /// `truth` with each pose moved by seeded normal noise of 1-σ `sigma_m` (metres) and `sigma_deg`
    /// (degrees) per axis.
    fn scattered(
        truth: &[Isometry3<f64>],
        seed: u64,
        sigma_m: f64,
        sigma_deg: f64,
    ) -> Vec<Isometry3<f64>> {
        let mut rng = Rng::new(seed);
        truth
            .iter()
            .map(|t| {
                let mut g = || rng.normal();
                let dt = Vector3::new(g(), g(), g()) * sigma_m;
                let dr = Vector3::new(g(), g(), g()) * sigma_deg.to_radians();
                Isometry3::from_parts(
                    Translation3::from(t.translation.vector + dt),
                    UnitQuaternion::from_scaled_axis(dr) * t.rotation,
                )
            })
            .collect()
    }

    #[test]
    fn scattered_poses_are_moved_to_agree() {
        let truth = cameras(8);
        let noisy = scattered(&truth, 7, 1.5e-3, 0.1);
        let (robot, views) = cell(&truth, &noisy);
        let s = estimate_pose_scatter(&robot, &views, &PoseScatterConfig::default()).unwrap();
        assert!(s.estimated && s.applied, "{s:?}");
        assert!(s.outliers.is_empty(), "{s:?}");
        let moved = s.corrected(&robot);
        let fixed: Vec<Isometry3<f64>> = moved.frames.iter().map(|f| f.t_base_ee).collect();
        let (before, after) = (pair_error(&noisy, &truth), pair_error(&fixed, &truth));
        assert!(after < 0.25 * before, "{before} mm -> {after} mm");
        // The scatter found is the one put in, within a factor of two, and widens the pose 1-σ.
        assert!(s.scatter_mm > 0.75 && s.scatter_mm < 3.0, "{s:?}");
        assert!(moved.uncertainty.pose_translation_m >= s.scatter_mm * 1e-3 - 1e-12);
    }

    #[test]
    fn the_sample_spreads_over_the_normals() {
        use crate::calibration::consistency::SmoothDepth;
        use crate::calibration::handeye::depth::residuals::{
            frame_points, frame_points_by_normals,
        };
        let truth = cameras(3);
        let (robot, views) = cell(&truth, &truth);
        let cfg = ConsistencyConfig {
            sample_points: 90,
            block: 4,
            ..ConsistencyConfig::default()
        };
        let depths: Vec<SmoothDepth> = views.iter().map(|v| SmoothDepth::new(v, &cfg)).collect();
        // Samples per plane of the corner (floor, wall x = 1.2, wall y = 0.5), by the normal in the base.
        let per_plane = |f: &FramePoints, cam: &Isometry3<f64>| -> [usize; 3] {
            let mut c = [0; 3];
            for n in &f.normals {
                let n = cam.rotation * n;
                c[n.iamax()] += 1;
            }
            c
        };
        let uniform = frame_points(&depths, &robot.intrinsics);
        let spread = frame_points_by_normals(&depths, &robot.intrinsics, 90, 2);
        assert_eq!(
            spread.iter().map(|f| f.points.clone()).collect::<Vec<_>>(),
            frame_points_by_normals(&depths, &robot.intrinsics, 90, 2)
                .iter()
                .map(|f| f.points.clone())
                .collect::<Vec<_>>(),
            "deterministic"
        );
        let mut rarest_before = usize::MAX;
        let mut rarest_after = usize::MAX;
        for (k, v) in views.iter().enumerate() {
            let cam = v.t_cam_base.inverse();
            assert_eq!(spread[k].points.len(), 90);
            let (a, b) = (per_plane(&uniform[k], &cam), per_plane(&spread[k], &cam));
            // Every plane the view sees keeps a share near a third (the octants split a plane's normals
            // where they straddle an axis of the camera), and none is left out.
            let seen: Vec<usize> = (0..3).filter(|&p| a[p] > 0).collect();
            for &p in &seen {
                assert!(b[p] >= 90 / (2 * seen.len()), "view {k}: {a:?} -> {b:?}");
            }
            rarest_before = rarest_before.min(seen.iter().map(|&p| a[p]).min().unwrap());
            rarest_after = rarest_after.min(seen.iter().map(|&p| b[p]).min().unwrap());
        }
        assert!(
            rarest_after > rarest_before,
            "{rarest_before} -> {rarest_after}"
        );
    }

    /// The hand-eye fit's sensitivity to each frame's pose against finite differences of its gradient
    /// (exact depth: the residuals are about zero, so the gradient moves by `C_k ε` alone).
    #[test]
    fn pose_sensitivity_matches_finite_differences() {
        use crate::calibration::handeye::depth::residuals::{total, Problem};
        let truth = cameras(5);
        let (robot, views) = cell(&truth, &truth);
        let cfg = ConsistencyConfig {
            sample_points: 150,
            block: 4,
            ..ConsistencyConfig::default()
        };
        let asn = Association {
            gate_m: 0.02,
            min_normal_cos: 45f64.to_radians().cos(),
            kernel: RobustKernel::Huber,
            kernel_sigmas: 2.0,
        };
        let x = Isometry3::identity();
        let centre = Vector3::new(0.9, 0.3, 0.2);
        let poses: Vec<Isometry3<f64>> = robot.frames.iter().map(|f| f.t_base_ee).collect();
        let problem = Problem::new(poses.clone(), &views, &robot.intrinsics, &cfg);
        let c = problem.pose_sensitivity(&x, &asn, &centre);
        assert_eq!(c.len(), 5);
        let scale = c.iter().map(|m| m.amax()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        // An error all frames share moves no relative pose.
        assert!(c.iter().sum::<Matrix6<f64>>().amax() < 1e-9 * scale);
        let gradient = |k: usize, d: &Vector6<f64>| {
            let mut p = poses.clone();
            p[k] = about(&centre, d) * p[k];
            let moved = Problem::new(p, &views, &robot.intrinsics, &cfg);
            total(&moved.sums(&x, &asn)).1
        };
        let h = 1e-6;
        for k in [0, 2, 4] {
            for d in 0..6 {
                let mut e = Vector6::zeros();
                e[d] = h;
                let fd = (gradient(k, &e) - gradient(k, &(-e))) / (2.0 * h);
                let err = (fd - c[k].column(d)).amax();
                assert!(
                    err < 0.02 * scale,
                    "frame {k}, axis {d}: {fd:?} vs {:?}",
                    c[k].column(d)
                );
            }
        }
    }

    #[test]
    fn exact_poses_are_left_alone() {
        let truth = cameras(8);
        let (robot, views) = cell(&truth, &truth);
        let s = estimate_pose_scatter(&robot, &views, &PoseScatterConfig::default()).unwrap();
        assert!(s.estimated && !s.applied, "{s:?}");
        assert!(s.displacement_mm < 0.1, "{s:?}");
        assert_eq!(s.corrected(&robot).frames[3].t_base_ee, truth[3]);
        assert_eq!(s.corrected(&robot).uncertainty, robot.uncertainty);
    }

    /// Stopping a gate once the steps are below the tolerance changes what is reported by less than the
    /// tolerance: on exact poses and on scattered ones, against every iteration run (tolerance 0).
    #[test]
    fn the_early_stop_changes_the_estimate_by_less_than_its_tolerance() {
        let truth = cameras(8);
        let noisy = scattered(&truth, 11, 1.0e-3, 0.0);
        for poses in [&truth, &noisy] {
            let (robot, views) = cell(&truth, poses);
            let every = PoseScatterConfig {
                step_tolerance_mm: 0.0,
                ..PoseScatterConfig::default()
            };
            let a = estimate_pose_scatter(&robot, &views, &every).unwrap();
            let b = estimate_pose_scatter(&robot, &views, &PoseScatterConfig::default()).unwrap();
            assert_eq!(
                (a.applied, a.widened),
                (b.applied, b.widened),
                "{a:?} {b:?}"
            );
            // Three steps at most left out per gate, each below a micrometre.
            assert!(
                (a.displacement_mm - b.displacement_mm).abs() < 0.006,
                "{a:?} {b:?}"
            );
            assert!((a.scatter_mm - b.scatter_mm).abs() < 0.006, "{a:?} {b:?}");
            for (x, y) in a.corrections.iter().zip(&b.corrections) {
                assert!((x.translation.vector - y.translation.vector).norm() < 6e-6);
            }
        }
    }

    #[test]
    fn too_few_frames_are_not_estimated() {
        let truth = cameras(3);
        let (robot, views) = cell(&truth, &truth);
        let s = estimate_pose_scatter(&robot, &views, &PoseScatterConfig::default()).unwrap();
        assert!(!s.estimated && !s.applied && s.note.is_some(), "{s:?}");
        assert_eq!(s.corrections.len(), 3);
    }

    #[test]
    fn config_ranges_are_checked() {
        let bad = PoseScatterConfig {
            gates_m: vec![],
            ..PoseScatterConfig::default()
        };
        assert!(bad.validate().is_err());
        let bad = PoseScatterConfig {
            prior_mm: 0.0,
            ..PoseScatterConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("pose_scatter.prior_mm"));
        let bad = PoseScatterConfig {
            step_tolerance_mm: -1e-3,
            ..PoseScatterConfig::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("pose_scatter.step_tolerance_mm"));
        PoseScatterConfig::default().validate().unwrap();
    }
}
