//! Both robots' hand-eyes and the base-to-base transform refined together from the depth frames.
//!
//! Eighteen parameters: a correction of each robot's hand-eye `T_ee_cam' = T_ee_cam · exp(δₖ)` (camera
//! frame, as in the per-robot refinement) and of the base-to-base transform `T_base1_base2' =
//! T_base1_base2 · exp(δ_B)` (base2 frame). The cost is each robot's own cross-frame point-to-plane terms
//! (the per-robot residuals, [`super::residuals`]) plus the cross-robot terms: every sampled point of a
//! robot-2 frame, mapped through `T_base1_base2` into every robot-1 camera, against the surface that camera
//! saw there, and the other way round (the same projective association, side-of-surface rule, Huber kernel
//! on whitened residuals and gates schedule). It starts from the per-robot refined hand-eyes and the
//! ordinary calibration's `T_base1_base2`.
//!
//! In the cross-robot terms only points where the surface is flat take part (`cross_max_bend_m`, in both
//! frames): the surfaces come from 4x4-pixel depth blocks, interpolated between block centres, which cut
//! the chord of a curved surface; the two robots see the objects from different sides, so on curved
//! surfaces the two chords lie on opposite sides of the true surface and pull `T_base1_base2` sideways
//! (measured: up to 5 mm on simulated cells without the rule, 0.04–0.7 mm with it; excluding only the
//! blocks near depth discontinuities, `cross_edge_blocks`, did not remove it).
//!
//! The covariance (18×18) is estimated as in the per-robot refinement (the mean of the model's and the
//! frame-clustered sandwich estimates, plus the floor), the directions it leaves weak are frozen and the
//! solve run again from the start. Each hand-eye's 6×6 block gives its observability in the per-robot
//! vocabulary; the base-to-base covariance is reported as a left increment in base1 (like calibrate's).

use super::observe::{DofObservability, WeakDirection};
use super::residuals::{skew, test_point, Association, FramePoints, Problem, Target};
use super::Memo;
use super::{
    association, characteristic_range, frame_residuals, frame_stats, load_views, observability,
    observability_reasons, FrameDepthResidual, HandEyeDepthConfig,
};
use crate::calibration::consistency::SmoothDepth;
use crate::cell::CellRobot;
use crate::error::{Error, Result};
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, RowVector6, SMatrix, SVector, Translation3,
    UnitQuaternion, Vector3,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Parameters of the joint problem: two hand-eyes and the base-to-base transform.
const N: usize = 18;

/// Settings of `calibrate --refine-hand-eye` (the `refine_hand_eye` section of calibrate's `--config`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineHandEyeConfig {
    /// After the per-robot refinements and the ordinary calibration, refine both hand-eyes and
    /// `T_base1_base2` together ([`refine_jointly`]) and report it (default true).
    pub joint: bool,
    /// The joint `T_base1_base2` (when trusted) replaces the ordinary calibration's (default false: it is
    /// reported beside it).
    pub adopt_joint_base: bool,
    /// Cross-robot terms use only points whose block and every block within this many blocks of it are
    /// smooth, in the point's own frame and where it lands in the other robot's frame (default 0: only the
    /// per-robot rule, the neighbouring blocks; 2 did not lower the base-to-base bias, measured).
    pub cross_edge_blocks: u32,
    /// Cross-robot terms use only points where the surface is flat: the centre of the block depths one
    /// block to each side bends away from their mean by at most this, metres (default 0.0004; 0 keeps
    /// curved surfaces too).
    pub cross_max_bend_m: f64,
    /// The settings of the per-robot refinements and of the joint one.
    pub depth: HandEyeDepthConfig,
}

impl Default for RefineHandEyeConfig {
    fn default() -> Self {
        RefineHandEyeConfig {
            joint: true,
            adopt_joint_base: false,
            cross_edge_blocks: 0,
            cross_max_bend_m: 0.0004,
            depth: HandEyeDepthConfig::default(),
        }
    }
}

impl RefineHandEyeConfig {
    /// Checks the ranges; the error names the field (`refine_hand_eye.depth.gates_m`).
    pub fn validate(&self) -> Result<()> {
        self.depth.validate_within("refine_hand_eye.depth")?;
        if !(self.cross_max_bend_m.is_finite() && self.cross_max_bend_m >= 0.0) {
            return Err(Error::Config {
                field: "refine_hand_eye.cross_max_bend_m".into(),
                msg: format!(
                    "must be a finite number ≥ 0, found {}",
                    self.cross_max_bend_m
                ),
            });
        }
        if self.cross_edge_blocks > 16 {
            return Err(Error::Config {
                field: "refine_hand_eye.cross_edge_blocks".into(),
                msg: format!("must be at most 16, found {}", self.cross_edge_blocks),
            });
        }
        Ok(())
    }
}

/// One robot's hand-eye in the joint refinement.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JointRobotResult {
    /// The robot's name.
    pub robot: String,
    /// The hand-eye it started from (the per-robot refinement's), `T_ee_cam`.
    #[serde(skip)]
    pub initial: Isometry3<f64>,
    /// The jointly refined hand-eye `T_ee_cam`.
    #[serde(skip)]
    pub t_ee_cam: Isometry3<f64>,
    /// `initial⁻¹ · refined` (camera frame).
    #[serde(skip)]
    pub change: Isometry3<f64>,
    /// Covariance of the change `[rx, ry, rz (rad), tx, ty, tz (m)]`, camera frame (its block of the joint
    /// covariance).
    #[serde(skip)]
    pub covariance: Matrix6<f64>,
    /// Each of the six parameters' 1-σ and status.
    pub dofs: Vec<DofObservability>,
    /// The poorly constrained directions in words.
    pub weak_directions: Vec<WeakDirection>,
    /// The range at which rotations are compared with translations, metres.
    pub characteristic_range_m: f64,
    /// Per frame (pose-file order): its own and cross-robot tests within the first gate, before and after.
    pub frames: Vec<FrameDepthResidual>,
    /// Median over the frames of `before_m`, metres.
    pub median_before_m: f64,
    /// Median over the frames of `after_m`, metres.
    pub median_after_m: f64,
}

/// Both hand-eyes and `T_base1_base2` refined together.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JointHandEyeResult {
    /// The two robots (reference first).
    pub robots: Vec<JointRobotResult>,
    /// The base-to-base transform it started from (the ordinary calibration's).
    #[serde(skip)]
    pub base_initial: Isometry3<f64>,
    /// The jointly refined `T_base1_base2`.
    #[serde(skip)]
    pub t_base1_base2: Isometry3<f64>,
    /// Its covariance, a left increment in base1 `[rx, ry, rz (rad), tx, ty, tz (m)]` (like calibrate's).
    #[serde(skip)]
    pub base_covariance: Matrix6<f64>,
    /// Cross-robot tests at the finest gate.
    pub cross_tests: usize,
    /// All tests at the finest gate (own and cross-robot).
    pub tests: usize,
    /// Tests refused by the side-of-surface rule at the finest gate.
    pub wrong_side_tests: usize,
    /// Gauss-Newton iterations over all gates.
    pub iterations: usize,
    /// The last step was negligible.
    pub converged: bool,
    /// True when every check passed.
    pub trusted: bool,
    /// Each failed check, in words.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
}

/// The current estimate: both hand-eyes and `T_base1_base2`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct State {
    x: [Isometry3<f64>; 2],
    b: Isometry3<f64>,
}

impl State {
    fn step(&self, d: &DVector<f64>) -> State {
        let e = |k: usize| {
            Isometry3::from_parts(
                Translation3::new(d[k + 3], d[k + 4], d[k + 5]),
                UnitQuaternion::from_scaled_axis(Vector3::new(d[k], d[k + 1], d[k + 2])),
            )
        };
        State {
            x: [self.x[0] * e(0), self.x[1] * e(6)],
            b: self.b * e(12),
        }
    }
}

/// One frame's share of the joint normal equations.
#[derive(Clone, Debug)]
struct JointSums {
    h: SMatrix<f64, N, N>,
    g: SVector<f64, N>,
    chi2: f64,
    weight: f64,
    abs: Vec<f32>,
    cross: usize,
    wrong_side: usize,
    samples_used: usize,
}

impl Default for JointSums {
    fn default() -> Self {
        JointSums {
            h: SMatrix::zeros(),
            g: SVector::zeros(),
            chi2: 0.0,
            weight: 0.0,
            abs: Vec::new(),
            cross: 0,
            wrong_side: 0,
            samples_used: 0,
        }
    }
}

/// Whether the view's blocks within `r` blocks of pixel `(u, v)` are all smooth.
fn away_from_edges(depth: &SmoothDepth, u: f64, v: f64, r: u32) -> bool {
    if r == 0 {
        return true;
    }
    let view = depth.view;
    let b = view.block as f64;
    let (sw, sh) = (view.size[0] as i64, view.size[1] as i64);
    let (bu, bv) = (
        ((u + 0.5) / b).floor() as i64,
        ((v + 0.5) / b).floor() as i64,
    );
    let r = r as i64;
    for y in bv - r..=bv + r {
        for x in bu - r..=bu + r {
            if x < 0 || y < 0 || x >= sw || y >= sh {
                return false;
            }
            if !depth.smooth((y * sw + x) as usize) {
                return false;
            }
        }
    }
    true
}

/// How far the view's surface at `(u, v)` bends: the largest distance, along the normal `n`, of the
/// centre point `p` from the mean of its neighbours one block to each side (metres). `None` where a
/// neighbour has no smooth depth.
fn bend_at(
    depth: &SmoothDepth,
    intr: &crate::camera::Intrinsics,
    u: f64,
    v: f64,
    p: &Vector3<f64>,
    n: &Vector3<f64>,
) -> Option<f64> {
    let at = |u: f64, v: f64| -> Option<Vector3<f64>> {
        let (near, far) = depth.depth(u, v)?;
        if far - near > 1e-9 || near <= 0.0 {
            return None;
        }
        let q = intr.deproject([u, v], near);
        Some(Vector3::new(q[0], q[1], q[2]))
    };
    let b = depth.view.block as f64;
    let du = (at(u + b, v)? + at(u - b, v)?) * 0.5 - p;
    let dv = (at(u, v + b)? + at(u, v - b)?) * 0.5 - p;
    Some(n.dot(&du).abs().max(n.dot(&dv).abs()))
}

/// Everything the joint residuals need: each robot's problem.
struct Joint<'a> {
    sides: [Problem<'a>; 2],
    cfg: &'a HandEyeDepthConfig,
    cross_edge_blocks: u32,
    cross_max_bend_m: f64,
    /// Per robot, which sampled points may take part in cross-robot terms (away from edges).
    cross_ok: [Vec<Vec<bool>>; 2],
    /// Characteristic ranges: robot 1, robot 2, the base-to-base transform.
    l: [f64; 3],
    /// Evaluations of [`Joint::sums`] by (state, gate).
    memo: Memo<(State, f64), Vec<JointSums>>,
}

impl Joint<'_> {
    /// The scaled-unit factors of the 18 parameters (rotations at their characteristic range).
    fn scale(&self) -> DVector<f64> {
        DVector::from_fn(N, |k, _| {
            let block = k / 6;
            if k % 6 < 3 {
                1.0 / self.l[block]
            } else {
                1.0
            }
        })
    }

    /// Per frame of both robots (robot 1's frames, then robot 2's): own and cross-robot sums under `s`,
    /// through the memo.
    fn sums(&self, s: &State, a: &Association) -> Vec<JointSums> {
        self.memo.get_or((*s, a.gate_m), || self.evaluate(s, a))
    }

    /// [`Self::sums`], evaluated.
    fn evaluate(&self, s: &State, a: &Association) -> Vec<JointSums> {
        let mut out = Vec::new();
        for r in 0..2 {
            let own = self.sides[r].sums(&s.x[r], a);
            let cross = self.cross_sums(s, r, a);
            for (o, mut c) in own.into_iter().zip(cross) {
                let k = 6 * r;
                let mut hv = c.h.fixed_view_mut::<6, 6>(k, k);
                hv += o.h;
                let mut gv = c.g.fixed_rows_mut::<6>(k);
                gv += o.g;
                c.chi2 += o.chi2;
                c.weight += o.weight;
                c.abs.extend_from_slice(&o.abs);
                c.wrong_side += o.wrong_side;
                c.samples_used = c.samples_used.max(o.samples_used);
                out.push(c);
            }
        }
        out
    }

    /// Robot `a`'s frames' points in every camera of the other robot.
    fn cross_sums(&self, s: &State, a: usize, asn: &Association) -> Vec<JointSums> {
        let b = 1 - a;
        let (pa, pb) = (&self.sides[a], &self.sides[b]);
        let xa = s.x[a];
        let xb_inv = s.x[b].inverse();
        // Maps robot a's base into robot b's: T_base1_base2 from 2 to 1, its inverse from 1 to 2.
        let m = if a == 1 { s.b } else { s.b.inverse() };
        let size = (pb.intr.width as f64, pb.intr.height as f64);
        (0..pa.frames())
            .into_par_iter()
            .map(|i| {
                let mut out = JointSums::default();
                let fp: &FramePoints = &pa.points[i];
                if fp.points.is_empty() {
                    return out;
                }
                let ok = &self.cross_ok[a][i];
                let mut used = vec![false; fp.points.len()];
                let base_a_cam = pa.t_base_ee[i] * xa;
                for j in 0..pb.frames() {
                    let cam_b_base_b = xb_inv * pb.t_base_ee[j].inverse();
                    let t = cam_b_base_b * m * base_a_cam;
                    let r = *t.rotation.to_rotation_matrix().matrix();
                    let tv = t.translation.vector;
                    // Rotation of the camera b ← base2 part, for the base-to-base Jacobian.
                    let r_b2 = if a == 1 {
                        *(cam_b_base_b * s.b).rotation.to_rotation_matrix().matrix()
                    } else {
                        *cam_b_base_b.rotation.to_rotation_matrix().matrix()
                    };
                    let target = Target {
                        depth: &pb.depths[j],
                        intr: pb.intr,
                        size,
                    };
                    // Cross-robot tests only away from depth edges and where the surface is flat.
                    let accept = |u: f64, v: f64, pj: &Vector3<f64>, nj: &Vector3<f64>| {
                        away_from_edges(target.depth, u, v, self.cross_edge_blocks)
                            && (self.cross_max_bend_m <= 0.0
                                || bend_at(target.depth, pb.intr, u, v, pj, nj)
                                    .is_some_and(|d| d <= self.cross_max_bend_m))
                    };
                    for (k, (p, np)) in fp.points.iter().zip(&fp.normals).enumerate() {
                        if !ok[k] {
                            continue;
                        }
                        let q = r * p + tv;
                        let test = test_point(&target, pa.cfg, asn, &r, (p, np), &q, accept);
                        let Some((nj, res, sigma, wk)) = test.hit(&mut out.wrong_side) else {
                            continue;
                        };
                        // dq/dδa = R·[−[p]×, I]; dq/dδb = [[q]×, −I].
                        let ja_w = nj.transpose() * (-r * skew(p));
                        let ja_v = nj.transpose() * r;
                        let jb_w = nj.transpose() * skew(&q);
                        let jb_v = -nj.transpose();
                        // The base-to-base correction, through the point in base2 `y`.
                        let (jbase_w, jbase_v) = if a == 1 {
                            // q = X₁⁻¹E₁ⱼ⁻¹ · B·exp(δ) · y: R_b2·[−[y]×, I].
                            let y = base_a_cam * nalgebra::Point3::from(*p);
                            (
                                nj.transpose() * (-r_b2 * skew(&y.coords)),
                                nj.transpose() * r_b2,
                            )
                        } else {
                            // q = X₂⁻¹E₂ⱼ⁻¹ · exp(−δ)·B⁻¹ · y: R_b2·[[z]×, −I], z = B⁻¹·y in base2.
                            let z = m * (base_a_cam * nalgebra::Point3::from(*p));
                            (
                                nj.transpose() * (r_b2 * skew(&z.coords)),
                                -(nj.transpose() * r_b2),
                            )
                        };
                        let mut jrow = SVector::<f64, N>::zeros();
                        let put = |jrow: &mut SVector<f64, N>, at: usize, row: RowVector6<f64>| {
                            for c in 0..6 {
                                jrow[at + c] += row[c];
                            }
                        };
                        put(
                            &mut jrow,
                            6 * a,
                            RowVector6::new(ja_w[0], ja_w[1], ja_w[2], ja_v[0], ja_v[1], ja_v[2]),
                        );
                        put(
                            &mut jrow,
                            6 * b,
                            RowVector6::new(jb_w[0], jb_w[1], jb_w[2], jb_v[0], jb_v[1], jb_v[2]),
                        );
                        put(
                            &mut jrow,
                            12,
                            RowVector6::new(
                                jbase_w[0], jbase_w[1], jbase_w[2], jbase_v[0], jbase_v[1],
                                jbase_v[2],
                            ),
                        );
                        let ws = wk / (sigma * sigma);
                        out.h.ger(ws, &jrow, &jrow, 1.0);
                        out.g.axpy(res * ws, &jrow, 1.0);
                        out.chi2 += wk * (res / sigma).powi(2);
                        out.weight += wk;
                        out.abs.push(res.abs() as f32);
                        out.cross += 1;
                        used[k] = true;
                    }
                }
                out.samples_used = used.iter().filter(|&&u| u).count();
                out
            })
            .collect()
    }

    /// The pseudo-inverse solve in scaled units: directions below `null_ratio` of the largest eigenvalue
    /// are left out. Returns the step and `H⁺` (unscaled).
    fn solve(&self, h: &DMatrix<f64>, g: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let s = DMatrix::from_diagonal(&self.scale());
        let hs = &s * h * &s;
        let eig = hs.symmetric_eigen();
        let lmax = eig.eigenvalues.max().max(0.0);
        let mut pinv = DMatrix::zeros(N, N);
        for k in 0..N {
            let lam = eig.eigenvalues[k];
            if lam > self.cfg.null_ratio * lmax && lam > 0.0 {
                let v = eig.eigenvectors.column(k);
                pinv += v * v.transpose() / lam;
            }
        }
        let h_pinv = &s * pinv * &s;
        (-(&h_pinv * g), h_pinv)
    }

    /// Gauss-Newton over the gates from `s0`, never stepping along `frozen` (unit vectors in scaled units).
    fn levels(&self, s0: &State, frozen: &[DVector<f64>]) -> (State, usize, bool) {
        let cfg = self.cfg;
        let sc = self.scale();
        let s_mat = DMatrix::from_diagonal(&sc);
        let s_inv = DMatrix::from_diagonal(&sc.map(|v| 1.0 / v));
        let mut p = DMatrix::<f64>::identity(N, N);
        for f in frozen {
            p -= f * f.transpose();
        }
        let proj = &s_mat * &p * &s_inv;
        let (mut s, mut iterations, mut converged) = (*s0, 0, false);
        for &gate in &cfg.gates_m {
            let a = association(cfg, gate);
            for _ in 0..cfg.max_iterations {
                iterations += 1;
                let (h, g, _, _, tests) = total(&self.sums(&s, &a));
                if tests < N {
                    break;
                }
                let (h, g) = if frozen.is_empty() {
                    (h, g)
                } else {
                    (proj.transpose() * h * &proj, proj.transpose() * g)
                };
                let (mut step, _) = self.solve(&h, &g);
                if !frozen.is_empty() {
                    step = &proj * step;
                }
                // At most a third of the gate per step, for each of the three transforms.
                let mut size: f64 = 0.0;
                for blk in 0..3 {
                    let k = 6 * blk;
                    let rot = Vector3::new(step[k], step[k + 1], step[k + 2]).norm() * self.l[blk];
                    let tr = Vector3::new(step[k + 3], step[k + 4], step[k + 5]).norm();
                    size = size.max(rot).max(tr);
                }
                if size > gate / 3.0 {
                    step *= gate / 3.0 / size;
                }
                s = s.step(&step);
                converged = (0..3).all(|blk| {
                    let k = 6 * blk;
                    Vector3::new(step[k], step[k + 1], step[k + 2]).norm() < 1e-3f64.to_radians()
                        && Vector3::new(step[k + 3], step[k + 4], step[k + 5]).norm() < 1e-5
                });
                if converged {
                    break;
                }
            }
        }
        (s, iterations, converged)
    }

    /// The joint covariance at `s` (as in the per-robot refinement), with the tests, cross-robot tests
    /// and refused tests at the finest gate.
    fn covariance(&self, s: &State) -> (DMatrix<f64>, usize, usize, usize) {
        let cfg = self.cfg;
        let fine = association(cfg, *cfg.gates_m.last().unwrap_or(&0.01));
        let sums = self.sums(s, &fine);
        let (h, _, chi2, weight, tests) = total(&sums);
        let cross: usize = sums.iter().map(|s| s.cross).sum();
        let wrong_side: usize = sums.iter().map(|s| s.wrong_side).sum();
        let (_, h_pinv) = self.solve(&h, &DVector::zeros(N));
        let samples: usize = sums.iter().map(|s| s.samples_used).sum();
        let k = if samples > 0 {
            (tests as f64 / samples as f64).max(1.0)
        } else {
            1.0
        };
        let s2 = if weight > N as f64 {
            chi2 / (weight - N as f64)
        } else {
            1.0
        };
        let mut meat = SMatrix::<f64, N, N>::zeros();
        for s in &sums {
            meat += s.g * s.g.transpose();
        }
        let meat = DMatrix::from_column_slice(N, N, meat.as_slice());
        let frames = sums.iter().filter(|s| !s.abs.is_empty()).count();
        let cluster_scale = if frames > 1 {
            frames as f64 / (frames - 1) as f64
        } else {
            1.0
        };
        let mut cov = (&h_pinv * (k * s2) + &h_pinv * meat * &h_pinv * cluster_scale) * 0.5;
        for blk in 0..3 {
            for d in 0..3 {
                cov[(6 * blk + d, 6 * blk + d)] += cfg.floor_deg.to_radians().powi(2);
                cov[(6 * blk + d + 3, 6 * blk + d + 3)] += (cfg.floor_mm * 1e-3).powi(2);
            }
        }
        // Directions left out of the solve: unobservable, 1 m 1-σ (in scaled units).
        let sm = DMatrix::from_diagonal(&self.scale());
        let eig = (&sm * &h * &sm).symmetric_eigen();
        let lmax = eig.eigenvalues.max().max(0.0);
        for kk in 0..N {
            if !(eig.eigenvalues[kk] > cfg.null_ratio * lmax && eig.eigenvalues[kk] > 0.0) {
                let v = &sm * eig.eigenvectors.column(kk);
                cov += &v * v.transpose();
            }
        }
        (cov, tests, cross, wrong_side)
    }

    /// The covariance's directions with their 1-σ (metres, rotations at their range), largest first.
    fn directions(&self, cov: &DMatrix<f64>) -> Vec<(DVector<f64>, f64)> {
        let s = DMatrix::from_diagonal(&self.scale().map(|v| 1.0 / v));
        let eig = (&s * cov * &s).symmetric_eigen();
        let mut out: Vec<(DVector<f64>, f64)> = (0..N)
            .map(|k| {
                (
                    eig.eigenvectors.column(k).into_owned(),
                    eig.eigenvalues[k].max(0.0).sqrt(),
                )
            })
            .collect();
        out.sort_by(|a, b| b.1.total_cmp(&a.1));
        out
    }

    /// Per frame of each robot: the median absolute residual and the tests.
    fn frame_stats(&self, s: &State, a: &Association) -> [Vec<(f64, usize)>; 2] {
        let mut sums = self.sums(s, a);
        let n0 = self.sides[0].frames();
        let mut all: Vec<super::residuals::FrameSums> = sums
            .iter_mut()
            .map(|j| super::residuals::FrameSums {
                abs: std::mem::take(&mut j.abs),
                ..Default::default()
            })
            .collect();
        let second = all.split_off(n0);
        [frame_stats(&mut all), {
            let mut second = second;
            frame_stats(&mut second)
        }]
    }
}

/// The sums of all frames, in frame order.
fn total(sums: &[JointSums]) -> (DMatrix<f64>, DVector<f64>, f64, f64, usize) {
    let mut h = SMatrix::<f64, N, N>::zeros();
    let mut g = SVector::<f64, N>::zeros();
    let (mut chi2, mut w, mut n) = (0.0, 0.0, 0usize);
    for s in sums {
        h += s.h;
        g += s.g;
        chi2 += s.chi2;
        w += s.weight;
        n += s.abs.len();
    }
    (
        DMatrix::from_column_slice(N, N, h.as_slice()),
        DVector::from_column_slice(g.as_slice()),
        chi2,
        w,
        n,
    )
}

fn block6(m: &DMatrix<f64>, k: usize) -> Matrix6<f64> {
    Matrix6::from_fn(|i, j| m[(k + i, k + j)])
}

/// The adjoint of `t` on twists `[ω, v]`: `t · exp(δ) = exp(Ad·δ) · t`.
fn adjoint(t: &Isometry3<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = *t.rotation.to_rotation_matrix().matrix();
    let tx = skew(&t.translation.vector) * r;
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 0).copy_from(&tx);
    a
}

/// Refines both robots' hand-eyes (`robots[0]` the reference, base1) and `t_base1_base2` together (see
/// the module documentation), from the robots' current hand-eyes and `t_base1_base2`, with
/// `settings.depth` and the cross-robot gates of `settings`. Errors: a bad
/// configuration, too few frames, an unreadable depth image. An answer the poses do not support is
/// returned untrusted with its reasons.
pub fn refine_jointly(
    robots: [&CellRobot; 2],
    t_base1_base2: &Isometry3<f64>,
    settings: &RefineHandEyeConfig,
) -> Result<JointHandEyeResult> {
    let cfg = &settings.depth;
    let cross_edge_blocks = settings.cross_edge_blocks;
    let cross_max_bend_m = settings.cross_max_bend_m;
    cfg.validate()?;
    for r in robots {
        if r.frames.len() < cfg.min_frames {
            return Err(Error::InvalidInput(format!(
                "robot {}: {} frames, the joint hand-eye refinement needs at least {}",
                r.name,
                r.frames.len(),
                cfg.min_frames
            )));
        }
    }
    let ccfg = cfg.consistency();
    let views = [load_views(robots[0], cfg)?, load_views(robots[1], cfg)?];
    let problem = |k: usize| {
        Problem::new(
            robots[k].frames.iter().map(|f| f.t_base_ee).collect(),
            &views[k],
            &robots[k].intrinsics,
            &ccfg,
        )
    };
    let sides = [problem(0), problem(1)];
    let cross_ok = [0, 1].map(|k| {
        let p = &sides[k];
        p.points
            .iter()
            .zip(&p.depths)
            .map(|(fp, depth)| {
                fp.points
                    .iter()
                    .zip(&fp.normals)
                    .map(|(q, n)| {
                        let [u, v] = p.intr.project([q.x, q.y, q.z]);
                        away_from_edges(depth, u, v, cross_edge_blocks)
                            && (cross_max_bend_m <= 0.0
                                || bend_at(depth, p.intr, u, v, q, n)
                                    .is_some_and(|d| d <= cross_max_bend_m))
                    })
                    .collect()
            })
            .collect()
    });
    let l0 = characteristic_range(&sides[0].points);
    let l1 = characteristic_range(&sides[1].points);
    let problem = Joint {
        l: [l0, l1, 0.5 * (l0 + l1)],
        sides,
        cfg,
        cross_edge_blocks,
        cross_max_bend_m,
        cross_ok,
        memo: Memo::new(3),
    };
    let s0 = State {
        x: [robots[0].t_ee_cam, robots[1].t_ee_cam],
        b: *t_base1_base2,
    };
    let report_gate = association(cfg, cfg.gates_m[0]);
    let before = problem.frame_stats(&s0, &report_gate);

    let (mut s, mut iterations, mut converged) = problem.levels(&s0, &[]);
    let mut cov = problem.covariance(&s).0;
    let weak_limit = (cfg.weak_sigma_mm * 1e-3).min(cfg.weak_sigma_deg.to_radians() * l0.min(l1));
    let frozen: Vec<DVector<f64>> = problem
        .directions(&cov)
        .into_iter()
        .filter(|(_, sd)| *sd > weak_limit)
        .map(|(v, _)| v)
        .collect();
    if !frozen.is_empty() {
        let (s2, it2, c2) = problem.levels(&s0, &frozen);
        (s, converged) = (s2, c2);
        iterations += it2;
        cov = problem.covariance(&s).0;
    }
    let (_, tests, cross_tests, wrong_side) = problem.covariance(&s);
    let after = problem.frame_stats(&s, &report_gate);

    let mut reasons = Vec::new();
    let mut suggestions = Vec::new();
    let mut out = Vec::new();
    for k in 0..2 {
        let robot = robots[k];
        let c = block6(&cov, 6 * k);
        let l = problem.l[k];
        let (dofs, weak_directions) = observability(&c, l, cfg);
        let motion = super::observe::flange_motion(&problem.sides[k].t_base_ee, &s0.x[k]);
        observability_reasons(
            &robot.name,
            &dofs,
            &weak_directions,
            &motion,
            &mut reasons,
            &mut suggestions,
        );
        let (frames, median_before_m, median_after_m) =
            frame_residuals(robot, &before[k], &after[k]);
        let change = s0.x[k].inverse() * s.x[k];
        let (angle, shift) = (
            change.rotation.angle().to_degrees(),
            change.translation.vector.norm() * 1e3,
        );
        if angle > cfg.max_change_deg || shift > cfg.max_change_mm {
            reasons.push(format!(
                "robot {}: the joint refinement moved the hand-eye {angle:.2}° / {shift:.1} mm, beyond {}° / {} mm",
                robot.name, cfg.max_change_deg, cfg.max_change_mm
            ));
        }
        if median_after_m > median_before_m * 1.05 + 1e-5 {
            reasons.push(format!(
                "robot {}: the frames agree less after the joint refinement (median residual {:.2} -> {:.2} mm)",
                robot.name,
                median_before_m * 1e3,
                median_after_m * 1e3
            ));
        }
        out.push(JointRobotResult {
            robot: robot.name.clone(),
            initial: s0.x[k],
            t_ee_cam: s.x[k],
            change,
            covariance: c,
            dofs,
            weak_directions,
            characteristic_range_m: l,
            frames,
            median_before_m,
            median_after_m,
        });
    }
    // The base-to-base covariance as a left increment in base1, like calibrate's.
    let ad = adjoint(&s.b);
    let base_covariance = ad * block6(&cov, 12) * ad.transpose();
    let base_sd_mm = (0..3)
        .map(|d| base_covariance[(d + 3, d + 3)].max(0.0).sqrt() * 1e3)
        .fold(0.0, f64::max);
    if base_sd_mm > cfg.unobservable_sigma_mm || cross_tests < 6 * N {
        reasons.push(format!(
            "the robots' frames share too little for the joint base-to-base transform ({cross_tests} \
             cross-robot tests, translation 1-σ {base_sd_mm:.2} mm)"
        ));
        suggestions.push("capture frames in which both robots see the same objects".into());
    }
    if !converged {
        reasons.push(format!(
            "the joint refinement did not converge within {} iterations per gate",
            cfg.max_iterations
        ));
    }
    suggestions.dedup();
    Ok(JointHandEyeResult {
        robots: out,
        base_initial: s0.b,
        t_base1_base2: s.b,
        base_covariance,
        cross_tests,
        tests,
        wrong_side_tests: wrong_side,
        iterations,
        converged,
        trusted: reasons.is_empty(),
        reasons,
        suggestions,
    })
}
