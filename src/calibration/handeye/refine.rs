//! Joint nonlinear refinement of `X = T_ee_cam` and `Z = T_base_board` (rotation and translation
//! together) by Levenberg-Marquardt on SE(3) × SE(3) with iteratively reweighted robust kernels.
//!
//! The residual of frame i is the pose error `Eᵢ = Z⁻¹ · T_base_ee_i · X · T_cam_board_i` (identity when the
//! frame fits), as the 6-vector `[log R_E / σ_r, t_E / σ_t]`. Its rotation angle is the angle between the
//! measured board orientation and the one predicted from the robot pose, and `‖t_E‖` the distance between
//! the measured and predicted board origins (the same in the camera and in the base frame). The scales
//! `σ_r` (radians) and `σ_t` (metres) are estimated from the data by the caller.

use super::{log_rotation, HandEyeFrame};
use nalgebra::{Isometry3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3, Vector6};

/// A robust kernel on the whitened residual norm `s` (dimensionless, in units of σ).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kernel {
    /// Plain least squares, `ρ(s) = s²/2`.
    None,
    /// Huber with width `k`: quadratic below `k`, linear above.
    Huber(f64),
    /// Cauchy (Lorentzian) with width `c`: `ρ(s) = c²/2 · ln(1 + s²/c²)`.
    Cauchy(f64),
}

impl Kernel {
    fn rho(self, s: f64) -> f64 {
        match self {
            Kernel::None => 0.5 * s * s,
            Kernel::Huber(k) => {
                if s <= k {
                    0.5 * s * s
                } else {
                    k * (s - 0.5 * k)
                }
            }
            Kernel::Cauchy(c) => 0.5 * c * c * (1.0 + (s / c).powi(2)).ln(),
        }
    }
    fn weight(self, s: f64) -> f64 {
        match self {
            Kernel::None => 1.0,
            Kernel::Huber(k) => {
                if s <= k {
                    1.0
                } else {
                    k / s
                }
            }
            Kernel::Cauchy(c) => 1.0 / (1.0 + (s / c).powi(2)),
        }
    }
}

/// The outcome of [`refine`].
#[derive(Clone, Debug)]
pub struct RefineOutcome {
    /// Refined `T_ee_cam`, metres.
    pub t_ee_cam: Isometry3<f64>,
    /// Refined `T_base_board`, metres.
    pub t_base_board: Isometry3<f64>,
    /// Levenberg-Marquardt iterations run.
    pub iterations: usize,
    /// True when the last step was below 1e-12 (radians and metres) or no step could lower the cost further.
    pub converged: bool,
    /// Final robust cost `Σ ρ(sᵢ)` over the active frames.
    pub cost: f64,
}

/// The pose error `Z⁻¹ · T_base_ee · X · T_cam_board` of one frame.
pub fn frame_error(
    f: &HandEyeFrame,
    t_ee_cam: &Isometry3<f64>,
    t_base_board: &Isometry3<f64>,
) -> Isometry3<f64> {
    t_base_board.inverse() * f.t_base_ee * t_ee_cam * f.t_cam_board
}

fn residual(
    f: &HandEyeFrame,
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
) -> Vector6<f64> {
    let e = frame_error(f, x, z);
    let w = log_rotation(&e.rotation) / sigma_r;
    let t = e.translation.vector / sigma_t;
    Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z)
}

fn exp_right(t: &Isometry3<f64>, d: &[f64]) -> Isometry3<f64> {
    let inc = Isometry3::from_parts(
        Translation3::new(d[3], d[4], d[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(d[0], d[1], d[2])),
    );
    let mut out = t * inc;
    out.rotation.renormalize();
    out
}

fn apply(
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    d: &SVector<f64, 12>,
) -> (Isometry3<f64>, Isometry3<f64>) {
    (
        exp_right(x, &d.as_slice()[0..6]),
        exp_right(z, &d.as_slice()[6..12]),
    )
}

fn cost(
    frames: &[HandEyeFrame],
    active: &[bool],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
    kernel: Kernel,
) -> f64 {
    frames
        .iter()
        .zip(active)
        .filter(|(_, a)| **a)
        .map(|(f, _)| kernel.rho(residual(f, x, z, sigma_r, sigma_t).norm()))
        .sum()
}

/// Central-difference step of the Jacobians (radians and metres).
const H: f64 = 1e-7;

/// The Jacobian of one frame's whitened residual with respect to the right increments of `(X, Z)`.
fn jacobian(
    f: &HandEyeFrame,
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
) -> SMatrix<f64, 6, 12> {
    let mut j = SMatrix::<f64, 6, 12>::zeros();
    for k in 0..12 {
        let mut d = SVector::<f64, 12>::zeros();
        d[k] = H;
        let (xp, zp) = apply(x, z, &d);
        let (xm, zm) = apply(x, z, &(-d));
        let col = (residual(f, &xp, &zp, sigma_r, sigma_t)
            - residual(f, &xm, &zm, sigma_r, sigma_t))
            / (2.0 * H);
        j.set_column(k, &col);
    }
    j
}

/// The kernel-weighted normal equations `JᵀWJ`, `JᵀWr` of the active frames, with `Σ|r|²` and their count.
struct NormalEquations {
    hess: SMatrix<f64, 12, 12>,
    grad: SVector<f64, 12>,
    chi2: f64,
    frames: usize,
}

fn normal_equations(
    frames: &[HandEyeFrame],
    active: &[bool],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
    kernel: Kernel,
) -> NormalEquations {
    let mut n = NormalEquations {
        hess: SMatrix::zeros(),
        grad: SVector::zeros(),
        chi2: 0.0,
        frames: 0,
    };
    for (f, _) in frames.iter().zip(active).filter(|(_, a)| **a) {
        let r = residual(f, x, z, sigma_r, sigma_t);
        let w = kernel.weight(r.norm());
        let j = jacobian(f, x, z, sigma_r, sigma_t);
        n.hess += j.transpose() * j * w;
        n.grad += j.transpose() * r * w;
        n.chi2 += r.norm_squared();
        n.frames += 1;
    }
    n
}

/// The 1-σ of `X = T_ee_cam` at `(x, z)` from the active frames: `s² (JᵀJ)⁻¹` of the whitened residuals,
/// with `s²` their reduced χ² (so the scales `sigma_r`, `sigma_t` only set the relative weighting), its
/// rotation block and translation block each reduced to an RMS per axis: `(radians, metres)`, the right
/// increment of `X` (camera frame). `None` when fewer than three frames are active or the normal
/// equations are singular. This is the statistical part only: a bias shared by every frame (a wrong board
/// size, intrinsics) does not show in it.
pub fn hand_eye_sigma(
    frames: &[HandEyeFrame],
    active: &[bool],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
) -> Option<(f64, f64)> {
    let n = normal_equations(frames, active, x, z, sigma_r, sigma_t, Kernel::None);
    let (hess, chi2, m) = (n.hess, n.chi2, n.frames);
    if m < 3 {
        return None;
    }
    let dof = (6 * m).saturating_sub(12).max(1) as f64;
    let cov = hess.try_inverse()? * (chi2 / dof);
    let rot = (cov[(0, 0)] + cov[(1, 1)] + cov[(2, 2)]) / 3.0;
    let tr = (cov[(3, 3)] + cov[(4, 4)] + cov[(5, 5)]) / 3.0;
    (rot.is_finite() && tr.is_finite() && rot >= 0.0 && tr >= 0.0).then(|| (rot.sqrt(), tr.sqrt()))
}

/// Refines `(X, Z)` from `(x0, z0)` over the frames with `active[i]`, with residual scales `sigma_r`
/// (radians) and `sigma_t` (metres), the robust `kernel`, and at most `max_iterations` LM iterations.
///
/// Jacobians are central differences (step 1e-7) of the exact residual, so the minimum found is the true
/// minimum of the stated cost.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    frames: &[HandEyeFrame],
    active: &[bool],
    x0: &Isometry3<f64>,
    z0: &Isometry3<f64>,
    sigma_r: f64,
    sigma_t: f64,
    kernel: Kernel,
    max_iterations: usize,
) -> RefineOutcome {
    let (mut x, mut z) = (*x0, *z0);
    let mut lambda = 1e-4;
    let mut current = cost(frames, active, &x, &z, sigma_r, sigma_t, kernel);
    let mut converged = false;
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        let NormalEquations { hess, grad, .. } =
            normal_equations(frames, active, &x, &z, sigma_r, sigma_t, kernel);
        let mut accepted = None;
        for _ in 0..12 {
            let mut a = hess;
            for k in 0..12 {
                a[(k, k)] += lambda * hess[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&(-grad))) else {
                lambda *= 10.0;
                continue;
            };
            let (xn, zn) = apply(&x, &z, &step);
            let c = cost(frames, active, &xn, &zn, sigma_r, sigma_t, kernel);
            if c <= current {
                accepted = Some((xn, zn, c, step));
                lambda = (lambda / 3.0).max(1e-12);
                break;
            }
            lambda *= 5.0;
        }
        match accepted {
            Some((xn, zn, c, step)) => {
                x = xn;
                z = zn;
                let small = step.amax() < 1e-12;
                let flat = current - c <= 1e-15 * current.max(1e-300);
                current = c;
                if small || flat {
                    converged = true;
                    break;
                }
            }
            None => {
                converged = true;
                break;
            }
        }
    }
    RefineOutcome {
        t_ee_cam: x,
        t_base_board: z,
        iterations,
        converged,
        cost: current,
    }
}
