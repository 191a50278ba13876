//! Lens distortion models, with librealsense's `rsutil.h` semantics.
//!
//! All functions work on *normalised* image coordinates: `x = X/Z`, `y = Y/Z` for a camera-frame point
//! `(X, Y, Z)` (dimensionless). Pixel coordinates follow from `u = x·fx + ppx`, `v = y·fy + ppy` (see
//! [`crate::camera::Intrinsics`]).
//!
//! | model | `coeffs` | project (point → pixel) | deproject (pixel → ray) |
//! |---|---|---|---|
//! | `none` | ignored | pinhole | pinhole |
//! | `brown_conrady` | k1, k2, p1, p2, k3 | closed form: radial on the undistorted point, tangential on the undistorted point | fixed-point iteration |
//! | `inverse_brown_conrady` | k1, k2, p1, p2, k3 | closed form: radial first, tangential on the radially distorted point | fixed-point iteration |
//! | `kannala_brandt4` | k1, k2, k3, k4, (unused) | `θ_d = θ(1 + k1θ² + k2θ⁴ + k3θ⁶ + k4θ⁸)` with `θ = atan r` | Newton on θ |
//!
//! The iterations converge to the exact inverse of the closed form (librealsense uses 10 fixed-point
//! iterations in `f32`; depthcal iterates in `f64` until the step is below 1e-14 or 100 iterations).

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;
use std::str::FromStr;

/// A lens distortion model (the subset of librealsense's `rs2_distortion` that depth cameras use).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum DistortionModel {
    /// Rectilinear pinhole, no distortion (`RS2_DISTORTION_NONE`).
    #[default]
    None,
    /// Brown-Conrady (OpenCV `plumb_bob`): coefficients distort an ideal point (`RS2_DISTORTION_BROWN_CONRADY`).
    BrownConrady,
    /// Inverse Brown-Conrady (`RS2_DISTORTION_INVERSE_BROWN_CONRADY`): tangential terms act on the radially
    /// distorted point, as librealsense computes it.
    InverseBrownConrady,
    /// Kannala-Brandt equidistant fisheye with four coefficients (`RS2_DISTORTION_KANNALA_BRANDT4`, OpenCV
    /// `fisheye`, ROS `equidistant`).
    KannalaBrandt4,
}

impl DistortionModel {
    /// The canonical name written to JSON and TOML.
    pub fn name(self) -> &'static str {
        match self {
            DistortionModel::None => "none",
            DistortionModel::BrownConrady => "brown_conrady",
            DistortionModel::InverseBrownConrady => "inverse_brown_conrady",
            DistortionModel::KannalaBrandt4 => "kannala_brandt4",
        }
    }
}

impl fmt::Display for DistortionModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for DistortionModel {
    type Err = String;
    /// Accepts the canonical names and the usual aliases: librealsense's enum names and display names
    /// (`RS2_DISTORTION_BROWN_CONRADY`, `Brown Conrady`, `distortion.inverse_brown_conrady`), ROS/OpenCV names
    /// (`plumb_bob`, `equidistant`, `fisheye`).
    fn from_str(s: &str) -> Result<Self, String> {
        let mut n = s.trim().to_ascii_lowercase().replace([' ', '-'], "_");
        for prefix in ["rs2_distortion_", "distortion."] {
            if let Some(rest) = n.strip_prefix(prefix) {
                n = rest.to_string();
            }
        }
        match n.as_str() {
            "none" | "pinhole" | "" => Ok(DistortionModel::None),
            "brown_conrady" | "plumb_bob" | "radtan" => Ok(DistortionModel::BrownConrady),
            "inverse_brown_conrady" => Ok(DistortionModel::InverseBrownConrady),
            "kannala_brandt4" | "kannala_brandt" | "equidistant" | "fisheye" => {
                Ok(DistortionModel::KannalaBrandt4)
            }
            "modified_brown_conrady" => Err(format!(
                "distortion model {s:?} is a forward model that librealsense itself cannot deproject; \
                 depthcal does not support it for depth images"
            )),
            _ => Err(format!(
                "unknown distortion model {s:?} (expected none, brown_conrady, inverse_brown_conrady or \
                 kannala_brandt4)"
            )),
        }
    }
}

impl Serialize for DistortionModel {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for DistortionModel {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

const MAX_ITER: usize = 100;
const STEP_TOL: f64 = 1e-14;

/// Brown-Conrady coefficients that are all zero: both directions are the identity (for finite input the
/// general formulas give the same numbers, one iteration for the inverse; RealSense depth streams report
/// zeros).
#[inline]
fn no_terms(c: &[f64; 5]) -> bool {
    c.iter().all(|&v| v == 0.0)
}

/// Applies the distortion: ideal normalised coordinates → distorted normalised coordinates (the
/// projection direction, librealsense's `rs2_project_point_to_pixel` before the focal length).
pub fn distort(model: DistortionModel, c: &[f64; 5], x: f64, y: f64) -> (f64, f64) {
    match model {
        DistortionModel::None => (x, y),
        DistortionModel::BrownConrady | DistortionModel::InverseBrownConrady if no_terms(c) => {
            (x, y)
        }
        DistortionModel::BrownConrady => {
            let r2 = x * x + y * y;
            let f = 1.0 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2;
            let dx = x * f + 2.0 * c[2] * x * y + c[3] * (r2 + 2.0 * x * x);
            let dy = y * f + 2.0 * c[3] * x * y + c[2] * (r2 + 2.0 * y * y);
            (dx, dy)
        }
        DistortionModel::InverseBrownConrady => {
            let r2 = x * x + y * y;
            let f = 1.0 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2;
            let (x, y) = (x * f, y * f);
            let dx = x + 2.0 * c[2] * x * y + c[3] * (r2 + 2.0 * x * x);
            let dy = y + 2.0 * c[3] * x * y + c[2] * (r2 + 2.0 * y * y);
            (dx, dy)
        }
        DistortionModel::KannalaBrandt4 => {
            let r = (x * x + y * y).sqrt().max(f64::EPSILON);
            let theta = r.atan();
            let t2 = theta * theta;
            let series = 1.0 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3])));
            let rd = theta * series;
            (x * rd / r, y * rd / r)
        }
    }
}

/// [`undistort`] returns its input unchanged (no model, or a Brown-Conrady variant without terms): pixel
/// rays are then separable, `x` from the column alone and `y` from the row alone.
pub fn undistort_is_identity(model: DistortionModel, c: &[f64; 5]) -> bool {
    match model {
        DistortionModel::None => true,
        DistortionModel::BrownConrady | DistortionModel::InverseBrownConrady => no_terms(c),
        DistortionModel::KannalaBrandt4 => false,
    }
}

/// Removes the distortion: distorted normalised coordinates → ideal normalised coordinates (the
/// deprojection direction, librealsense's `rs2_deproject_pixel_to_point` after the focal length).
///
/// The Brown-Conrady variants use librealsense's fixed-point iteration; Kannala-Brandt uses Newton's method
/// on θ. For a point inside the model's valid region `undistort(distort(p)) == p` to ~1e-12.
pub fn undistort(model: DistortionModel, c: &[f64; 5], xd: f64, yd: f64) -> (f64, f64) {
    match model {
        DistortionModel::None => (xd, yd),
        DistortionModel::BrownConrady | DistortionModel::InverseBrownConrady if no_terms(c) => {
            (xd, yd)
        }
        DistortionModel::BrownConrady => {
            let (mut x, mut y) = (xd, yd);
            for _ in 0..MAX_ITER {
                let r2 = x * x + y * y;
                let icdist = 1.0 / (1.0 + ((c[4] * r2 + c[1]) * r2 + c[0]) * r2);
                let delta_x = 2.0 * c[2] * x * y + c[3] * (r2 + 2.0 * x * x);
                let delta_y = 2.0 * c[3] * x * y + c[2] * (r2 + 2.0 * y * y);
                let (nx, ny) = ((xd - delta_x) * icdist, (yd - delta_y) * icdist);
                let step = (nx - x).abs() + (ny - y).abs();
                x = nx;
                y = ny;
                if step < STEP_TOL {
                    break;
                }
            }
            (x, y)
        }
        DistortionModel::InverseBrownConrady => {
            let (mut x, mut y) = (xd, yd);
            for _ in 0..MAX_ITER {
                let r2 = x * x + y * y;
                let icdist = 1.0 / (1.0 + ((c[4] * r2 + c[1]) * r2 + c[0]) * r2);
                let xq = x / icdist;
                let yq = y / icdist;
                let delta_x = 2.0 * c[2] * xq * yq + c[3] * (r2 + 2.0 * xq * xq);
                let delta_y = 2.0 * c[3] * xq * yq + c[2] * (r2 + 2.0 * yq * yq);
                let (nx, ny) = ((xd - delta_x) * icdist, (yd - delta_y) * icdist);
                let step = (nx - x).abs() + (ny - y).abs();
                x = nx;
                y = ny;
                if step < STEP_TOL {
                    break;
                }
            }
            (x, y)
        }
        DistortionModel::KannalaBrandt4 => {
            let rd = (xd * xd + yd * yd).sqrt().max(f64::EPSILON);
            let mut theta = rd;
            for _ in 0..MAX_ITER {
                let t2 = theta * theta;
                let f = theta * (1.0 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3])))) - rd;
                let df = 1.0
                    + t2 * (3.0 * c[0] + t2 * (5.0 * c[1] + t2 * (7.0 * c[2] + 9.0 * t2 * c[3])));
                let step = f / df;
                theta -= step;
                if step.abs() < STEP_TOL {
                    break;
                }
            }
            let r = theta.tan();
            (xd * r / rd, yd * r / rd)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_with_aliases() {
        for m in [
            DistortionModel::None,
            DistortionModel::BrownConrady,
            DistortionModel::InverseBrownConrady,
            DistortionModel::KannalaBrandt4,
        ] {
            assert_eq!(m.name().parse::<DistortionModel>().unwrap(), m);
        }
        assert_eq!(
            "RS2_DISTORTION_INVERSE_BROWN_CONRADY"
                .parse::<DistortionModel>()
                .unwrap(),
            DistortionModel::InverseBrownConrady
        );
        assert_eq!(
            "Brown Conrady".parse::<DistortionModel>().unwrap(),
            DistortionModel::BrownConrady
        );
        assert_eq!(
            "equidistant".parse::<DistortionModel>().unwrap(),
            DistortionModel::KannalaBrandt4
        );
        assert!("modified_brown_conrady".parse::<DistortionModel>().is_err());
        assert!("zernike".parse::<DistortionModel>().is_err());
    }

    #[test]
    fn distortion_is_not_identity_and_inverts() {
        let bc = [0.12, -0.25, 0.001, -0.0015, 0.08];
        let kb = [-0.01, 0.05, -0.06, 0.02, 0.0];
        for (m, c) in [
            (DistortionModel::BrownConrady, bc),
            (DistortionModel::InverseBrownConrady, bc),
            (DistortionModel::KannalaBrandt4, kb),
        ] {
            for &(x, y) in &[
                (0.6, 0.45),
                (-0.6, 0.45),
                (0.0, -0.5),
                (0.3, 0.0),
                (1e-9, 0.0),
            ] {
                let (xd, yd) = distort(m, &c, x, y);
                if x.abs() > 0.1 {
                    assert!((xd - x).abs() > 1e-4, "{m}: distortion had no effect");
                }
                let (xu, yu) = undistort(m, &c, xd, yd);
                assert!(
                    (xu - x).abs() < 1e-10 && (yu - y).abs() < 1e-10,
                    "{m}: {x},{y} -> {xu},{yu}"
                );
            }
        }
    }

    /// Where `undistort_is_identity` says so, `undistort` returns its input bit for bit; a camera with
    /// terms is never called the identity.
    #[test]
    fn the_identity_is_the_identity() {
        let terms = [0.1, -0.2, 0.001, -0.002, 0.05];
        let models = [
            DistortionModel::None,
            DistortionModel::BrownConrady,
            DistortionModel::InverseBrownConrady,
            DistortionModel::KannalaBrandt4,
        ];
        let mut identities = 0;
        for m in models {
            assert!(!undistort_is_identity(m, &terms) || m == DistortionModel::None);
            for c in [[0.0; 5], terms] {
                if !undistort_is_identity(m, &c) {
                    continue;
                }
                identities += 1;
                for k in 0..1000 {
                    let (x, y) = (
                        (k as f64 * 0.731).sin() * 0.9,
                        (k as f64 * 1.37).cos() * 0.7,
                    );
                    let (ux, uy) = undistort(m, &c, x, y);
                    assert_eq!((ux.to_bits(), uy.to_bits()), (x.to_bits(), y.to_bits()));
                }
            }
        }
        assert_eq!(
            identities, 4,
            "None twice, the two Brown-Conrady variants without terms"
        );
    }
}
