//! Anderson acceleration of a fixed-point iteration `u ← G(u)` on a 6-vector (a pose increment), as
//! AA-ICP applies it to ICP (Pavlov, Ovchinnikov, Shabalina & Burnaev, "AA-ICP: Iterative Closest Point
//! with Anderson Acceleration", ICRA 2018).
//!
//! ICP is such an iteration: `G` re-pairs the points at the current pose and takes one step. Near a
//! solution it converges only linearly, slowly where the correspondences lag behind the pose (sliding
//! along surfaces; a rough start). Anderson's method proposes the next iterate as the combination of the
//! last `m` values of `G` whose residuals `f = G(u) − u` cancel best:
//!
//! `γ = argmin ‖f_k − ΔF γ‖`, `u_{k+1} = G(u_k) − ΔG γ`,
//!
//! with `ΔF`, `ΔG` the differences of consecutive residuals and values. The caller guards it: a proposal
//! that raises the objective is dropped for the plain step `G(u_k)` and the history restarts
//! ([`Anderson::reset`]). Rotations are weighed by a length (cloud units per radian) so that the least
//! squares fit compares like with like.

use nalgebra::{DMatrix, DVector, Vector6};
use std::collections::VecDeque;

/// The history and settings of one accelerated iteration.
#[derive(Clone, Debug)]
pub struct Anderson {
    /// Differences kept at most (`m`).
    depth: usize,
    /// Per-component weights of the fit (the length scale on the three rotation components, 1 on the
    /// translation).
    weight: Vector6<f64>,
    /// The last `depth + 1` values `G(u)` and residuals `G(u) − u`, oldest first (weighted).
    g: VecDeque<Vector6<f64>>,
    f: VecDeque<Vector6<f64>>,
}

impl Anderson {
    /// `depth` differences at most (≥ 1); `length` weighs the rotation components (cloud units per radian,
    /// e.g. the RMS radius of the moving points; non-positive or non-finite values count as 1).
    pub fn new(depth: usize, length: f64) -> Self {
        let l = if length.is_finite() && length > 0.0 {
            length
        } else {
            1.0
        };
        Anderson {
            depth: depth.max(1),
            weight: Vector6::new(l, l, l, 1.0, 1.0, 1.0),
            g: VecDeque::new(),
            f: VecDeque::new(),
        }
    }

    /// Forgets the history (after a rejected proposal): the next call returns its `g` unchanged.
    pub fn reset(&mut self) {
        self.g.clear();
        self.f.clear();
    }

    /// The next iterate after `u` whose map value is `g = G(u)`: `g` itself until the history holds two
    /// entries, then Anderson's combination. Deterministic; falls back to `g` when the fit is not finite.
    pub fn next(&mut self, u: &Vector6<f64>, g: &Vector6<f64>) -> Vector6<f64> {
        let gw = g.component_mul(&self.weight);
        let fw = (g - u).component_mul(&self.weight);
        self.g.push_back(gw);
        self.f.push_back(fw);
        if self.g.len() > self.depth + 1 {
            self.g.pop_front();
            self.f.pop_front();
        }
        let m = self.g.len() - 1;
        if m == 0 {
            return *g;
        }
        let mut df = DMatrix::zeros(6, m);
        let mut dg = DMatrix::zeros(6, m);
        for k in 0..m {
            df.set_column(k, &(self.f[k + 1] - self.f[k]));
            dg.set_column(k, &(self.g[k + 1] - self.g[k]));
        }
        let rhs = DVector::from_column_slice(fw.as_slice());
        let Ok(gamma) = df
            .svd(true, true)
            .solve(&rhs, 1e-12 * fw.norm().max(1e-300))
        else {
            return *g;
        };
        let next_w = DVector::from_column_slice(gw.as_slice()) - dg * gamma;
        let next = Vector6::from_iterator(next_w.iter().copied()).component_div(&self.weight);
        if next.iter().all(|x| x.is_finite()) {
            next
        } else {
            *g
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix6;

    /// A slowly contracting linear map with fixed point `x*`: `G(u) = x* + A (u − x*)`.
    fn slow_map() -> (Matrix6<f64>, Vector6<f64>) {
        let mut a = Matrix6::zeros();
        for (k, r) in [0.95, 0.9, 0.8, 0.6, 0.3, 0.1].iter().enumerate() {
            a[(k, k)] = *r;
        }
        // Couple the components so the map is not diagonal in the iterate's own basis.
        a[(0, 3)] = 0.02;
        a[(4, 1)] = -0.03;
        (a, Vector6::new(0.1, -0.2, 0.05, 1.0, -0.5, 0.25))
    }

    fn iterations_to(tol: f64, depth: Option<usize>) -> usize {
        let (a, x) = slow_map();
        let mut u = Vector6::zeros();
        let mut acc = depth.map(|d| Anderson::new(d, 2.0));
        for it in 1..=10_000 {
            let g = x + a * (u - x);
            if (g - u).norm() < tol {
                return it;
            }
            u = match acc.as_mut() {
                Some(acc) => acc.next(&u, &g),
                None => g,
            };
        }
        usize::MAX
    }

    #[test]
    fn accelerates_a_slow_linear_iteration_to_the_same_fixed_point() {
        let plain = iterations_to(1e-10, None);
        let fast = iterations_to(1e-10, Some(5));
        assert!(plain > 300, "{plain}");
        // A linear map in 6-D: Anderson with depth ≥ 6 is GMRES-like and finishes in a few steps; depth 5
        // still cuts the count by far.
        assert!(fast * 5 < plain, "plain {plain}, accelerated {fast}");
        assert!(iterations_to(1e-10, Some(6)) < 20);
    }

    #[test]
    fn the_first_call_and_a_reset_return_the_plain_step() {
        let mut acc = Anderson::new(3, 1.0);
        let (u, g) = (Vector6::repeat(1.0), Vector6::repeat(0.5));
        assert_eq!(acc.next(&u, &g), g);
        acc.reset();
        assert_eq!(acc.next(&g, &(g * 0.5)), g * 0.5);
        // A degenerate history (the same residual twice) still gives a finite iterate.
        let mut acc = Anderson::new(3, f64::NAN);
        acc.next(&u, &g);
        let n = acc.next(&u, &g);
        assert!(n.iter().all(|x| x.is_finite()));
    }
}
