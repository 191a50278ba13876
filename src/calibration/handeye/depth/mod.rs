//! Hand-eye from depth: the `T_ee_cam` that makes one robot's depth frames agree.
//!
//! Each frame, put into the robot's base with `T_base_ee_i · T_ee_cam`, must describe one static scene.
//! Every frame's sampled surface points (the consistency check's sample of smooth depth blocks,
//! [`crate::calibration::consistency`]) are moved into every other camera and compared with the surface that
//! camera saw there: projective association, point-to-plane residual, normals oriented toward the camera
//! that saw them, and a pair counted only when both frames see the surface from the same side (the
//! side-of-surface rule). All frames are registered at once with the hand-eye as the only unknown (in the
//! spirit of RegHEC), by Gauss-Newton on the six parameters of a correction `T_ee_cam' = T_ee_cam · exp(δ)`
//! (rotation vector and translation in the camera frame) with a Huber kernel on residuals whitened by the
//! depth noise, coarse to fine over shrinking association gates.
//!
//! What the poses cannot see is not solved: the step is taken only in the directions the normal equations
//! constrain (eigenvalues above a relative floor), the others keep the initial value; and when the
//! covariance leaves a direction weak (1-σ above the limits), the solve is run again from the cell's
//! hand-eye with that direction frozen, so that a weak direction keeps the cell's value instead of
//! absorbing pose errors (centimetre-accurate poses otherwise drag the translation by centimetres). The covariance is
//! the mean of two estimates of the same variance, `k·s²·H⁻¹` (`s²` the robust variance factor, `k` the tests
//! per sampled point: each point is tested against many frames, which are not independent measurements)
//! and the frame-clustered sandwich `H⁻¹ (Σᵢ gᵢgᵢᵀ) H⁻¹` (the frames' own scatter, which also catches
//! per-frame systematic errors such as pose repeatability), plus a floor. Each of the six
//! parameters is `observable`, `weak` or `unobservable` by its 1-σ; the weak directions of the covariance are
//! named in words, with the flange motion that explains them (no rotation: the translation is free; one
//! rotation axis: the translation along it is free).

pub mod check;
pub mod joint;
pub mod observe;
pub mod plan;
pub(crate) mod residuals;

use crate::calibration::consistency::ConsistencyConfig;
use crate::camera::DepthView;
use crate::cell::CellRobot;
use crate::error::{Error, Result};
use crate::registration::RobustKernel;
use crate::stats::median;
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use observe::{
    direction_words, directions, flange_motion, DofObservability, FlangeMotion, WeakDirection,
};
use rayon::prelude::*;
use residuals::{total, Association, FrameSums, Problem};
use serde::{Deserialize, Serialize};
use std::sync::Mutex;

/// Settings of [`refine_hand_eye_from_depth`]. Lengths in metres, angles in degrees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandEyeDepthConfig {
    /// Depth blocks sampled per frame (default 1200).
    pub sample_points: usize,
    /// Block size of the depth views, pixels (default 4).
    pub block: u32,
    /// Depth noise `σ(z) = noise_a_m + noise_b_per_m · z²`, constant part, metres (default 0.0005).
    pub noise_a_m: f64,
    /// Quadratic part of the depth noise, 1/metre (default 0.0022).
    pub noise_b_per_m: f64,
    /// Association gates, coarse to fine, metres: point-to-plane residuals beyond the gate are not counted
    /// (default `[0.04, 0.015, 0.008]`). The first one is also the cap of the per-frame residuals.
    pub gates_m: Vec<f64>,
    /// Gauss-Newton iterations per gate at most (default 12).
    pub max_iterations: usize,
    /// A gate's iterations end once a step turns the hand-eye by less than this, degrees (default 0.001) ...
    pub step_tolerance_deg: f64,
    /// ... and moves it by less than this, millimetres (default 0.01).
    pub step_tolerance_mm: f64,
    /// Robust kernel (default Huber) ...
    pub kernel: RobustKernel,
    /// ... at this many depth-noise σ of the pair (default 2).
    pub kernel_sigmas: f64,
    /// Side-of-surface rule: the two frames' normals of a pair must agree within this, degrees (default 45).
    pub max_normal_angle_deg: f64,
    /// A parameter is weak when its rotation 1-σ exceeds this, degrees (default 0.05) ...
    pub weak_sigma_deg: f64,
    /// ... or its translation 1-σ exceeds this, millimetres (default 0.5).
    pub weak_sigma_mm: f64,
    /// A direction the poses leave free: 1-σ above this, millimetres (rotations at the characteristic range)
    /// (default 5).
    pub unobservable_sigma_mm: f64,
    /// Floor added to each rotation variance, degrees 1-σ (default 0.003).
    pub floor_deg: f64,
    /// Floor added to each translation variance, millimetres 1-σ (default 0.02).
    pub floor_mm: f64,
    /// Directions whose eigenvalue is below this fraction of the largest are not stepped (default 1e-7).
    pub null_ratio: f64,
    /// Fewest frames (default 3).
    pub min_frames: usize,
    /// A change larger than this is not trusted, degrees (default 10) ...
    pub max_change_deg: f64,
    /// ... or millimetres (default 50).
    pub max_change_mm: f64,
}

impl Default for HandEyeDepthConfig {
    fn default() -> Self {
        HandEyeDepthConfig {
            sample_points: 1200,
            block: 4,
            noise_a_m: 0.0005,
            noise_b_per_m: 0.0022,
            gates_m: vec![0.04, 0.015, 0.008],
            max_iterations: 12,
            step_tolerance_deg: 0.001,
            step_tolerance_mm: 0.01,
            kernel: RobustKernel::Huber,
            kernel_sigmas: 2.0,
            max_normal_angle_deg: 45.0,
            weak_sigma_deg: 0.05,
            weak_sigma_mm: 0.5,
            unobservable_sigma_mm: 5.0,
            floor_deg: 0.003,
            floor_mm: 0.02,
            null_ratio: 1e-7,
            min_frames: 3,
            max_change_deg: 10.0,
            max_change_mm: 50.0,
        }
    }
}

impl HandEyeDepthConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("hand_eye_depth.{field}"),
                msg,
            })
        };
        if self.sample_points == 0 {
            return bad("sample_points", "must be at least 1".into());
        }
        if self.block == 0 {
            return bad("block", "must be at least 1 pixel".into());
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "must be at least 1".into());
        }
        for (field, v) in [
            ("step_tolerance_deg", self.step_tolerance_deg),
            ("step_tolerance_mm", self.step_tolerance_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("must be positive, found {v}"));
            }
        }
        if self.min_frames < 2 {
            return bad("min_frames", "must be at least 2".into());
        }
        if self.gates_m.is_empty() || self.gates_m.iter().any(|g| !(g.is_finite() && *g > 0.0)) {
            return bad(
                "gates_m",
                format!(
                    "must be a non-empty list of finite numbers > 0, found {:?}",
                    self.gates_m
                ),
            );
        }
        for (name, v) in [
            ("noise_a_m", self.noise_a_m),
            ("noise_b_per_m", self.noise_b_per_m),
            ("floor_deg", self.floor_deg),
            ("floor_mm", self.floor_mm),
            ("null_ratio", self.null_ratio),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, format!("must be a finite number ≥ 0, found {v}"));
            }
        }
        for (name, v) in [
            ("kernel_sigmas", self.kernel_sigmas),
            ("weak_sigma_deg", self.weak_sigma_deg),
            ("weak_sigma_mm", self.weak_sigma_mm),
            ("unobservable_sigma_mm", self.unobservable_sigma_mm),
            ("max_change_deg", self.max_change_deg),
            ("max_change_mm", self.max_change_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(name, format!("must be a finite number > 0, found {v}"));
            }
        }
        if !(self.max_normal_angle_deg > 0.0 && self.max_normal_angle_deg <= 90.0) {
            return bad(
                "max_normal_angle_deg",
                format!(
                    "must be within (0, 90], found {}",
                    self.max_normal_angle_deg
                ),
            );
        }
        Ok(())
    }

    /// [`Self::validate`] for the configuration nested at `prefix` in its parent's (the error then names
    /// e.g. `refine_hand_eye.depth.gates_m`).
    pub fn validate_within(&self, prefix: &str) -> Result<()> {
        self.validate().map_err(|e| match e {
            Error::Config { field, msg } => Error::Config {
                field: format!("{prefix}.{}", field.trim_start_matches("hand_eye_depth.")),
                msg,
            },
            e => e,
        })
    }

    pub(crate) fn consistency(&self) -> ConsistencyConfig {
        ConsistencyConfig {
            sample_points: self.sample_points,
            block: self.block,
            noise_a_m: self.noise_a_m,
            noise_b_per_m: self.noise_b_per_m,
            ..ConsistencyConfig::default()
        }
    }
}

/// One frame's agreement with the robot's other frames, before and after the refinement.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameDepthResidual {
    /// Frame id (the pose file's `frame` column).
    pub id: String,
    /// Median absolute point-to-plane residual against the other frames with the initial hand-eye, metres
    /// (tests within the first gate).
    pub before_m: f64,
    /// The same with the refined hand-eye, metres.
    pub after_m: f64,
    /// Tests behind `before_m`.
    pub tests_before: usize,
    /// Tests behind `after_m`.
    pub tests_after: usize,
}

/// The hand-eye of one robot refined from its depth frames.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HandEyeDepthResult {
    /// The robot's name.
    pub robot: String,
    /// Frames used.
    pub frames_used: usize,
    /// The hand-eye it started from (the cell's), `T_ee_cam`, metres.
    #[serde(skip)]
    pub initial: Isometry3<f64>,
    /// The refined hand-eye `T_ee_cam`, metres.
    #[serde(skip)]
    pub t_ee_cam: Isometry3<f64>,
    /// The change `initial⁻¹ · refined` (in the camera frame), metres.
    #[serde(skip)]
    pub change: Isometry3<f64>,
    /// Covariance of the change `[rx, ry, rz (rad), tx, ty, tz (m)]`, camera frame.
    #[serde(skip)]
    pub covariance: Matrix6<f64>,
    /// Each of the six parameters (camera frame): its 1-σ and whether the poses make it observable.
    pub dofs: Vec<DofObservability>,
    /// The directions the frames constrain poorly (weak or unobservable), in words.
    pub weak_directions: Vec<WeakDirection>,
    /// How the flange moved between the frames.
    pub flange_motion: FlangeMotion,
    /// The range at which rotations are compared with translations, metres (median sample depth).
    pub characteristic_range_m: f64,
    /// Flange poses to capture so that the weak directions get constrained (empty when none is weak).
    pub suggested_poses: Vec<plan::SuggestedPose>,
    /// Per frame, in pose-file order.
    pub frames: Vec<FrameDepthResidual>,
    /// Median over the frames of `before_m`, metres.
    pub median_before_m: f64,
    /// Median over the frames of `after_m`, metres.
    pub median_after_m: f64,
    /// Tests (point × other frame) at the finest gate.
    pub tests: usize,
    /// Tests refused by the side-of-surface rule at the finest gate.
    pub wrong_side_tests: usize,
    /// Gauss-Newton iterations over all gates.
    pub iterations: usize,
    /// The last step was below 0.01 mm and 0.001°.
    pub converged: bool,
    /// True when every check passed.
    pub trusted: bool,
    /// Each failed check, in words.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
}

fn exp_twist(d: &Vector6<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(d[3], d[4], d[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])),
    )
}

/// The scaled normal equations' eigen-decomposition solve: directions below `null_ratio` of the largest
/// eigenvalue are left out (not stepped, infinite variance). Returns the step and `H⁺` (unscaled).
fn solve(
    h: &Matrix6<f64>,
    g: &Vector6<f64>,
    l: f64,
    null_ratio: f64,
) -> (Vector6<f64>, Matrix6<f64>, Vec<bool>) {
    let s = Matrix6::from_diagonal(&Vector6::new(1.0 / l, 1.0 / l, 1.0 / l, 1.0, 1.0, 1.0));
    let hs = s * h * s;
    let eig = hs.symmetric_eigen();
    let lmax = eig.eigenvalues.max().max(0.0);
    let mut pinv = Matrix6::zeros();
    let mut null = vec![false; 6];
    for (k, is_null) in null.iter_mut().enumerate() {
        let lam = eig.eigenvalues[k];
        let v = eig.eigenvectors.column(k);
        if lam > null_ratio * lmax && lam > 0.0 {
            pinv += v * v.transpose() / lam;
        } else {
            *is_null = true;
        }
    }
    let step = -(s * pinv * s * g);
    (step, s * pinv * s, null)
}

/// The per-frame residual medians (metres) and test counts.
pub(crate) fn frame_stats(sums: &mut [FrameSums]) -> Vec<(f64, usize)> {
    sums.iter_mut()
        .map(|s| {
            let n = s.abs.len();
            (crate::stats::quantile_in_place_f32(&mut s.abs, 0.5), n)
        })
        .collect()
}

/// The coarse-to-fine solve and the covariance over one problem.
struct Solver<'a> {
    problem: &'a Problem<'a>,
    cfg: &'a HandEyeDepthConfig,
    /// Characteristic range, metres.
    l: f64,
    assoc: &'a dyn Fn(f64) -> Association,
    /// Evaluations by (hand-eye, gate).
    memo: Memo<(Isometry3<f64>, f64), Vec<FrameSums>>,
}

/// Evaluations of a costly function kept by key: the first one (in the refinements, the starting point
/// at the first gate, which the report's "before" and each solve's first step ask for) and the last
/// `cap − 1` (the covariance and the report's "after" ask for the solution's twice).
pub(crate) struct Memo<K, V> {
    cap: usize,
    entries: Mutex<Vec<(K, V)>>,
}

impl<K: PartialEq, V: Clone> Memo<K, V> {
    /// An empty memo keeping at most `cap` (at least 2) evaluations.
    pub(crate) fn new(cap: usize) -> Self {
        Memo {
            cap: cap.max(2),
            entries: Mutex::new(Vec::new()),
        }
    }

    /// The value kept for `key`, else `eval()` (then kept).
    pub(crate) fn get_or(&self, key: K, eval: impl FnOnce() -> V) -> V {
        if let Some(v) = self.get(&key) {
            return v;
        }
        // Evaluated without the lock held (the evaluation runs in parallel).
        let v = eval();
        self.put(key, v.clone());
        v
    }

    /// The value kept for `key`.
    pub(crate) fn get(&self, key: &K) -> Option<V> {
        let entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        entries
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.clone())
    }

    /// Keeps `v` for `key` (dropping the second-oldest entry when full: the first is the start's).
    pub(crate) fn put(&self, key: K, v: V) {
        let mut entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        if entries.len() == self.cap {
            entries.remove(1);
        }
        entries.push((key, v));
    }
}

impl Solver<'_> {
    /// The per-frame sums at hand-eye `x` with the association of `gate` (metres), through the memo.
    fn sums(&self, x: &Isometry3<f64>, gate: f64) -> Vec<FrameSums> {
        self.memo
            .get_or((*x, gate), || self.problem.sums(x, &(self.assoc)(gate)))
    }

    /// The sums at `x` with the last gate, which the covariance uses. Evaluated (when not kept) in one
    /// run of the tests together with the first gate's, which the residuals after the fit are reported
    /// with: the fit ends where the covariance is taken.
    fn final_sums(&self, x: &Isometry3<f64>) -> Vec<FrameSums> {
        let gates = &self.cfg.gates_m;
        let (first, last) = (gates[0], *gates.last().unwrap_or(&0.01));
        if let Some(v) = self.memo.get(&(*x, last)) {
            return v;
        }
        if first == last || self.memo.get(&(*x, first)).is_some() {
            return self.sums(x, last);
        }
        let wide = (self.assoc)(first.max(last));
        let mut both = self.problem.sums_at_gates(x, &wide, &[first, last]);
        let at_last = both.pop().expect("two gates");
        self.memo.put((*x, first), both.pop().expect("two gates"));
        self.memo.put((*x, last), at_last.clone());
        at_last
    }

    fn scale(&self) -> Matrix6<f64> {
        let l = self.l;
        Matrix6::from_diagonal(&Vector6::new(1.0 / l, 1.0 / l, 1.0 / l, 1.0, 1.0, 1.0))
    }

    /// Gauss-Newton over the gates from `x0`, never stepping along `frozen` (unit vectors in scaled
    /// units). Returns the hand-eye, the iterations and whether the last step was negligible.
    fn levels(
        &self,
        x0: &Isometry3<f64>,
        frozen: &[Vector6<f64>],
    ) -> (Isometry3<f64>, usize, bool) {
        let cfg = self.cfg;
        let s = self.scale();
        let mut p = Matrix6::identity();
        for f in frozen {
            p -= f * f.transpose();
        }
        // Scaled parameters are S⁻¹·δ: in unscaled ones the projection is S·P·S⁻¹.
        let s_inv = s.try_inverse().unwrap_or_else(Matrix6::identity);
        let (mut x, mut iterations, mut converged) = (*x0, 0, false);
        for &gate in &cfg.gates_m {
            for _ in 0..cfg.max_iterations {
                iterations += 1;
                let (h, g, _, _, tests) = total(&self.sums(&x, gate));
                if tests < 6 {
                    break;
                }
                let (h, g) = if frozen.is_empty() {
                    (h, g)
                } else {
                    let m = s * p * s_inv; // maps a twist onto the free subspace
                    (m.transpose() * h * m, m.transpose() * g)
                };
                let (mut step, _, _) = solve(&h, &g, self.l, cfg.null_ratio);
                if !frozen.is_empty() {
                    step = s * p * s_inv * step;
                }
                // At most a third of the gate per step (rotations at the characteristic range).
                let size = (Vector3::new(step[0], step[1], step[2]).norm() * self.l)
                    .max(Vector3::new(step[3], step[4], step[5]).norm());
                if size > gate / 3.0 {
                    step *= gate / 3.0 / size;
                }
                x *= exp_twist(&step);
                converged = Vector3::new(step[0], step[1], step[2]).norm()
                    < cfg.step_tolerance_deg.to_radians()
                    && Vector3::new(step[3], step[4], step[5]).norm()
                        < cfg.step_tolerance_mm * 1e-3;
                if converged {
                    break;
                }
            }
        }
        (x, iterations, converged)
    }

    /// [`Self::levels`] from `x0`, then again from `x0` with the directions the covariance leaves weak
    /// frozen (they keep the cell's value instead of absorbing pose errors). Returns the hand-eye, the
    /// iterations, whether the last step was negligible and the covariance.
    fn solve_freezing_weak(
        &self,
        x0: &Isometry3<f64>,
    ) -> (Isometry3<f64>, usize, bool, Matrix6<f64>) {
        let (cfg, l) = (self.cfg, self.l);
        let (mut x, mut iterations, mut converged) = self.levels(x0, &[]);
        let mut cov = self.covariance(&x).0;
        let weak_limit = (cfg.weak_sigma_mm * 1e-3).min(cfg.weak_sigma_deg.to_radians() * l);
        let frozen: Vec<Vector6<f64>> = directions(&cov, l)
            .into_iter()
            .filter(|(_, sd)| *sd > weak_limit)
            .map(|(v, _)| v)
            .collect();
        if !frozen.is_empty() {
            let (x2, it2, c2) = self.levels(x0, &frozen);
            (x, converged) = (x2, c2);
            iterations += it2;
            cov = self.covariance(&x).0;
        }
        (x, iterations, converged, cov)
    }

    /// The covariance of the hand-eye change at `x` that independent flange pose errors of 1-σ `sr`
    /// (radians) and `st` (metres) per axis, about the scene's centre, cause through the finest gate's
    /// normal equations (see [`refine_hand_eye_under_scatter`]).
    fn pose_noise_covariance(&self, x: &Isometry3<f64>, sr: f64, st: f64) -> Matrix6<f64> {
        let cfg = self.cfg;
        let gate = *cfg.gates_m.last().unwrap_or(&0.01);
        let (h, _, _, _, _) = total(&self.sums(x, gate));
        let (_, h_pinv, _) = solve(&h, &Vector6::zeros(), self.l, cfg.null_ratio);
        let p = self.problem;
        let (sum, count) = p
            .points
            .iter()
            .zip(&p.t_base_ee)
            .flat_map(|(f, e)| {
                let c = e * x;
                f.points
                    .iter()
                    .map(move |q| (c * nalgebra::Point3::from(*q)).coords)
            })
            .fold((Vector3::zeros(), 0usize), |(s, n), q| (s + q, n + 1));
        let centre = sum / count.max(1) as f64;
        let sens = p.pose_sensitivity(x, &(self.assoc)(gate), &centre);
        let e = crate::calibration::uncertainty::twist_covariance(sr, st);
        let meat: Matrix6<f64> = sens.iter().map(|c| c * e * c.transpose()).sum();
        h_pinv * meat * h_pinv.transpose()
    }

    /// The covariance of the hand-eye at `x` (see the module documentation), the tests and refused tests
    /// at the finest gate, and the frames with tests.
    fn covariance(&self, x: &Isometry3<f64>) -> (Matrix6<f64>, usize, usize, usize) {
        let cfg = self.cfg;
        let sums = self.final_sums(x);
        let (h, _, chi2, weight, tests) = total(&sums);
        let wrong_side: usize = sums.iter().map(|s| s.wrong_side).sum();
        let (_, h_pinv, _) = solve(&h, &Vector6::zeros(), self.l, cfg.null_ratio);
        let samples: usize = sums.iter().map(|s| s.samples_used).sum();
        let k = if samples > 0 {
            (tests as f64 / samples as f64).max(1.0)
        } else {
            1.0
        };
        let s2 = if weight > 6.0 {
            chi2 / (weight - 6.0)
        } else {
            1.0
        };
        let mut meat = Matrix6::zeros();
        let frames = sums.iter().filter(|s| !s.abs.is_empty()).count();
        for s in &sums {
            meat += s.g * s.g.transpose();
        }
        let cluster_scale = if frames > 1 {
            frames as f64 / (frames - 1) as f64
        } else {
            1.0
        };
        // Two estimates of the same variance, averaged: the model's (noise scale from the residuals,
        // inflated by the tests per point) and the frames' own scatter (catches per-frame systematic
        // errors).
        let mut cov = (h_pinv * (k * s2) + h_pinv * meat * h_pinv * cluster_scale) * 0.5;
        for d in 0..3 {
            cov[(d, d)] += cfg.floor_deg.to_radians().powi(2);
            cov[(d + 3, d + 3)] += (cfg.floor_mm * 1e-3).powi(2);
        }
        // Directions left out of the solve: unobservable, 1 m 1-σ (in scaled units).
        let s = self.scale();
        let eig = (s * h * s).symmetric_eigen();
        let lmax = eig.eigenvalues.max().max(0.0);
        for kk in 0..6 {
            if !(eig.eigenvalues[kk] > cfg.null_ratio * lmax && eig.eigenvalues[kk] > 0.0) {
                let v = s * eig.eigenvectors.column(kk);
                cov += v * v.transpose();
            }
        }
        (cov, tests, wrong_side, frames)
    }
}

/// Each robot's depth views (one per frame) from its depth images.
pub(crate) fn load_views(robot: &CellRobot, cfg: &HandEyeDepthConfig) -> Result<Vec<DepthView>> {
    (0..robot.frames.len())
        .into_par_iter()
        .map(|i| {
            robot
                .load_depth(i)
                .map(|img| DepthView::new(&img, &robot.intrinsics, &robot.t_base_cam(i), cfg.block))
        })
        .collect()
}

/// The range at which rotations are compared with translations: the median sample depth, metres (at least
/// 5 cm; 0.5 m without samples).
pub(crate) fn characteristic_range(points: &[residuals::FramePoints]) -> f64 {
    let depths: Vec<f64> = points
        .iter()
        .flat_map(|f| f.points.iter().map(|p| p.z))
        .collect();
    if depths.is_empty() {
        0.5
    } else {
        median(&depths)
    }
    .max(0.05)
}

/// The association settings at one gate.
pub(crate) fn association(cfg: &HandEyeDepthConfig, gate: f64) -> Association {
    Association {
        gate_m: gate,
        min_normal_cos: cfg.max_normal_angle_deg.to_radians().cos(),
        kernel: cfg.kernel,
        kernel_sigmas: cfg.kernel_sigmas,
    }
}

/// Each of the six hand-eye parameters' 1-σ and status under `cov` (camera frame), and the weak
/// directions in words.
pub(crate) fn observability(
    cov: &Matrix6<f64>,
    l: f64,
    cfg: &HandEyeDepthConfig,
) -> (Vec<DofObservability>, Vec<WeakDirection>) {
    let names = ["rx", "ry", "rz", "tx", "ty", "tz"];
    let dofs: Vec<DofObservability> = (0..6)
        .map(|d| {
            let sd = cov[(d, d)].max(0.0).sqrt();
            let (sigma, weak, mm) = if d < 3 {
                (sd.to_degrees(), cfg.weak_sigma_deg, sd * l * 1e3)
            } else {
                (sd * 1e3, cfg.weak_sigma_mm, sd * 1e3)
            };
            let status = if mm > cfg.unobservable_sigma_mm {
                "unobservable"
            } else if sigma > weak {
                "weak"
            } else {
                "observable"
            };
            DofObservability {
                dof: names[d],
                sigma,
                status,
            }
        })
        .collect();
    let weak_directions: Vec<WeakDirection> = directions(cov, l)
        .into_iter()
        .filter(|(_, sd)| *sd > (cfg.weak_sigma_mm * 1e-3).min(cfg.weak_sigma_deg.to_radians() * l))
        .map(|(v, sd)| WeakDirection {
            description: direction_words(&v),
            vector: [v[0], v[1], v[2], v[3], v[4], v[5]],
            sigma_mm: sd * 1e3,
            status: if sd * 1e3 > cfg.unobservable_sigma_mm {
                "unobservable"
            } else {
                "weak"
            },
        })
        .collect();
    (dofs, weak_directions)
}

/// The per-frame residuals before and after (pose-file order) and their medians over the frames with
/// tests, metres.
pub(crate) fn frame_residuals(
    robot: &CellRobot,
    before: &[(f64, usize)],
    after: &[(f64, usize)],
) -> (Vec<FrameDepthResidual>, f64, f64) {
    let frames: Vec<FrameDepthResidual> = robot
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| FrameDepthResidual {
            id: f.id.clone(),
            before_m: before[i].0,
            after_m: after[i].0,
            tests_before: before[i].1,
            tests_after: after[i].1,
        })
        .collect();
    let judged = |v: &dyn Fn(&FrameDepthResidual) -> (f64, usize)| -> f64 {
        let m: Vec<f64> = frames
            .iter()
            .map(v)
            .filter(|(_, n)| *n > 0)
            .map(|(m, _)| m)
            .collect();
        median(&m)
    };
    let median_before_m = judged(&|f| (f.before_m, f.tests_before));
    let median_after_m = judged(&|f| (f.after_m, f.tests_after));
    (frames, median_before_m, median_after_m)
}

/// The reason (and suggestion) when some of a robot's hand-eye parameters are not observable, with the
/// flange motion that explains it.
pub(crate) fn observability_reasons(
    robot: &str,
    dofs: &[DofObservability],
    weak_directions: &[WeakDirection],
    motion: &FlangeMotion,
    reasons: &mut Vec<String>,
    suggestions: &mut Vec<String>,
) {
    let motion_words = if motion.max_rotation_deg < 1.0 {
        format!(
            "the flange did not rotate between the frames (largest rotation {:.2}°): pure translations leave \
             the hand-eye translation free",
            motion.max_rotation_deg
        )
    } else if motion.axis_spread_deg < 5.0 {
        let a = motion.main_axis_ee;
        format!(
            "the flange only rotated about one axis ({:.2}, {:.2}, {:.2}) in the flange frame, i.e. {} (axis \
             spread {:.1}°): the translation along it is free",
            a[0],
            a[1],
            a[2],
            observe::axis_words(&Vector3::from(motion.main_axis_cam)),
            motion.axis_spread_deg
        )
    } else {
        String::new()
    };
    if dofs.iter().any(|d| d.status != "observable") {
        let list: Vec<String> = weak_directions
            .iter()
            .map(|w| {
                format!(
                    "{} is {} (1-σ {:.2} mm)",
                    w.description, w.status, w.sigma_mm
                )
            })
            .collect();
        reasons.push(format!(
            "robot {}: the poses do not determine the whole hand-eye: {}{}",
            robot,
            if list.is_empty() {
                "some parameters have a large 1-σ".to_string()
            } else {
                list.join("; ")
            },
            if motion_words.is_empty() {
                String::new()
            } else {
                format!(" — {motion_words}")
            }
        ));
        suggestions.push(
            "capture frames that rotate the flange by 20° or more about at least two different axes \
             (tilt it, not only turn it), all looking at the same part of the scene"
                .into(),
        );
    }
}

/// Refines `robot.t_ee_cam` so that all its depth frames agree (see the module documentation). `views` are
/// the robot's depth views (one per frame, e.g. a fused cloud's `views`); `None` reads the depth images.
/// Errors: a bad configuration, fewer than `min_frames` frames, an unreadable depth image (named). An
/// answer the poses do not support is returned untrusted with its reasons.
pub fn refine_hand_eye_from_depth(
    robot: &CellRobot,
    views: Option<&[DepthView]>,
    cfg: &HandEyeDepthConfig,
) -> Result<HandEyeDepthResult> {
    Ok(refine_hand_eye_under_scatter(robot, views, cfg, None)?.0)
}

/// [`refine_hand_eye_from_depth`], and with `scatter` (the flange poses' 1-σ per axis as a left increment
/// in the base frame about the scene's centre: rotation in radians, translation in metres) the covariance
/// of the hand-eye change that pose errors of that size cause in this fit: `H⁻¹ (Σ_k C_k Σ C_kᵀ) H⁻¹`
/// with each frame's sensitivity `C_k` ([`Problem::pose_sensitivity`]), the frames' errors independent.
/// An error all frames share moves no relative pose and changes nothing (the `C_k` sum to zero).
pub(crate) fn refine_hand_eye_under_scatter(
    robot: &CellRobot,
    views: Option<&[DepthView]>,
    cfg: &HandEyeDepthConfig,
    scatter: Option<(f64, f64)>,
) -> Result<(HandEyeDepthResult, Option<Matrix6<f64>>)> {
    cfg.validate()?;
    let n = robot.frames.len();
    if n < cfg.min_frames {
        return Err(Error::InvalidInput(format!(
            "robot {}: {n} frames, the hand-eye from depth needs at least {} (frames from different flange \
             orientations)",
            robot.name, cfg.min_frames
        )));
    }
    let ccfg = cfg.consistency();
    let built: Vec<DepthView>;
    let views: &[DepthView] = match views {
        Some(v) if v.len() == n => v,
        _ => {
            built = load_views(robot, cfg)?;
            &built
        }
    };
    let problem = Problem::new(
        robot.frames.iter().map(|f| f.t_base_ee).collect(),
        views,
        &robot.intrinsics,
        &ccfg,
    );
    let l = characteristic_range(&problem.points);
    let assoc = |gate: f64| association(cfg, gate);
    let x0 = robot.t_ee_cam;
    let solver = Solver {
        problem: &problem,
        cfg,
        l,
        assoc: &assoc,
        memo: Memo::new(3),
    };
    let before = frame_stats(&mut solver.sums(&x0, cfg.gates_m[0]));
    let (x, iterations, converged, cov) = solver.solve_freezing_weak(&x0);
    let (_, tests, wrong_side, frames_with_tests) = solver.covariance(&x);
    let after = frame_stats(&mut solver.sums(&x, cfg.gates_m[0]));

    let motion = flange_motion(&problem.t_base_ee, &x0);
    let (dofs, weak_directions) = observability(&cov, l, cfg);
    let (frames, median_before_m, median_after_m) = frame_residuals(robot, &before, &after);
    let change = x0.inverse() * x;

    let mut reasons = Vec::new();
    let mut suggestions = Vec::new();
    observability_reasons(
        &robot.name,
        &dofs,
        &weak_directions,
        &motion,
        &mut reasons,
        &mut suggestions,
    );
    if frames_with_tests < cfg.min_frames {
        reasons.push(format!(
            "robot {}: only {frames_with_tests} frames overlap the others",
            robot.name
        ));
        suggestions.push("capture frames that see a common part of the scene".into());
    }
    if !converged {
        reasons.push(format!(
            "robot {}: the refinement did not converge within {} iterations per gate",
            robot.name, cfg.max_iterations
        ));
    }
    let (angle, shift) = (
        change.rotation.angle().to_degrees(),
        change.translation.vector.norm() * 1e3,
    );
    if angle > cfg.max_change_deg || shift > cfg.max_change_mm {
        reasons.push(format!(
            "robot {}: the hand-eye moved {angle:.2}° / {shift:.1} mm, beyond {}° / {} mm",
            robot.name, cfg.max_change_deg, cfg.max_change_mm
        ));
        suggestions
            .push("start from a closer hand-eye (a board calibration, `handeye --images`)".into());
    }
    if median_after_m > median_before_m * 1.05 + 1e-5 {
        reasons.push(format!(
            "robot {}: the frames agree less after the refinement (median residual {:.2} -> {:.2} mm)",
            robot.name,
            median_before_m * 1e3,
            median_after_m * 1e3
        ));
    }
    let ids: Vec<String> = robot.frames.iter().map(|f| f.id.clone()).collect();
    let suggested_poses =
        plan::suggest_poses(&weak_directions, &motion, &problem.t_base_ee, &ids, &x0, l);
    let result = HandEyeDepthResult {
        robot: robot.name.clone(),
        frames_used: frames_with_tests,
        initial: x0,
        t_ee_cam: x,
        change,
        covariance: cov,
        dofs,
        weak_directions,
        suggested_poses,
        flange_motion: motion,
        characteristic_range_m: l,
        frames,
        median_before_m,
        median_after_m,
        tests,
        wrong_side_tests: wrong_side,
        iterations,
        converged,
        trusted: reasons.is_empty(),
        reasons,
        suggestions,
    };
    let under_scatter = scatter.map(|(sr, st)| solver.pose_noise_covariance(&x, sr, st));
    Ok((result, under_scatter))
}

#[cfg(test)]
mod tests {
    use super::Memo;
    use std::cell::Cell;

    /// The memo evaluates a key once while it is kept, keeps the first key for good and the last ones
    /// after it.
    #[test]
    fn memo_keeps_the_first_and_the_last_evaluations() {
        let memo: Memo<u32, u32> = Memo::new(3);
        let calls = Cell::new(0);
        let get = |k: u32| {
            memo.get_or(k, || {
                calls.set(calls.get() + 1);
                10 * k
            })
        };
        assert_eq!(get(1), 10);
        assert_eq!(get(1), 10);
        assert_eq!(calls.get(), 1);
        for k in 2..=5 {
            assert_eq!(get(k), 10 * k);
        }
        assert_eq!(calls.get(), 5);
        // Kept: 1 (the first), 4 and 5 (the last two).
        for k in [1, 4, 5] {
            assert_eq!(get(k), 10 * k);
        }
        assert_eq!(calls.get(), 5);
        assert_eq!(get(2), 20);
        assert_eq!(calls.get(), 6);
    }
}
