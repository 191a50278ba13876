//! Sums of weighted outer products `Σ w·r·rᵀ` of 6-vectors (the normal equations' `JᵀWJ` of
//! Gauss-Newton fits over many point tests), accumulated on the upper triangle only.

use nalgebra::{Matrix6, Vector6};

/// `Σ w·r·rᵀ` over 6-vectors `r`, kept as its upper triangle (21 sums instead of 36). Each term is
/// `(r_i·r_j)·w`, the value nalgebra's `r * r.transpose() * w` has at `(i, j)` and at `(j, i)`, added in
/// the same order, so [`Self::matrix`] is that sum bit for bit at a little more than half the cost.
#[derive(Clone, Copy, Debug)]
pub struct OuterSum6 {
    upper: [f64; 21],
}

impl Default for OuterSum6 {
    fn default() -> Self {
        OuterSum6 { upper: [0.0; 21] }
    }
}

impl OuterSum6 {
    /// Adds `w·r·rᵀ`.
    #[inline(always)]
    pub fn add(&mut self, r: &Vector6<f64>, w: f64) {
        let mut k = 0;
        for i in 0..6 {
            for j in i..6 {
                self.upper[k] += r[i] * r[j] * w;
                k += 1;
            }
        }
    }

    /// The symmetric 6x6 sum.
    pub fn matrix(&self) -> Matrix6<f64> {
        let mut m = Matrix6::zeros();
        let mut k = 0;
        for i in 0..6 {
            for j in i..6 {
                m[(i, j)] = self.upper[k];
                m[(j, i)] = self.upper[k];
                k += 1;
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    /// The sum is nalgebra's `Σ r·rᵀ·w` (of a column or a row vector, as the fits write it), bit for bit.
    #[test]
    fn the_sum_is_nalgebras_bit_for_bit() {
        let mut rng = Rng::new(7);
        let mut u = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
        let (mut col, mut row) = (Matrix6::<f64>::zeros(), Matrix6::<f64>::zeros());
        let mut sum = OuterSum6::default();
        for n in 0..500 {
            let r = Vector6::from_fn(|i, _| u() * 10f64.powi((i as i32 + n) % 7 - 3));
            let w = u().abs() * 1e4;
            col += r * r.transpose() * w;
            let jrow = r.transpose();
            row += jrow.transpose() * jrow * w;
            sum.add(&r, w);
        }
        let m = sum.matrix();
        for i in 0..36 {
            assert_eq!(m[i].to_bits(), col[i].to_bits(), "entry {i}");
            assert_eq!(m[i].to_bits(), row[i].to_bits(), "entry {i}");
        }
    }
}
