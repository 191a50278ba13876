//! Camera intrinsics: librealsense's `rs2_intrinsics` plus the depth scale, with JSON I/O.

use super::distortion::{distort, undistort, DistortionModel};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Default depth scale: 1 mm per depth unit (RealSense D400 default, Kinect, Redwood, 7-Scenes).
pub const DEFAULT_DEPTH_SCALE: f64 = 0.001;

/// The largest image side depthcal accepts, pixels (depth cameras are at most a few thousand pixels wide).
pub const MAX_IMAGE_SIDE: u32 = 16384;
/// The largest image area depthcal accepts, pixels (64 Mpx: a 512 MB ray table, a 128 MB depth image).
pub const MAX_IMAGE_PIXELS: u64 = 1 << 26;

/// Checks an image size from a header or intrinsics against [`MAX_IMAGE_SIDE`] and [`MAX_IMAGE_PIXELS`], so
/// that a hostile size is an error before anything of that size is allocated.
pub fn check_image_size(width: u32, height: u32) -> std::result::Result<(), String> {
    if width > MAX_IMAGE_SIDE
        || height > MAX_IMAGE_SIDE
        || width as u64 * height as u64 > MAX_IMAGE_PIXELS
    {
        return Err(format!(
            "{width}x{height} pixels is larger than depthcal accepts (at most {MAX_IMAGE_SIDE} per side and \
             {MAX_IMAGE_PIXELS} pixels)"
        ));
    }
    Ok(())
}

fn default_depth_scale() -> f64 {
    DEFAULT_DEPTH_SCALE
}

/// Intrinsics of a (depth) camera: the fields of librealsense's `rs2_intrinsics` plus `depth_scale`.
///
/// Pixel coordinates follow librealsense: `(0, 0)` is the centre of the top-left pixel, `x` to the right,
/// `y` down; the camera frame has `z` forward. A camera-frame point `(X, Y, Z)` (metres) projects to
/// `u = x_d·fx + ppx`, `v = y_d·fy + ppy` where `(x_d, y_d)` is `(X/Z, Y/Z)` after the distortion model.
///
/// JSON (what `depthcal intrinsics --json` writes and the cell dataset references):
/// `{"fx": 615.0, "fy": 615.0, "ppx": 320.0, "ppy": 240.0, "coeffs": [0,0,0,0,0], "model": "none",
///   "width": 640, "height": 480, "depth_scale": 0.001, "rms": 0.21}` — `coeffs`, `model`, `depth_scale`
/// and `rms` are optional (zeros, `none`, 0.001 and absent). [`Intrinsics::from_json_file`] also reads the
/// Open3D `PinholeCameraIntrinsic` JSON (`width`, `height`, column-major `intrinsic_matrix`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (from the centre of the top-left pixel).
    pub ppx: f64,
    /// Principal point y, pixels.
    pub ppy: f64,
    /// Distortion coefficients (meaning depends on `model`; see [`crate::camera::distortion`]).
    #[serde(default)]
    pub coeffs: [f64; 5],
    /// Distortion model.
    #[serde(default)]
    pub model: DistortionModel,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Metres per depth-image unit (default 0.001: millimetres).
    #[serde(default = "default_depth_scale")]
    pub depth_scale: f64,
    /// RMS reprojection error of the calibration that produced these intrinsics, pixels (informative).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms: Option<f64>,
}

#[derive(Deserialize)]
struct Open3dPinhole {
    width: u32,
    height: u32,
    intrinsic_matrix: [f64; 9],
}

impl Intrinsics {
    /// Pinhole intrinsics without distortion, depth in millimetres.
    pub fn pinhole(width: u32, height: u32, fx: f64, fy: f64, ppx: f64, ppy: f64) -> Self {
        Intrinsics {
            fx,
            fy,
            ppx,
            ppy,
            coeffs: [0.0; 5],
            model: DistortionModel::None,
            width,
            height,
            depth_scale: DEFAULT_DEPTH_SCALE,
            rms: None,
        }
    }

    /// Checks that the values are usable (positive finite focal lengths, size and depth scale; finite
    /// principal point and coefficients). The message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        for (name, v) in [
            ("fx", self.fx),
            ("fy", self.fy),
            ("depth_scale", self.depth_scale),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "field `{name}` must be a positive number, found {v}"
                ));
            }
        }
        for (name, v) in [("ppx", self.ppx), ("ppy", self.ppy)] {
            if !v.is_finite() {
                return Err(format!("field `{name}` must be finite, found {v}"));
            }
        }
        if self.coeffs.iter().any(|c| !c.is_finite()) {
            return Err("field `coeffs` has a NaN or infinite entry".into());
        }
        if self.width == 0 || self.height == 0 {
            return Err(format!(
                "fields `width` and `height` must be positive, found {}x{}",
                self.width, self.height
            ));
        }
        check_image_size(self.width, self.height)
            .map_err(|m| format!("fields `width` and `height`: {m}"))?;
        Ok(())
    }

    /// Parses intrinsics JSON (depthcal/RealSense fields, or Open3D pinhole JSON); `path` names the source in
    /// errors.
    pub fn from_json_str(text: &str, path: &Path) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
        let intr = if value.get("intrinsic_matrix").is_some() && value.get("fx").is_none() {
            let o: Open3dPinhole = serde_json::from_value(value)
                .map_err(|e| Error::format(path, format!("Open3D pinhole intrinsics: {e}")))?;
            let k = o.intrinsic_matrix; // column-major
            Intrinsics::pinhole(o.width, o.height, k[0], k[4], k[6], k[7])
        } else {
            let has_model = value.get("model").is_some();
            let intr: Intrinsics = serde_json::from_value(value).map_err(|e| {
                Error::format(
                    path,
                    format!(
                        "intrinsics: {e} (expected fields fx, fy, ppx, ppy, width, height; optional \
                         coeffs, model, depth_scale, rms)"
                    ),
                )
            })?;
            if !has_model && intr.coeffs.iter().any(|&c| c != 0.0) {
                return Err(Error::format(
                    path,
                    "field `model` is missing but `coeffs` are not all zero; name the distortion model \
                     (none, brown_conrady, inverse_brown_conrady, kannala_brandt4)",
                ));
            }
            intr
        };
        intr.validate().map_err(|m| Error::format(path, m))?;
        Ok(intr)
    }

    /// Reads an intrinsics JSON file (see [`Intrinsics::from_json_str`]).
    pub fn from_json_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_json_str(&text, path)
    }

    /// The JSON text (pretty-printed, fields `fx, fy, ppx, ppy, coeffs, model, width, height, depth_scale`
    /// and `rms` when known).
    pub fn to_json_string(&self) -> String {
        serde_json::to_string_pretty(self).expect("intrinsics serialise")
    }

    /// Writes the JSON atomically.
    pub fn write_json_file(&self, path: impl AsRef<Path>) -> Result<()> {
        let text = self.to_json_string();
        crate::io::write_atomically(path.as_ref(), |w| {
            w.write_all(text.as_bytes())?;
            w.write_all(b"\n")
        })
    }

    /// Projects a camera-frame point (metres, `z > 0`) to pixel coordinates `[u, v]`.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let (xd, yd) = distort(self.model, &self.coeffs, x, y);
        [xd * self.fx + self.ppx, yd * self.fy + self.ppy]
    }

    /// The ray through pixel `[u, v]` as normalised coordinates `(X/Z, Y/Z)`.
    pub fn pixel_ray(&self, px: [f64; 2]) -> [f64; 2] {
        let xd = (px[0] - self.ppx) / self.fx;
        let yd = (px[1] - self.ppy) / self.fy;
        let (x, y) = undistort(self.model, &self.coeffs, xd, yd);
        [x, y]
    }

    /// Deprojects pixel `[u, v]` with depth `z` (metres along the optical axis) to a camera-frame point.
    pub fn deproject(&self, px: [f64; 2], z: f64) -> [f64; 3] {
        let [x, y] = self.pixel_ray(px);
        [x * z, y * z, z]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn realsense_like(model: DistortionModel, coeffs: [f64; 5]) -> Intrinsics {
        Intrinsics {
            model,
            coeffs,
            ..Intrinsics::pinhole(1280, 720, 910.2, 909.7, 641.3, 358.9)
        }
    }

    #[test]
    fn project_deproject_round_trip_at_the_corners() {
        let models = [
            realsense_like(DistortionModel::None, [0.0; 5]),
            realsense_like(
                DistortionModel::BrownConrady,
                [0.15, -0.45, 0.0012, -0.0008, 0.38],
            ),
            realsense_like(
                DistortionModel::InverseBrownConrady,
                [-0.055, 0.065, -0.0004, 0.0007, -0.021],
            ),
            realsense_like(
                DistortionModel::KannalaBrandt4,
                [-0.0045, 0.039, -0.037, 0.0062, 0.0],
            ),
        ];
        for intr in &models {
            let (w, h) = (intr.width as f64 - 1.0, intr.height as f64 - 1.0);
            for px in [
                [0.0, 0.0],
                [w, 0.0],
                [0.0, h],
                [w, h],
                [w / 2.0, h / 2.0],
                [intr.ppx, intr.ppy],
            ] {
                for z in [0.3, 1.7, 6.0] {
                    let p = intr.deproject(px, z);
                    assert!((p[2] - z).abs() < 1e-12);
                    let back = intr.project(p);
                    let err = ((back[0] - px[0]).powi(2) + (back[1] - px[1]).powi(2)).sqrt();
                    assert!(
                        err < 1e-6,
                        "{}: pixel {px:?} came back as {back:?}",
                        intr.model
                    );
                }
            }
            // The corner ray differs from the pinhole ray when there is distortion.
            let pin = Intrinsics {
                model: DistortionModel::None,
                ..intr.clone()
            };
            let d = intr.pixel_ray([0.0, 0.0]);
            let p = pin.pixel_ray([0.0, 0.0]);
            if intr.model != DistortionModel::None {
                assert!((d[0] - p[0]).abs() > 1e-3, "{}", intr.model);
            }
        }
    }

    #[test]
    fn json_round_trip_and_errors() {
        let intr = realsense_like(
            DistortionModel::InverseBrownConrady,
            [0.1, 0.2, 0.0, 0.0, 0.3],
        );
        let text = intr.to_json_string();
        assert!(text.contains("\"inverse_brown_conrady\""));
        let back = Intrinsics::from_json_str(&text, Path::new("x.json")).unwrap();
        assert_eq!(back, intr);
        let missing = r#"{"fx": 600, "ppx": 320, "ppy": 240, "width": 640, "height": 480}"#;
        let e = Intrinsics::from_json_str(missing, Path::new("cam.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cam.json") && e.contains("fy"), "{e}");
        let neg = r#"{"fx": -600, "fy": 600, "ppx": 320, "ppy": 240, "width": 640, "height": 480}"#;
        assert!(Intrinsics::from_json_str(neg, Path::new("n.json")).is_err());
        let o3d = r#"{"width": 640, "height": 480, "intrinsic_matrix": [525.0,0,0,0,525.0,0,319.5,239.5,1]}"#;
        let o = Intrinsics::from_json_str(o3d, Path::new("o.json")).unwrap();
        assert_eq!(
            (o.fx, o.fy, o.ppx, o.ppy, o.width),
            (525.0, 525.0, 319.5, 239.5, 640)
        );
        assert_eq!(o.depth_scale, 0.001);
    }
}
