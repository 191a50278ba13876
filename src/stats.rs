//! Summary statistics of samples: medians, quantiles, RMS. Empty samples give 0 (callers that must tell
//! "no samples" apart check the length first).

/// The median: the middle value, or the mean of the two middle values of an even count.
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// The upper median: the value at index `n / 2` of the sorted samples (the median for an odd count, the
/// larger middle value for an even one). Always a sample, which robust thresholds rely on.
pub fn upper_median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// The sample at rank `floor(n·q)` (clamped to the last), `q` in `[0, 1]`, found in place by selection.
pub fn quantile_in_place_f32(v: &mut [f32], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = ((v.len() as f64 * q) as usize).min(v.len() - 1);
    let (_, m, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *m as f64
}

/// Root mean square.
pub fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// The largest value, 0 for an empty sample (for non-negative quantities such as errors).
pub fn max_or_zero(v: &[f64]) -> f64 {
    v.iter().cloned().fold(0.0, f64::max)
}

/// Sorts `v` in the order of `f32::total_cmp` (ascending, `-0` before `+0`, NaNs at the ends by sign), by
/// a three-pass radix sort of the values' bits: for the hundreds of thousands of squared distances an
/// ICP iteration sorts, several times cheaper than a comparison sort of them (measured in BENCHMARK.md).
pub fn sort_f32(v: &mut [f32]) {
    const BITS: u32 = 11;
    const BUCKETS: usize = 1 << BITS;
    if v.len() < 4 * BUCKETS {
        v.sort_unstable_by(f32::total_cmp);
        return;
    }
    // total_cmp's order as unsigned keys: a negative value's bits all flipped, a positive's sign set.
    let key = |x: f32| {
        let b = x.to_bits();
        if b >> 31 == 1 {
            !b
        } else {
            b | 1 << 31
        }
    };
    let unkey = |k: u32| f32::from_bits(if k >> 31 == 1 { k & !(1 << 31) } else { !k });
    let mut a: Vec<u32> = v.iter().map(|&x| key(x)).collect();
    let mut b = vec![0u32; a.len()];
    for shift in [0, BITS, 2 * BITS] {
        let digit = |k: u32| ((k >> shift) as usize) & (BUCKETS - 1);
        let mut start = [0usize; BUCKETS];
        for &k in &a {
            start[digit(k)] += 1;
        }
        let mut sum = 0;
        for c in start.iter_mut() {
            (*c, sum) = (sum, sum + *c);
        }
        for &k in &a {
            let d = digit(k);
            b[start[d]] = k;
            start[d] += 1;
        }
        std::mem::swap(&mut a, &mut b);
    }
    for (x, &k) in v.iter_mut().zip(&a) {
        *x = unkey(k);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn against_sorted_definitions() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(upper_median(&[4.0, 1.0, 3.0, 2.0]), 3.0);
        assert_eq!(median(&[]), 0.0);
        assert_eq!(rms(&[3.0, 4.0]), (12.5f64).sqrt());
        assert_eq!(max_or_zero(&[1.0, 5.0, 2.0]), 5.0);
        // The radix sort against the comparison sort: small and large, signed zeros, infinities, NaNs,
        // subnormals and repeats.
        let mut rng = crate::geometry::Rng::new(3);
        for n in [0usize, 1, 7, 9000, 70_000] {
            let mut v: Vec<f32> = (0..n)
                .map(|k| match k % 11 {
                    0 => -0.0,
                    1 => 0.0,
                    2 => f32::INFINITY,
                    3 => f32::NEG_INFINITY,
                    4 => f32::from_bits(rng.uniform(1.0, 8e6) as u32),
                    5 => f32::NAN,
                    6 => -f32::NAN,
                    7 => 1.5,
                    _ => (rng.uniform(-1.0, 1.0) * 10f64.powf(rng.uniform(-30.0, 30.0))) as f32,
                })
                .collect();
            let mut want = v.clone();
            want.sort_by(f32::total_cmp);
            sort_f32(&mut v);
            let bits = |s: &[f32]| s.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&v), bits(&want), "{n}");
        }
        let mut v = [5.0f32, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(quantile_in_place_f32(&mut v, 0.5), 3.0);
        assert_eq!(quantile_in_place_f32(&mut v, 1.0), 5.0);
        assert_eq!(quantile_in_place_f32(&mut v, 0.0), 1.0);
    }
}
