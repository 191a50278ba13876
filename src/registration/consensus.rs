//! The one RANSAC loop: hypotheses drawn in batches of iteration numbers, each batch merged (in
//! iteration order) into the caller's best so far, and a confidence-based stop rule. What a sample is, how
//! hypotheses are scored and kept is the caller's; the loop owns the batching, the iteration count and the
//! stop. Random draws come from [`Rng`] (`crate::geometry::rng`): one stream per iteration
//! ([`draw_streams`], parallel and bit-identical at any thread count) or one sequential generator
//! ([`draw_sequential`]).

use crate::geometry::Rng;
use rayon::prelude::*;
use std::ops::Range;

/// How many samples [`consensus_loop`] draws and how it groups them.
#[derive(Clone, Copy, Debug)]
pub struct LoopLimits {
    /// Most samples drawn.
    pub max_iterations: usize,
    /// Fewest samples drawn whatever the stop rule says.
    pub min_iterations: usize,
    /// Samples per batch; the stop rule is checked between batches (at least 1).
    pub batch: usize,
}

/// Runs batches of iterations `done..done + batch` through `draw` (which gives the batch's hypotheses in
/// iteration order) and `merge` (which keeps what it wants of them and returns the number of samples the
/// confidence needs given the best so far, `None` while no stop rule applies), until `max_iterations`
/// samples or, past `min_iterations`, as many as `merge` says are needed. Gives the samples drawn.
pub fn consensus_loop<H>(
    limits: &LoopLimits,
    mut draw: impl FnMut(Range<usize>) -> Vec<H>,
    mut merge: impl FnMut(Vec<H>) -> Option<f64>,
) -> usize {
    let batch = limits.batch.max(1);
    let mut done = 0;
    while done < limits.max_iterations {
        let end = (done + batch).min(limits.max_iterations);
        let hypotheses = draw(done..end);
        done = end;
        if let Some(needed) = merge(hypotheses) {
            if done >= limits.min_iterations && done as f64 >= needed {
                break;
            }
        }
    }
    done
}

/// Samples needed to draw an all-inlier sample at least once with confidence `1 − e^ln_fail`, when one
/// sample is all-inlier with probability `p_success` in (0, 1]: `ln_fail / ln(1 − p)` (1 when `p ≥ 1`).
pub fn samples_needed(p_success: f64, ln_fail: f64) -> f64 {
    if p_success >= 1.0 {
        1.0
    } else {
        ln_fail / (1.0 - p_success).ln()
    }
}

/// The hypotheses of iterations `its`, iteration `k` drawing from its own stream `Rng::stream(seed, k)`
/// (in parallel; the result is in iteration order).
pub fn draw_streams<H: Send>(
    seed: u64,
    its: Range<usize>,
    hypothesis: &(impl Fn(&mut Rng, usize) -> Option<H> + Sync),
) -> Vec<H> {
    its.into_par_iter()
        .filter_map(|it| hypothesis(&mut Rng::stream(seed, it as u64), it))
        .collect()
}

/// The hypotheses of iterations `its`, drawn one after the other from `rng`.
pub fn draw_sequential<H>(
    rng: &mut Rng,
    its: Range<usize>,
    mut hypothesis: impl FnMut(&mut Rng, usize) -> Option<H>,
) -> Vec<H> {
    its.filter_map(|it| hypothesis(rng, it)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stops_by_confidence_after_the_minimum() {
        let limits = LoopLimits {
            max_iterations: 1000,
            min_iterations: 30,
            batch: 10,
        };
        // Every batch says 5 samples are enough: the loop still draws the minimum, in whole batches.
        let done = consensus_loop(&limits, |r| r.collect::<Vec<usize>>(), |_| Some(5.0));
        assert_eq!(done, 30);
        // No stop rule: the maximum.
        let done = consensus_loop(&limits, |r| r.collect::<Vec<usize>>(), |_| None);
        assert_eq!(done, 1000);
        // Streams give the same draws whatever the batch split.
        let h = |rng: &mut Rng, it: usize| Some((it, rng.next_u64()));
        let a = draw_streams(3, 0..50, &h);
        let mut b = draw_streams(3, 0..20, &h);
        b.extend(draw_streams(3, 20..50, &h));
        assert_eq!(a, b);
        assert!((samples_needed(0.5, 0.5f64.ln()) - 1.0).abs() < 1e-12);
        assert_eq!(samples_needed(1.0, -3.0), 1.0);
    }
}
