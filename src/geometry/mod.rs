//! Geometry: the point cloud type, rigid transforms, pose errors and formats, random numbers.

pub mod cloud;
pub mod outer;
pub mod plane;
pub mod pose;
pub mod rng;
pub mod robot_formats;
pub mod transform;

pub use cloud::PointCloud;
pub use rng::Rng;

/// `floor(x)` as an integer without a libm call (the baseline x86-64 target has no floor instruction):
/// the same value as `x.floor() as i64` for every `x`, NaN (0) and the saturated ends included.
#[inline(always)]
pub fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn floor_i64_is_floor() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1.5,
            2.999_999_999,
            -2.000_000_001,
            1e18,
            -1e18,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
        ];
        let mut rng = super::Rng::new(7);
        xs.extend((0..10_000).map(|_| rng.uniform(-1e4, 1e4)));
        for x in xs {
            assert_eq!(super::floor_i64(x), x.floor() as i64, "{x}");
        }
    }
}
