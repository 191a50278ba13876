//! RealSense-like depth camera presets for the simulator.

use crate::camera::{DistortionModel, Intrinsics, DEFAULT_DEPTH_SCALE};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Depth stream resolution presets of a D4xx camera.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Resolution {
    /// 640x480 (D435 depth: fx = fy ≈ 383 px, 87°x62° field of view).
    #[default]
    #[serde(rename = "640x480")]
    Vga,
    /// 1280x720 (D435 depth: fx = fy ≈ 638 px).
    #[serde(rename = "1280x720")]
    Hd,
}

impl Resolution {
    /// `(width, height)` in pixels.
    pub fn size(self) -> (u32, u32) {
        match self {
            Resolution::Vga => (640, 480),
            Resolution::Hd => (1280, 720),
        }
    }
}

impl fmt::Display for Resolution {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (w, h) = self.size();
        write!(f, "{w}x{h}")
    }
}

impl FromStr for Resolution {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "640x480" | "vga" => Ok(Resolution::Vga),
            "1280x720" | "hd" | "720p" => Ok(Resolution::Hd),
            _ => Err(format!(
                "unknown resolution {s:?} (expected 640x480 or 1280x720)"
            )),
        }
    }
}

/// A simulated stereo depth camera: intrinsics of the depth stream, its range and the stereo baseline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimCamera {
    /// Intrinsics of the depth stream (what the cell's intrinsics JSON holds).
    pub intrinsics: Intrinsics,
    /// Nearest depth the camera returns, metres.
    pub min_depth_m: f64,
    /// Farthest depth the camera returns, metres.
    pub max_depth_m: f64,
    /// Distance from the depth origin (left imager) to the second imager along +x, metres (D435: 0.050).
    pub baseline_m: f64,
}

impl SimCamera {
    /// A D435-like depth camera at the given resolution: real-looking D4xx intrinsics (model
    /// `brown_conrady` with zero coefficients, as the depth stream reports), depth scale 1 mm, range
    /// 0.17–4 m at 640x480 (0.28–4 m at 1280x720), baseline 50 mm.
    pub fn d435(res: Resolution) -> Self {
        let (w, h) = res.size();
        let (f, ppx, ppy, min) = match res {
            Resolution::Vga => (382.6, 319.8, 238.9, 0.17),
            Resolution::Hd => (637.7, 639.7, 358.2, 0.28),
        };
        SimCamera {
            intrinsics: Intrinsics {
                fx: f,
                fy: f,
                ppx,
                ppy,
                coeffs: [0.0; 5],
                model: DistortionModel::BrownConrady,
                width: w,
                height: h,
                depth_scale: DEFAULT_DEPTH_SCALE,
                rms: None,
            },
            min_depth_m: min,
            max_depth_m: 4.0,
            baseline_m: 0.05,
        }
    }
}
