//! The report of `intrinsics`: [`IntrinsicsReport`]. Plain data; built from a calibration with the cargo
//! feature `vision`.

use crate::camera::Intrinsics;
use crate::cell::Board;
use serde::Serialize;

/// The schema name and version of [`IntrinsicsReport`].
pub const INTRINSICS_SCHEMA: &str = "depthcal.intrinsics/1";

/// One view used by the calibration.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ViewReport {
    /// The image's name (its path as given).
    pub name: String,
    /// RMS reprojection error over the view's corners, pixels.
    pub rms_px: f64,
    /// Largest corner reprojection error, pixels.
    pub max_px: f64,
    /// Corners of the view used (a ChArUco view may show part of the board).
    pub corners: usize,
}

/// An image the calibration did not use.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RejectedImage {
    /// The image's name (its path as given).
    pub image: String,
    /// Why it was not used (board not found, unreadable, other size).
    pub reason: String,
}

/// 1-σ of the estimated intrinsics (0 for a parameter held fixed).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IntrinsicsSigma {
    /// Of `fx`, pixels.
    pub fx: f64,
    /// Of `fy`, pixels.
    pub fy: f64,
    /// Of `ppx`, pixels.
    pub ppx: f64,
    /// Of `ppy`, pixels.
    pub ppy: f64,
    /// Of `k1, k2, p1, p2, k3` (dimensionless).
    pub coeffs: [f64; 5],
}

impl IntrinsicsSigma {
    /// From OpenCV's 1-σ of `[fx, fy, ppx, ppy, k1, k2, p1, p2, k3]`.
    pub fn new(s: &[f64; 9]) -> Self {
        IntrinsicsSigma {
            fx: s[0],
            fy: s[1],
            ppx: s[2],
            ppy: s[3],
            coeffs: [s[4], s[5], s[6], s[7], s[8]],
        }
    }
}

/// Camera intrinsics calibrated from board images, as `depthcal intrinsics --json` prints it: the fields of
/// the cell dataset's intrinsics file (`fx` ... `rms`, at the top level, so the object reads as one) plus
/// the board, the views and the 1-σ.
#[derive(Clone, Debug, Serialize)]
pub struct IntrinsicsReport {
    /// [`INTRINSICS_SCHEMA`].
    pub schema: &'static str,
    /// The intrinsics (pixels; `brown_conrady`; `rms` is the RMS reprojection error over all corners,
    /// pixels; `depth_scale` is the default and means nothing here).
    #[serde(flatten)]
    pub intrinsics: Intrinsics,
    /// The board (lengths in metres).
    pub board: Board,
    /// The views used, in input order.
    pub views: Vec<ViewReport>,
    /// The images not used.
    pub rejected: Vec<RejectedImage>,
    /// 1-σ of the intrinsics.
    pub sigma: IntrinsicsSigma,
    /// The configuration used (`IntrinsicsConfig`, with the command's flags applied).
    pub config: serde_json::Value,
}

#[cfg(feature = "vision")]
impl IntrinsicsReport {
    /// The report of the calibration `c` of `board` with the configuration `cfg`.
    pub fn new(
        c: &crate::vision::intrinsics::IntrinsicCalibration,
        board: &Board,
        cfg: &crate::vision::intrinsics::IntrinsicsConfig,
    ) -> crate::Result<Self> {
        let config = serde_json::to_value(cfg)
            .map_err(|e| crate::Error::Failed(format!("serialising the configuration: {e}")))?;
        Ok(IntrinsicsReport {
            schema: INTRINSICS_SCHEMA,
            intrinsics: c.intrinsics.clone(),
            board: *board,
            views: c
                .views
                .iter()
                .map(|v| ViewReport {
                    name: v.name.clone(),
                    rms_px: v.rms_px,
                    max_px: v.max_px,
                    corners: v.corners,
                })
                .collect(),
            rejected: c
                .rejected
                .iter()
                .map(|(image, reason)| RejectedImage {
                    image: image.clone(),
                    reason: reason.clone(),
                })
                .collect(),
            sigma: IntrinsicsSigma::new(&c.sigma),
            config,
        })
    }
}
