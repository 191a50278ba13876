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
        let mut v = [5.0f32, 1.0, 4.0, 2.0, 3.0];
        assert_eq!(quantile_in_place_f32(&mut v, 0.5), 3.0);
        assert_eq!(quantile_in_place_f32(&mut v, 1.0), 5.0);
        assert_eq!(quantile_in_place_f32(&mut v, 0.0), 1.0);
    }
}
