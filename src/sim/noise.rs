//! The depth noise model: what a RealSense D4xx-like stereo depth camera does to an ideal depth image.
//!
//! Applied per pixel, in this order (each step seeded per frame and per pixel, so the result does not depend
//! on the thread count):
//!
//! 1. **Lateral jitter**: the ray of pixel `(u, v)` is cast through `(u + δu, v + δv)`, `δ ~ N(0, σ_lat²)`
//!    (clamped to ±1 px): edges wobble by a fraction of a pixel, like stereo matching does.
//! 2. **Stereo shadow** (optional): a point the second imager (`baseline_m` to the right of the depth origin)
//!    cannot see, or that falls outside its image, has no depth — the band of missing depth on the left side
//!    of objects and of the image that D4xx cameras show.
//! 3. **Grazing incidence**: with θ the angle between the ray and the surface normal, a return is missing with
//!    probability rising linearly from 0 at `grazing_start_deg` to 1 at `grazing_end_deg`.
//! 4. **Random dropouts** with probability `dropout_prob`.
//! 5. **Flying pixels**: on a pixel whose 3x3 neighbourhood spans a depth jump larger than
//!    `flying_jump · z`, with probability `flying_prob` the depth becomes a random mix
//!    `α·z_near + (1 − α)·z_far` of the nearest and farthest depth around it.
//! 6. **Axial noise**: `z += N(0, σ(z)²)` with `σ(z) = axial_a_m + axial_b_per_m · z²` (metres).
//! 7. **Range limits and quantisation**: depths outside `[min_depth_m, max_depth_m]` of the camera become 0;
//!    the rest is rounded to the nearest multiple of `depth_scale`.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::str::FromStr;

/// Parameters of the depth noise model (see the module documentation). The defaults look like a RealSense
/// D435 at 640x480 and 0.5–1 m: σ ≈ 1.05 mm at 0.5 m, 2.7 mm at 1 m.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseConfig {
    /// Constant part of the axial (depth) noise standard deviation, metres (default 0.0005).
    pub axial_a_m: f64,
    /// Quadratic part of the axial noise: `σ(z) = axial_a_m + axial_b_per_m · z²`, 1/metre (default 0.0022,
    /// i.e. 2.2 mm at 1 m).
    pub axial_b_per_m: f64,
    /// Standard deviation of the lateral (sub-pixel) jitter of each pixel's ray, pixels (default 0.25).
    pub lateral_sigma_px: f64,
    /// Incidence angle (ray vs surface normal) at which returns start to go missing, degrees (default 75).
    pub grazing_start_deg: f64,
    /// Incidence angle beyond which no return survives, degrees (default 86).
    pub grazing_end_deg: f64,
    /// Probability of a random missing pixel, 0–1 (default 0.003).
    pub dropout_prob: f64,
    /// Probability that a pixel at a depth edge becomes a flying pixel, 0–1 (default 0.5).
    pub flying_prob: f64,
    /// Relative depth jump in a 3x3 neighbourhood that makes a pixel an edge pixel (default 0.03: 3 cm at 1 m).
    pub flying_jump: f64,
    /// Drop points the second imager cannot see (stereo shadow and the left invalid band) (default true).
    pub stereo_shadow: bool,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            axial_a_m: 0.0005,
            axial_b_per_m: 0.0022,
            lateral_sigma_px: 0.25,
            grazing_start_deg: 75.0,
            grazing_end_deg: 86.0,
            dropout_prob: 0.003,
            flying_prob: 0.5,
            flying_jump: 0.03,
            stereo_shadow: true,
        }
    }
}

impl NoiseConfig {
    /// An ideal sensor: no noise, no jitter, no missing returns, no flying pixels, no shadows (depth is still
    /// quantised by the depth scale and limited to the camera's range).
    pub fn none() -> Self {
        NoiseConfig {
            axial_a_m: 0.0,
            axial_b_per_m: 0.0,
            lateral_sigma_px: 0.0,
            grazing_start_deg: 90.0,
            grazing_end_deg: 90.0,
            dropout_prob: 0.0,
            flying_prob: 0.0,
            flying_jump: 0.03,
            stereo_shadow: false,
        }
    }

    /// The default model with its magnitudes (axial σ, lateral jitter, dropout and flying-pixel
    /// probabilities) multiplied by `s`; `s = 0` gives [`NoiseConfig::none`].
    pub fn scaled(s: f64) -> Self {
        if s <= 0.0 {
            return Self::none();
        }
        let d = Self::default();
        NoiseConfig {
            axial_a_m: d.axial_a_m * s,
            axial_b_per_m: d.axial_b_per_m * s,
            lateral_sigma_px: d.lateral_sigma_px * s,
            dropout_prob: (d.dropout_prob * s).min(1.0),
            flying_prob: (d.flying_prob * s).min(1.0),
            ..d
        }
    }

    /// Axial noise standard deviation at depth `z` (metres), metres.
    #[inline]
    pub fn axial_sigma(&self, z: f64) -> f64 {
        self.axial_a_m + self.axial_b_per_m * z * z
    }

    /// True when the model changes nothing but quantisation.
    pub fn is_ideal(&self) -> bool {
        self.axial_a_m == 0.0
            && self.axial_b_per_m == 0.0
            && self.lateral_sigma_px == 0.0
            && self.grazing_start_deg >= 90.0
            && self.dropout_prob == 0.0
            && self.flying_prob == 0.0
            && !self.stereo_shadow
    }

    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("noise.{field}"),
                msg,
            })
        };
        for (f, v) in [
            ("axial_a_m", self.axial_a_m),
            ("axial_b_per_m", self.axial_b_per_m),
            ("lateral_sigma_px", self.lateral_sigma_px),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(f, format!("must be ≥ 0, found {v}"));
            }
        }
        for (f, v) in [
            ("dropout_prob", self.dropout_prob),
            ("flying_prob", self.flying_prob),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return bad(f, format!("must be in [0, 1], found {v}"));
            }
        }
        if !(self.flying_jump.is_finite() && self.flying_jump > 0.0) {
            return bad(
                "flying_jump",
                format!("must be positive, found {}", self.flying_jump),
            );
        }
        if !(0.0..=90.0).contains(&self.grazing_start_deg)
            || !(self.grazing_start_deg..=90.0).contains(&self.grazing_end_deg)
        {
            return bad(
                "grazing_end_deg",
                format!(
                    "need 0 ≤ grazing_start_deg ({}) ≤ grazing_end_deg ({}) ≤ 90",
                    self.grazing_start_deg, self.grazing_end_deg
                ),
            );
        }
        Ok(())
    }

    /// Probability that a return at incidence angle with cosine `cos_theta` is missing.
    #[inline]
    #[cfg_attr(not(feature = "sim"), allow(dead_code))]
    pub(crate) fn grazing_drop_prob(&self, cos_theta: f64) -> f64 {
        if self.grazing_start_deg >= 90.0 || cos_theta >= self.grazing_start_deg.to_radians().cos()
        {
            return 0.0;
        }
        let theta = cos_theta.clamp(0.0, 1.0).acos().to_degrees();
        if theta >= self.grazing_end_deg {
            1.0
        } else {
            (theta - self.grazing_start_deg) / (self.grazing_end_deg - self.grazing_start_deg)
        }
    }
}

/// A named noise level: `none`, `low` (×0.5), `default` (×1), `high` (×2), or a scale factor.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseLevel {
    /// An ideal sensor ([`NoiseConfig::none`]).
    None,
    /// Half the default magnitudes.
    Low,
    /// The defaults (a D435 at 0.5–1 m).
    Default,
    /// Twice the default magnitudes.
    High,
    /// The default magnitudes times this factor.
    Scale(f64),
}

impl NoiseLevel {
    /// The scale factor of the level.
    pub fn factor(self) -> f64 {
        match self {
            NoiseLevel::None => 0.0,
            NoiseLevel::Low => 0.5,
            NoiseLevel::Default => 1.0,
            NoiseLevel::High => 2.0,
            NoiseLevel::Scale(s) => s,
        }
    }

    /// The noise model of the level.
    pub fn config(self) -> NoiseConfig {
        NoiseConfig::scaled(self.factor())
    }
}

impl FromStr for NoiseLevel {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" | "off" | "0" => Ok(NoiseLevel::None),
            "low" => Ok(NoiseLevel::Low),
            "default" | "normal" => Ok(NoiseLevel::Default),
            "high" => Ok(NoiseLevel::High),
            other => match other.parse::<f64>() {
                Ok(v) if v.is_finite() && v >= 0.0 => Ok(NoiseLevel::Scale(v)),
                _ => Err(format!(
                    "unknown noise level {s:?} (expected none, low, default, high or a factor ≥ 0)"
                )),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_and_sigma() {
        let d = NoiseConfig::default();
        assert!((d.axial_sigma(0.5) - 0.00105).abs() < 1e-9);
        assert!((d.axial_sigma(1.0) - 0.0027).abs() < 1e-9);
        assert!("none".parse::<NoiseLevel>().unwrap().config().is_ideal());
        assert_eq!("2.5".parse::<NoiseLevel>().unwrap(), NoiseLevel::Scale(2.5));
        assert!("loud".parse::<NoiseLevel>().is_err());
        assert_eq!(NoiseLevel::High.config().axial_a_m, 0.001);
        d.validate().unwrap();
        assert!(NoiseConfig {
            dropout_prob: 2.0,
            ..d.clone()
        }
        .validate()
        .is_err());
        assert_eq!(d.grazing_drop_prob(1.0), 0.0);
        assert_eq!(d.grazing_drop_prob(0.0), 1.0);
    }
}
