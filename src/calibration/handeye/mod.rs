//! Hand-eye calibration in pure Rust: `T_ee_cam` (and `T_base_board`) from robot poses and board poses.
//!
//! # Conventions
//!
//! Eye-in-hand: the camera is on the flange, the board is fixed in the cell. Frame i gives the robot pose
//! `T_base_ee_i` and the board pose seen by the camera `T_cam_board_i`. The unknowns are `X = T_ee_cam` and
//! `Z = T_base_board`, with `T_base_ee_i · X · T_cam_board_i = Z` for every frame.
//!
//! * **AX = XB** (Tsai-Lenz, Park-Martin, Daniilidis): for a pair of frames `(i, j)`,
//!   `A = T_ee_i_ee_j = T_base_ee_i⁻¹ · T_base_ee_j` (robot motion), `B = T_cam_i_cam_j = T_cam_board_i ·
//!   T_cam_board_j⁻¹` (camera motion), `X = T_ee_cam`. `Z` then follows as the average of the per-frame
//!   `T_base_ee_i · X · T_cam_board_i` (rotation average, see [`crate::calibration::average`]).
//! * **AX = ZB** (robot-world; Shah, Li): per frame `Aᵢ = T_base_ee_i`, `X = T_ee_cam`, `Z = T_base_board`,
//!   `Bᵢ = T_board_cam_i = T_cam_board_i⁻¹`. Gives X and Z at once.
//! * **Refinement**: from the best closed form, Levenberg-Marquardt over X and Z together on the per-frame
//!   residual `Eᵢ = Z⁻¹ · T_base_ee_i · X · T_cam_board_i` (see [`refine`]), first with a Cauchy kernel,
//!   then outlier frames are rejected and the inliers refined again with a Huber kernel.
//!
//! * **Reprojection** (optional, [`reprojection`]): from a solution, `X` and `Z` refined on the reprojection
//!   error of the board's corners through the chain, when the corners are at hand (board images).
//!
//! Eye-to-hand (camera fixed in the cell, board on the flange): pass `T_board_cam_i = T_cam_board_i⁻¹` as
//! `t_cam_board`; the solver then returns `T_ee_board` in `t_ee_cam` and `T_base_cam` in `t_base_board`.
//!
//! # Pairs
//!
//! The AX=XB methods use every pair `i < j` of frames when there are at most
//! [`HandEyeConfig::max_pairs`] of them (all pairs for up to 200 frames by default); beyond that each frame is
//! paired with the next `max_pairs / n` frames. Pairs are only used for the closed forms and the
//! excitation/consistency checks; the refinement and the residuals work per frame, so each measurement
//! counts once.
//!
//! # Residuals
//!
//! Per frame: `rotation_deg` = angle of `Eᵢ`, `translation_mm` = `‖t(Eᵢ)‖`, the distance between the board
//! origin measured by the camera and the one predicted from the robot pose and `(X, Z)`.

pub mod ax_xb;
pub mod ax_zb;
pub mod depth;
pub mod refine;
pub mod reprojection;
mod solve;

pub use solve::calibrate_hand_eye;

use crate::calibration::average::{
    average_poses, rotation_angle_between, AverageConfig, PoseAverage,
};
use crate::error::{Error, Result};
use crate::geometry::Rng;
use crate::io::poses::PoseRecord;
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};
use refine::frame_error;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// One calibration frame: a robot pose and the board pose the camera saw there (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct HandEyeFrame {
    /// Frame id (from the pose files).
    pub id: String,
    /// The flange pose in the robot base, `T_base_ee`.
    pub t_base_ee: Isometry3<f64>,
    /// The board pose in the camera, `T_cam_board`.
    pub t_cam_board: Isometry3<f64>,
}

/// A pair of frames `(i, j)` as motions: `a = T_base_ee_i⁻¹ · T_base_ee_j`, `b = T_cam_board_i ·
/// T_cam_board_j⁻¹`, so that `a · T_ee_cam = T_ee_cam · b`.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// Index of the first frame.
    pub i: usize,
    /// Index of the second frame.
    pub j: usize,
    /// Robot motion `T_ee_i_ee_j`, metres.
    pub a: Isometry3<f64>,
    /// Camera motion `T_cam_i_cam_j`, metres.
    pub b: Isometry3<f64>,
}

/// The rotation vector (axis · angle, radians, angle in `[0, π]`) of a unit quaternion, accurate for tiny
/// angles.
pub fn log_rotation(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let q = q.quaternion();
    let (mut w, mut v) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let n = v.norm();
    if n < 1e-300 {
        return Vector3::zeros();
    }
    let angle = 2.0 * n.atan2(w);
    v * (angle / n)
}

/// The motion pairs of `frames` (see the module documentation for which pairs).
pub fn motion_pairs(frames: &[HandEyeFrame], max_pairs: usize) -> Vec<Motion> {
    let n = frames.len();
    let all = n * n.saturating_sub(1) / 2;
    let reach = if all <= max_pairs {
        n
    } else {
        (max_pairs / n.max(1)).max(1)
    };
    let mut out = Vec::new();
    for i in 0..n {
        for j in (i + 1)..n.min(i + 1 + reach) {
            let (fi, fj) = (&frames[i], &frames[j]);
            out.push(Motion {
                i,
                j,
                a: fi.t_base_ee.inverse() * fj.t_base_ee,
                b: fi.t_cam_board * fj.t_cam_board.inverse(),
            });
        }
    }
    out
}

/// A hand-eye closed form (or `Auto`: the closed form whose solution fits the frames best, robustly).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum HandEyeMethod {
    /// The best of all closed forms and of a least-median-of-squares search over frame triples (default).
    #[default]
    Auto,
    /// Tsai-Lenz (AX=XB, Gibbs vectors).
    TsaiLenz,
    /// Park-Martin (AX=XB, rotation vectors, Procrustes).
    ParkMartin,
    /// Daniilidis (AX=XB, dual quaternions).
    Daniilidis,
    /// Shah (AX=ZB, Kronecker product).
    Shah,
    /// Li, Wang and Wu (AX=ZB, joint linear system).
    Li,
}

impl HandEyeMethod {
    /// The closed forms, in the order they are reported.
    pub const CLOSED_FORMS: [HandEyeMethod; 5] = [
        HandEyeMethod::TsaiLenz,
        HandEyeMethod::ParkMartin,
        HandEyeMethod::Daniilidis,
        HandEyeMethod::Shah,
        HandEyeMethod::Li,
    ];

    /// The method's name (`auto`, `tsai-lenz`, `park-martin`, `daniilidis`, `shah`, `li`).
    pub fn name(self) -> &'static str {
        match self {
            HandEyeMethod::Auto => "auto",
            HandEyeMethod::TsaiLenz => "tsai-lenz",
            HandEyeMethod::ParkMartin => "park-martin",
            HandEyeMethod::Daniilidis => "daniilidis",
            HandEyeMethod::Shah => "shah",
            HandEyeMethod::Li => "li",
        }
    }
}

impl fmt::Display for HandEyeMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for HandEyeMethod {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().replace('_', "-").as_str() {
            "auto" => Ok(HandEyeMethod::Auto),
            "tsai" | "tsai-lenz" => Ok(HandEyeMethod::TsaiLenz),
            "park" | "park-martin" => Ok(HandEyeMethod::ParkMartin),
            "daniilidis" | "dual-quaternion" => Ok(HandEyeMethod::Daniilidis),
            "shah" => Ok(HandEyeMethod::Shah),
            "li" => Ok(HandEyeMethod::Li),
            _ => Err(format!(
                "unknown hand-eye method {s:?} (expected auto, tsai, park, daniilidis, shah or li)"
            )),
        }
    }
}

/// Hand-eye calibration settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandEyeConfig {
    /// The closed form that starts the refinement (or is the answer without refinement). Default `auto`.
    pub method: HandEyeMethod,
    /// Refine X and Z jointly (robust LM) and reject outlier frames. Default true.
    pub refine: bool,
    /// Most motion pairs used by the AX=XB closed forms (all pairs when `n(n−1)/2` is at most this).
    /// Default 20000.
    pub max_pairs: usize,
    /// A frame is rejected when its whitened residual norm (rotation/σ_r and translation/σ_t together,
    /// dimensionless, ~χ with 6 degrees of freedom for inliers) exceeds this. Default 5.0.
    pub outlier_threshold: f64,
    /// Also reject frames whose rotation residual exceeds this, degrees. Default none.
    pub max_rotation_residual_deg: Option<f64>,
    /// Also reject frames whose translation residual exceeds this, millimetres. Default none.
    pub max_translation_residual_mm: Option<f64>,
    /// Width of the Cauchy kernel of the first refinement pass, in σ units. Default 4.0.
    pub cauchy_width: f64,
    /// Levenberg-Marquardt iterations per refinement pass. Default 100.
    pub max_iterations: usize,
    /// Frame triples tried by the least-median-of-squares search (with `method = auto`). Default 200.
    pub lmeds_samples: usize,
    /// Seed of that search. Default 0.
    pub seed: u64,
    /// Error when the relative rotation axes spread less than this, degrees. Default 2.
    pub min_axis_spread_deg: f64,
    /// Warning when they spread less than this, degrees. Default 10.
    pub warn_axis_spread_deg: f64,
    /// Warning when no relative rotation reaches this angle, degrees. Default 10.
    pub warn_rotation_deg: f64,
    /// Error when the median difference between the robot and the camera rotation angles of the motion
    /// pairs exceeds this, degrees (wrong units, swapped or inverted poses). Default 10.
    pub max_angle_mismatch_deg: f64,
    /// Error when any pose translates farther than this, metres (millimetres given as metres). Default 20.
    pub max_translation_m: f64,
    /// Warning (with a check of the other pose conventions) when the inliers' median rotation residual
    /// exceeds this, degrees. Default 3.
    pub warn_residual_deg: f64,
    /// The same for the median translation residual, millimetres. Default 30.
    pub warn_residual_mm: f64,
}

impl Default for HandEyeConfig {
    fn default() -> Self {
        HandEyeConfig {
            method: HandEyeMethod::Auto,
            refine: true,
            max_pairs: 20_000,
            outlier_threshold: 5.0,
            max_rotation_residual_deg: None,
            max_translation_residual_mm: None,
            cauchy_width: 4.0,
            max_iterations: 100,
            lmeds_samples: 200,
            seed: 0,
            min_axis_spread_deg: 2.0,
            warn_axis_spread_deg: 10.0,
            warn_rotation_deg: 10.0,
            max_angle_mismatch_deg: 10.0,
            max_translation_m: 20.0,
            warn_residual_deg: 3.0,
            warn_residual_mm: 30.0,
        }
    }
}

impl HandEyeConfig {
    /// Checks the ranges; the error names the field (`handeye.…`). [`calibrate_hand_eye`] calls it first.
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        check::at_least("handeye.max_pairs", self.max_pairs, 1)?;
        check::positive("handeye.outlier_threshold", self.outlier_threshold)?;
        if let Some(v) = self.max_rotation_residual_deg {
            check::positive("handeye.max_rotation_residual_deg", v)?;
        }
        if let Some(v) = self.max_translation_residual_mm {
            check::positive("handeye.max_translation_residual_mm", v)?;
        }
        check::positive("handeye.cauchy_width", self.cauchy_width)?;
        for (field, v) in [
            ("handeye.min_axis_spread_deg", self.min_axis_spread_deg),
            ("handeye.warn_axis_spread_deg", self.warn_axis_spread_deg),
            ("handeye.warn_rotation_deg", self.warn_rotation_deg),
            ("handeye.warn_residual_deg", self.warn_residual_deg),
            ("handeye.warn_residual_mm", self.warn_residual_mm),
        ] {
            check::non_negative(field, v)?;
        }
        check::positive(
            "handeye.max_angle_mismatch_deg",
            self.max_angle_mismatch_deg,
        )?;
        check::positive("handeye.max_translation_m", self.max_translation_m)
    }
}

/// How well the motions excite the rotation axes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    /// Motion pairs considered.
    pub pairs: usize,
    /// Spread of the robot's relative rotation axes, degrees: `2·atan(√(λ₂/λ₁))` of the axes' scatter
    /// matrix (the angle between the axes for two motions; 0 when all axes are parallel).
    pub axis_spread_deg: f64,
    /// Largest relative rotation angle of the robot, degrees.
    pub max_rotation_deg: f64,
    /// Median |angle(A) − angle(B)| over the pairs, degrees (0 for consistent data).
    pub angle_mismatch_deg: f64,
    /// Median difference of the translation along the rotation axis (screw pitch) between robot and
    /// camera motions, millimetres (0 for consistent data).
    pub pitch_mismatch_mm: f64,
}

/// The residual of one frame under a solution.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameResidual {
    /// Frame id.
    pub frame: String,
    /// Rotation residual, degrees.
    pub rotation_deg: f64,
    /// Translation residual (board origin, measured vs predicted), millimetres.
    pub translation_mm: f64,
    /// Whitened residual norm (dimensionless; compare with [`HandEyeConfig::outlier_threshold`]); 0 when
    /// not refined.
    pub normalized: f64,
    /// Whether the frame was rejected as an outlier.
    pub rejected: bool,
}

/// The solution of one closed form and how well it fits all frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClosedFormResult {
    /// The method.
    pub method: HandEyeMethod,
    /// `T_ee_cam`, metres (`None` when the method failed).
    pub t_ee_cam: Option<Isometry3<f64>>,
    /// `T_base_board`, metres (its own for Shah and Li, the frame average for the AX=XB methods).
    pub t_base_board: Option<Isometry3<f64>>,
    /// Median rotation residual over all frames, degrees.
    pub rotation_median_deg: f64,
    /// Median translation residual over all frames, millimetres.
    pub translation_median_mm: f64,
    /// RMS rotation residual over all frames, degrees.
    pub rotation_rms_deg: f64,
    /// RMS translation residual over all frames, millimetres.
    pub translation_rms_mm: f64,
    /// Why the method failed, if it did.
    pub error: Option<String>,
}

/// The result of [`calibrate_hand_eye`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HandEyeResult {
    /// The hand-eye transform `T_ee_cam`, metres.
    pub t_ee_cam: Isometry3<f64>,
    /// The board pose in the base `T_base_board`, metres (jointly refined; the closed form's otherwise).
    pub t_base_board: Isometry3<f64>,
    /// The closed form the answer starts from (chosen by `auto`, or the one asked for).
    pub method: HandEyeMethod,
    /// `true` when the least-median-of-squares search over frame triples gave the starting point.
    pub from_lmeds: bool,
    /// Whether the joint refinement ran.
    pub refined: bool,
    /// Per-frame residuals of the answer, in input order (rejected frames included, flagged).
    pub residuals: Vec<FrameResidual>,
    /// Ids of the rejected frames.
    pub rejected: Vec<String>,
    /// Every closed form's answer, for comparison.
    pub closed_forms: Vec<ClosedFormResult>,
    /// The excitation and consistency of the motions.
    pub excitation: Excitation,
    /// Per-frame `T_base_board` of the inlier frames: rotation-averaged mean and spread.
    pub board: PoseAverage,
    /// Residual scale of the inliers, rotation, degrees (RMS per axis).
    pub sigma_rotation_deg: f64,
    /// Residual scale of the inliers, translation, millimetres (RMS per axis).
    pub sigma_translation_mm: f64,
    /// 1-σ of the estimated `T_ee_cam` (statistical part: `s²(JᵀJ)⁻¹` of the refined inlier frames, RMS per
    /// axis): rotation in degrees, translation in millimetres. `None` without refinement. A cell's
    /// `hand_eye_sigma_deg` / `hand_eye_sigma_mm` take it from a hand-eye JSON file that carries it.
    pub t_ee_cam_sigma: Option<HandEyeSigma>,
    /// LM iterations (both passes).
    pub iterations: usize,
    /// Whether the refinement converged.
    pub converged: bool,
    /// Things the user should know (weak excitation, rejected frames, failed methods, ...).
    pub warnings: Vec<String>,
}

/// Per-frame `(rotation rad, translation m)` residuals of `(x, z)`.
pub fn frame_residuals(
    frames: &[HandEyeFrame],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
) -> Vec<(f64, f64)> {
    frames
        .iter()
        .map(|f| {
            let e = frame_error(f, x, z);
            (
                rotation_angle_between(&UnitQuaternion::identity(), &e.rotation),
                e.translation.vector.norm(),
            )
        })
        .collect()
}

/// `T_base_board` for a given `T_ee_cam`: the rotation average and mean of the per-frame
/// `T_base_ee_i · T_ee_cam · T_cam_board_i`.
pub fn board_for(frames: &[HandEyeFrame], x: &Isometry3<f64>) -> Result<Isometry3<f64>> {
    let poses: Vec<Isometry3<f64>> = frames
        .iter()
        .map(|f| f.t_base_ee * x * f.t_cam_board)
        .collect();
    Ok(average_poses(&poses, None, &AverageConfig::default())?.mean)
}

use crate::stats::median;

/// Checks the frames before solving: count, finite values, plausible translations.
pub fn validate_frames(frames: &[HandEyeFrame], config: &HandEyeConfig) -> Result<()> {
    if frames.len() < 3 {
        return Err(Error::InvalidInput(format!(
            "hand-eye calibration needs at least 3 frames (two motions about different axes), got {}; \
             record more robot poses with the board in view",
            frames.len()
        )));
    }
    for f in frames {
        for (what, t) in [
            ("robot pose T_base_ee", &f.t_base_ee),
            ("target pose T_cam_board", &f.t_cam_board),
        ] {
            let v = t.translation.vector;
            if !v.iter().all(|x| x.is_finite())
                || !t.rotation.quaternion().coords.iter().all(|x| x.is_finite())
            {
                return Err(Error::InvalidInput(format!(
                    "frame {}: the {what} has a NaN or infinite value",
                    f.id
                )));
            }
            if v.norm() > config.max_translation_m {
                return Err(Error::InvalidInput(format!(
                    "frame {}: the {what} translates {:.3} m, which is implausible for a robot cell \
                     (limit {} m); matrix and xyzquat pose files are in metres: were millimetres given?",
                    f.id,
                    v.norm(),
                    config.max_translation_m
                )));
            }
        }
    }
    Ok(())
}

/// Measures the excitation and the robot/camera consistency of the motions; errors when the data cannot
/// determine the hand-eye transform or is clearly inconsistent, and returns warnings for weak data.
pub fn check_motions(
    motions: &[Motion],
    config: &HandEyeConfig,
) -> Result<(Excitation, Vec<String>)> {
    let mut warnings = Vec::new();
    let mut scatter = Matrix3::<f64>::zeros();
    let mut used = 0usize;
    let mut max_rot = 0.0f64;
    let mut mismatch = Vec::with_capacity(motions.len());
    let mut pitch = Vec::new();
    let mut pitch_scale = Vec::new();
    for m in motions {
        let wa = log_rotation(&m.a.rotation);
        let wb = log_rotation(&m.b.rotation);
        let (ta, tb) = (wa.norm(), wb.norm());
        max_rot = max_rot.max(ta);
        mismatch.push((ta - tb).abs());
        if ta > 1f64.to_radians() {
            let axis = wa / ta;
            scatter += axis * axis.transpose();
            used += 1;
        }
        if ta > 10f64.to_radians() && tb > 10f64.to_radians() {
            let da = wa.dot(&m.a.translation.vector) / ta;
            let db = wb.dot(&m.b.translation.vector) / tb;
            pitch.push((da - db).abs());
            pitch_scale.push(da.abs().max(db.abs()));
        }
    }
    let mut ev: Vec<f64> = scatter
        .symmetric_eigen()
        .eigenvalues
        .iter()
        .cloned()
        .collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    let spread = if used >= 2 && ev[0] > 0.0 {
        2.0 * (ev[1].max(0.0) / ev[0]).sqrt().atan()
    } else {
        0.0
    }
    .to_degrees();
    let exc = Excitation {
        pairs: motions.len(),
        axis_spread_deg: spread,
        max_rotation_deg: max_rot.to_degrees(),
        angle_mismatch_deg: median(&mismatch).to_degrees(),
        pitch_mismatch_mm: median(&pitch) * 1e3,
    };
    if exc.angle_mismatch_deg > config.max_angle_mismatch_deg {
        return Err(Error::InvalidInput(format!(
            "the robot and the camera motions rotate by different angles (median difference {:.1}° over \
             {} pairs): the robot and target poses do not describe the same motions. Check the units \
             (kuka A,B,C are degrees; matrix and xyzquat hold rotations, not angles in degrees), that the \
             frame ids match the right images, and that the target poses are T_cam_board",
            exc.angle_mismatch_deg,
            motions.len()
        )));
    }
    if used < 2 {
        return Err(Error::InvalidInput(format!(
            "the robot barely rotates between frames (largest relative rotation {:.2}°): the hand-eye \
             rotation cannot be determined; record poses that rotate the flange by 20° or more about \
             different axes (if the kuka A,B,C columns hold radians, give them in degrees)",
            exc.max_rotation_deg
        )));
    }
    if spread < config.min_axis_spread_deg {
        return Err(Error::InvalidInput(format!(
            "all relative rotations are about nearly the same axis (axis spread {spread:.2}°, minimum {}°): \
             the hand-eye translation along that axis cannot be determined; add poses that rotate the \
             flange about a different axis (tilt it, not only turn it)",
            config.min_axis_spread_deg
        )));
    }
    if spread < config.warn_axis_spread_deg {
        warnings.push(format!(
            "the relative rotation axes spread only {spread:.1}° (want ≥ {}°): the result is sensitive to \
             noise; add poses rotating about other axes",
            config.warn_axis_spread_deg
        ));
    }
    if exc.max_rotation_deg < config.warn_rotation_deg {
        warnings.push(format!(
            "the largest relative rotation is only {:.1}° (want ≥ {}°): small rotations amplify noise",
            exc.max_rotation_deg, config.warn_rotation_deg
        ));
    }
    if exc.angle_mismatch_deg > config.max_angle_mismatch_deg / 4.0 {
        warnings.push(format!(
            "robot and camera rotation angles differ by {:.2}° (median over pairs): noisy or partly \
             inconsistent poses",
            exc.angle_mismatch_deg
        ));
    }
    if !pitch.is_empty() {
        let scale = median(&pitch_scale);
        let pm = median(&pitch);
        if pm > 0.01 && pm > 0.5 * scale {
            warnings.push(format!(
                "the robot and camera translations along the rotation axes disagree (median {:.1} mm): \
                 check the translation units (metres vs millimetres) and that the target poses are \
                 T_cam_board (not T_board_cam; a fixed camera watching a board on the flange is \
                 eye-to-hand)",
                pm * 1e3
            ));
        }
    }
    Ok((exc, warnings))
}

/// Runs one closed form: `(T_ee_cam, T_base_board)`.
pub fn solve_closed_form(
    method: HandEyeMethod,
    frames: &[HandEyeFrame],
    motions: &[Motion],
) -> Result<(Isometry3<f64>, Isometry3<f64>)> {
    let x = match method {
        HandEyeMethod::TsaiLenz => ax_xb::tsai_lenz(motions)?,
        HandEyeMethod::ParkMartin | HandEyeMethod::Auto => ax_xb::park_martin(motions)?,
        HandEyeMethod::Daniilidis => ax_xb::daniilidis(motions)?,
        HandEyeMethod::Shah => return ax_zb::shah(frames),
        HandEyeMethod::Li => return ax_zb::li(frames),
    };
    let z = board_for(frames, &x)?;
    Ok((x, z))
}

/// A robust, unit-free fit score: the median over frames of `√((θᵢ·L)² + dᵢ²)` (metres), with `L` the
/// median camera-to-board distance, so that rotation errors count as the displacement they cause at the board.
fn robust_score(
    frames: &[HandEyeFrame],
    x: &Isometry3<f64>,
    z: &Isometry3<f64>,
    lever: f64,
) -> f64 {
    let r = frame_residuals(frames, x, z);
    median(
        &r.iter()
            .map(|(a, d)| ((a * lever).powi(2) + d * d).sqrt())
            .collect::<Vec<_>>(),
    )
}

/// Robust residual scales from per-frame residuals: `median / 1.538` (the median of the norm of a 3-D
/// Gaussian vector with per-axis σ is 1.538σ), floored at 1e-9 (radians, metres).
fn robust_sigmas(res: &[(f64, f64)]) -> (f64, f64) {
    let r: Vec<f64> = res.iter().map(|p| p.0).collect();
    let t: Vec<f64> = res.iter().map(|p| p.1).collect();
    (
        (median(&r) / 1.538).max(1e-9),
        (median(&t) / 1.538).max(1e-9),
    )
}

/// Least median of squares over random frame triples (Park-Martin on their three pairs).
fn lmeds(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
    lever: f64,
) -> Option<(f64, Isometry3<f64>, Isometry3<f64>)> {
    let n = frames.len();
    if n < 4 {
        return None;
    }
    let mut best: Option<(f64, Isometry3<f64>, Isometry3<f64>)> = None;
    for s in 0..config.lmeds_samples {
        let mut rng = Rng::stream(config.seed, s as u64);
        let i = rng.below(n);
        let mut j = rng.below(n - 1);
        if j >= i {
            j += 1;
        }
        let mut k = rng.below(n);
        let mut guard = 0;
        while k == i || k == j {
            k = rng.below(n);
            guard += 1;
            if guard > 100 {
                break;
            }
        }
        if k == i || k == j {
            continue;
        }
        let sample = [frames[i].clone(), frames[j].clone(), frames[k].clone()];
        let motions = motion_pairs(&sample, 3);
        let quiet = HandEyeConfig {
            warn_axis_spread_deg: 0.0,
            warn_rotation_deg: 0.0,
            max_angle_mismatch_deg: 180.0,
            min_axis_spread_deg: 5.0,
            ..config.clone()
        };
        if check_motions(&motions, &quiet).is_err() {
            continue;
        }
        let Ok(x) = ax_xb::park_martin(&motions) else {
            continue;
        };
        let Ok(z) = board_for(&sample, &x) else {
            continue;
        };
        let score = robust_score(frames, &x, &z, lever);
        if best.as_ref().is_none_or(|b| score < b.0) {
            best = Some((score, x, z));
        }
    }
    best
}

/// When the fit is poor: tries the other pose conventions (inverted target poses, inverted robot poses,
/// both) with Park-Martin and says which one fits far better, if any.
fn convention_hint(
    frames: &[HandEyeFrame],
    config: &HandEyeConfig,
    lever: f64,
    mine: f64,
) -> String {
    let variants: [(&str, bool, bool); 3] = [
        (
            "the target poses fit far better inverted: they look like T_board_cam (invert them), or the \
             camera is fixed and the board is on the flange (eye-to-hand)",
            false,
            true,
        ),
        (
            "the robot poses fit far better inverted: they look like T_ee_base (invert them), or the \
             camera is fixed and the board is on the flange (eye-to-hand: invert the target poses instead)",
            true,
            false,
        ),
        ("both pose files fit far better inverted", true, true),
    ];
    let mut best: Option<(f64, &str)> = None;
    for (msg, inv_robot, inv_target) in variants {
        let alt: Vec<HandEyeFrame> = frames
            .iter()
            .map(|f| HandEyeFrame {
                id: f.id.clone(),
                t_base_ee: if inv_robot {
                    f.t_base_ee.inverse()
                } else {
                    f.t_base_ee
                },
                t_cam_board: if inv_target {
                    f.t_cam_board.inverse()
                } else {
                    f.t_cam_board
                },
            })
            .collect();
        let motions = motion_pairs(&alt, config.max_pairs);
        let Ok(x) = ax_xb::park_martin(&motions) else {
            continue;
        };
        let Ok(z) = board_for(&alt, &x) else {
            continue;
        };
        let score = robust_score(&alt, &x, &z, lever);
        if score < 0.2 * mine && best.is_none_or(|b| score < b.0) {
            best = Some((score, msg));
        }
    }
    match best {
        Some((_, msg)) => format!("; {msg}"),
        None => String::new(),
    }
}

/// The 1-σ of an estimated hand-eye transform, RMS per axis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HandEyeSigma {
    /// Rotation, degrees.
    pub rotation_deg: f64,
    /// Translation, millimetres.
    pub translation_mm: f64,
}

/// Matches robot poses (`T_base_ee`) and target poses (`T_cam_board`) by frame id, in the robot file's
/// order. Errors name the file and the frame that has no partner.
pub fn frames_from_records(
    robot: &[PoseRecord],
    robot_path: &Path,
    target: &[PoseRecord],
    target_path: &Path,
) -> Result<Vec<HandEyeFrame>> {
    let tmap: std::collections::HashMap<&str, &PoseRecord> =
        target.iter().map(|r| (r.frame.as_str(), r)).collect();
    let rset: std::collections::HashSet<&str> = robot.iter().map(|r| r.frame.as_str()).collect();
    let mut out = Vec::with_capacity(robot.len());
    for r in robot {
        let Some(t) = tmap.get(r.frame.as_str()) else {
            return Err(Error::format(
                target_path,
                format!(
                    "frame {} (line {} of {}) has no target pose here; every robot frame needs a target \
                     pose row with the same frame id",
                    r.frame,
                    r.line,
                    robot_path.display()
                ),
            ));
        };
        out.push(HandEyeFrame {
            id: r.frame.clone(),
            t_base_ee: r.pose,
            t_cam_board: t.pose,
        });
    }
    if let Some(t) = target.iter().find(|t| !rset.contains(t.frame.as_str())) {
        return Err(Error::format(
            robot_path,
            format!(
                "frame {} (line {} of {}) has no robot pose here; every target frame needs a robot pose \
                 row with the same frame id",
                t.frame,
                t.line,
                target_path.display()
            ),
        ));
    }
    Ok(out)
}
