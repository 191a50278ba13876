//! How precisely a calibration's registration pins its answer: the largest 1-σ over rotation directions and
//! over translation directions of the registration's own covariance (without the inputs': hand-eyes and
//! poses), and the bound a trusted result keeps within ([`CalibrateConfig::max_registration_sigma_deg`],
//! [`CalibrateConfig::max_registration_sigma_m`]).
//!
//! [`CalibrateConfig::max_registration_sigma_deg`]: crate::calibration::config::CalibrateConfig::max_registration_sigma_deg
//! [`CalibrateConfig::max_registration_sigma_m`]: crate::calibration::config::CalibrateConfig::max_registration_sigma_m

use nalgebra::{Matrix3, Matrix6};

/// The largest 1-σ of a covariance of `[ω (rad), v (m)]` over rotation directions and over translation
/// directions: the square roots of the largest eigenvalues of its two diagonal blocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    /// Degrees.
    pub rotation_deg: f64,
    /// Metres.
    pub translation_m: f64,
}

impl Spread {
    /// The spread of `cov` (`[ω (rad), v (m)]`); a non-finite covariance has an infinite spread.
    pub fn of(cov: &Matrix6<f64>) -> Spread {
        let largest = |b: Matrix3<f64>| -> f64 {
            if !b.iter().all(|x| x.is_finite()) {
                return f64::INFINITY;
            }
            let sym = 0.5 * (b + b.transpose());
            sym.symmetric_eigenvalues().max().max(0.0).sqrt()
        };
        Spread {
            rotation_deg: largest(cov.fixed_view::<3, 3>(0, 0).into_owned()).to_degrees(),
            translation_m: largest(cov.fixed_view::<3, 3>(3, 3).into_owned()),
        }
    }

    /// Why a result of this spread is not trusted, when it exceeds `max_deg` (degrees) or `max_m` (metres)
    /// (`None`: no bound).
    pub fn excess(&self, max_deg: Option<f64>, max_m: Option<f64>) -> Option<String> {
        // A spread that is not a number exceeds every bound.
        let beyond = |v: f64, m: f64| v.is_nan() || v > m;
        let over_r = max_deg.is_some_and(|m| beyond(self.rotation_deg, m));
        let over_t = max_m.is_some_and(|m| beyond(self.translation_m, m));
        (over_r || over_t).then(|| {
            let bound = |v: Option<f64>, f: &dyn Fn(f64) -> String| v.map_or("none".into(), f);
            format!(
                "the geometry pins the answer only to {:.3}° / {:.1} mm (1-σ of the registration alone, the largest over directions), more than the {} / {} a trusted result may leave (max_registration_sigma_deg, max_registration_sigma_m)",
                self.rotation_deg,
                self.translation_m * 1e3,
                bound(max_deg, &|m| format!("{m}°")),
                bound(max_m, &|m| format!("{:.0} mm", m * 1e3)),
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spread_is_the_largest_direction_of_each_block() {
        let mut c = Matrix6::zeros();
        // Rotation: 0.5° and 0.1° along two axes, correlated; translation 3 mm along x+y.
        let (a, b) = (0.5f64.to_radians(), 0.1f64.to_radians());
        c[(0, 0)] = a * a;
        c[(1, 1)] = b * b;
        let t = 0.003f64 * 0.003 / 2.0;
        for (i, j) in [(3, 3), (3, 4), (4, 3), (4, 4)] {
            c[(i, j)] = t;
        }
        // Off-diagonal rotation-translation terms do not count.
        c[(0, 3)] = 1.0;
        c[(3, 0)] = 1.0;
        let s = Spread::of(&c);
        assert!((s.rotation_deg - 0.5).abs() < 1e-9, "{s:?}");
        assert!((s.translation_m - 0.003).abs() < 1e-12, "{s:?}");
        let mut bad = c;
        bad[(1, 1)] = f64::NAN;
        assert_eq!(Spread::of(&bad).rotation_deg, f64::INFINITY);
    }

    #[test]
    fn the_bounds_are_checked_and_may_be_turned_off() {
        use crate::calibration::config::CalibrateConfig;
        let d = CalibrateConfig::default();
        assert_eq!(d.max_registration_sigma_deg, Some(1.0));
        assert_eq!(d.max_registration_sigma_m, Some(0.02));
        d.validate().unwrap();
        let off = CalibrateConfig {
            max_registration_sigma_deg: None,
            max_registration_sigma_m: None,
            ..CalibrateConfig::default()
        };
        off.validate().unwrap();
        for bad in [0.0, -1.0, f64::NAN] {
            let e = CalibrateConfig {
                max_registration_sigma_deg: Some(bad),
                ..CalibrateConfig::default()
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("max_registration_sigma_deg"), "{e}");
            let e = CalibrateConfig {
                max_registration_sigma_m: Some(bad),
                ..CalibrateConfig::default()
            }
            .validate()
            .unwrap_err();
            assert!(e.to_string().contains("max_registration_sigma_m"), "{e}");
        }
    }

    #[test]
    fn only_a_spread_beyond_a_bound_is_a_reason() {
        let s = Spread {
            rotation_deg: 0.98,
            translation_m: 0.073,
        };
        assert_eq!(s.excess(Some(1.0), None), None);
        assert_eq!(s.excess(None, None), None);
        let why = s.excess(Some(1.0), Some(0.02)).unwrap();
        assert!(why.contains("0.980° / 73.0 mm"), "{why}");
        assert!(why.contains("1° / 20 mm"), "{why}");
        assert!(s.excess(Some(0.5), Some(0.1)).is_some());
        let nan = Spread {
            rotation_deg: f64::NAN,
            translation_m: 0.0,
        };
        assert!(nan.excess(Some(1.0), Some(0.02)).is_some());
    }
}
