//! The cell dataset `depthcal-cell/1`: a directory with a `cell.toml` manifest, per-robot pose files,
//! intrinsics, hand-eye transforms and depth frames, and optionally `ground_truth.json`.
//!
//! ```toml
//! format = "depthcal-cell/1"
//! reference = "left"              # the robot whose base frame is base1
//!
//! [[robot]]
//! name = "left"
//! poses = "left/poses.csv"        # one row per frame: T_base_ee
//! pose_format = "kuka"            # kuka (default) | matrix | xyzquat | ur | abb | fanuc
//! intrinsics = "left/intrinsics.json"
//! hand_eye = [1,0,0,0, 0,1,0,0, 0,0,1,0.1, 0,0,0,1]   # T_ee_cam, row-major, metres (or a JSON path)
//! depth = "left/depth/{frame}.png"
//! color = "left/color/{frame}.png"   # optional
//! ```
//!
//! Every path is relative to the cell directory and must stay inside it: an absolute path, or one that
//! leaves the directory (`..`, a symlink) after canonicalisation, is an error naming the key, unless the
//! manifest opts in with `allow_outside_paths = true` at its top. A path whose file name is a temporary
//! file of an atomic write (`.NAME.tmp-PID`) is never read. Tables and keys this version does not know
//! (e.g. `[priors]`) are kept and written back unchanged. See `docs/cell-format.md`.

pub mod board;
pub mod charuco;
pub mod fiducial;
pub mod markers;
pub use board::{Board, Checkerboard};
pub use charuco::CharucoBoard;
pub use fiducial::MarkerTarget;
pub use markers::MarkerDictionary;

use crate::camera::depth::read_depth_png_header;
use crate::camera::{read_depth_png, DepthImage, Intrinsics};
use crate::error::{Error, Result};
use crate::geometry::transform::{isometry_from_rows, isometry_to_nested, isometry_to_rows};
use crate::io::poses::{read_poses, PoseFormat, PoseRecord};
use nalgebra::Isometry3;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::path::{Path, PathBuf};

/// The manifest's `format` value for this version of the schema.
pub const CELL_FORMAT: &str = "depthcal-cell/1";
/// The manifest's file name inside the cell directory.
pub const MANIFEST_FILE: &str = "cell.toml";
/// The optional ground-truth file inside the cell directory.
pub const GROUND_TRUTH_FILE: &str = "ground_truth.json";
/// The placeholder replaced by the frame id in image path patterns.
pub const FRAME_PLACEHOLDER: &str = "{frame}";

/// A robot's hand-eye transform `T_ee_cam` as the manifest gives it.
#[derive(Clone, Debug, PartialEq)]
pub enum HandEyeSpec {
    /// Given inline as 16 numbers (row-major 4x4, metres) or as 4 rows of 4.
    Inline(Isometry3<f64>),
    /// A JSON file (relative to the cell directory) holding the matrix: 16 numbers, 4 rows of 4, or an object
    /// with one of the keys `T_ee_cam`, `transform`, `matrix` holding either.
    File(String),
}

fn matrix_from_json(v: &serde_json::Value) -> std::result::Result<[f64; 16], String> {
    if let serde_json::Value::Object(o) = v {
        for key in ["T_ee_cam", "transform", "matrix"] {
            if let Some(inner) = o.get(key) {
                return crate::io::matrix::matrix_from_json(inner);
            }
        }
        return Err("expected a key T_ee_cam, transform or matrix holding the 4x4 matrix".into());
    }
    crate::io::matrix::matrix_from_json(v)
}

impl Serialize for HandEyeSpec {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            HandEyeSpec::Inline(t) => {
                let mut rows = isometry_to_rows(t);
                for v in &mut rows {
                    // Round away float noise (1e-12 m, ~1e-12 rad) so manifests stay readable.
                    *v = (*v * 1e12).round() / 1e12;
                }
                rows.serialize(s)
            }
            HandEyeSpec::File(p) => s.serialize_str(p),
        }
    }
}

impl<'de> Deserialize<'de> for HandEyeSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        use serde::de::Error as _;
        let v = serde_json::Value::deserialize(d)?;
        if let Some(s) = v.as_str() {
            return Ok(HandEyeSpec::File(s.to_string()));
        }
        let m = matrix_from_json(&v)
            .map_err(|m| D::Error::custom(format!("hand_eye: {m}, or a JSON file path")))?;
        isometry_from_rows(&m, "hand_eye")
            .map(HandEyeSpec::Inline)
            .map_err(|e| D::Error::custom(e.to_string()))
    }
}

fn default_pose_format() -> PoseFormat {
    PoseFormat::Kuka
}

/// One `[[robot]]` table of the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RobotEntry {
    /// The robot's name (unique in the cell).
    pub name: String,
    /// The pose CSV file (one row per frame: `T_base_ee`).
    pub poses: String,
    /// The pose file's format (default `kuka`).
    #[serde(default = "default_pose_format")]
    pub pose_format: PoseFormat,
    /// The camera intrinsics JSON file (see [`Intrinsics`]).
    pub intrinsics: String,
    /// The hand-eye transform `T_ee_cam` (metres).
    pub hand_eye: HandEyeSpec,
    /// Depth image path pattern containing `{frame}`, e.g. `left/depth/{frame}.png` (16-bit PNG).
    pub depth: String,
    /// Optional colour image path pattern containing `{frame}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<String>,
    /// 1-σ of the hand-eye's rotation, degrees (optional; see [`RobotUncertainty`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_sigma_deg: Option<f64>,
    /// 1-σ of the hand-eye's translation, millimetres (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hand_eye_sigma_mm: Option<f64>,
    /// The robot's pose repeatability at the flange, 1-σ millimetres (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_repeatability_mm: Option<f64>,
    /// The robot's rotational repeatability at the flange, 1-σ degrees (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_repeatability_deg: Option<f64>,
    /// 1-σ of the depth camera's scale error, as a fraction (optional; 0.001 = 0.1%).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_scale_sigma: Option<f64>,
    /// The ROS / TF frame id of the robot's base (optional; default `{name}_base`), used by the
    /// robot and ROS outputs of `calibrate`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame: Option<String>,
    /// Keys this schema version does not know: an error when the manifest is read (kept so that the error
    /// can name them).
    #[serde(flatten)]
    pub extra: toml::Table,
}

/// The keys of a `[[robot]]` table.
pub const ROBOT_KEYS: &[&str] = &[
    "name",
    "poses",
    "pose_format",
    "intrinsics",
    "hand_eye",
    "depth",
    "color",
    "hand_eye_sigma_deg",
    "hand_eye_sigma_mm",
    "pose_repeatability_mm",
    "pose_repeatability_deg",
    "depth_scale_sigma",
    "frame",
];

/// The top-level keys and tables of `cell.toml`.
pub const MANIFEST_KEYS: &[&str] = &[
    "format",
    "reference",
    "robot",
    "priors",
    "board",
    "markers",
    ALLOW_OUTSIDE_PATHS,
];

/// The top-level manifest key (`allow_outside_paths = true`) that lets the cell's paths point outside the
/// cell directory (absolute paths, `..`, symlinks leaving it).
pub const ALLOW_OUTSIDE_PATHS: &str = "allow_outside_paths";

/// What the cell says, or depthcal assumes, about how uncertain each robot's inputs are; it enters the
/// covariance of `T_base1_base2`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RobotUncertainty {
    /// Hand-eye rotation 1-σ, radians (default 0.05°: a good board calibration).
    pub hand_eye_rotation_rad: f64,
    /// Hand-eye translation 1-σ, metres (default 0.5 mm).
    pub hand_eye_translation_m: f64,
    /// Pose repeatability at the flange, metres (default 0.1 mm: industrial arms state ±0.03–0.1 mm).
    pub pose_translation_m: f64,
    /// Rotational pose repeatability at the flange, radians (default 0.01°).
    pub pose_rotation_rad: f64,
    /// Depth scale 1-σ, a fraction (default 0.0005).
    pub depth_scale: f64,
    /// Which of the values above the cell stated (the others are the defaults).
    pub stated: Vec<String>,
}

impl Default for RobotUncertainty {
    /// The defaults of a robot entry that states none.
    fn default() -> Self {
        RobotUncertainty::from_entry(&RobotEntry::standard("", Isometry3::identity()))
    }
}

impl RobotUncertainty {
    /// The robot entry's values, with the defaults where it says nothing.
    pub fn from_entry(e: &RobotEntry) -> Self {
        let mut stated = Vec::new();
        let mut take = |v: Option<f64>, key: &str, default: f64, scale: f64| match v {
            Some(x) => {
                stated.push(key.to_string());
                x * scale
            }
            None => default,
        };
        RobotUncertainty {
            hand_eye_rotation_rad: take(
                e.hand_eye_sigma_deg,
                "hand_eye_sigma_deg",
                0.05f64.to_radians(),
                1f64.to_radians(),
            ),
            hand_eye_translation_m: take(e.hand_eye_sigma_mm, "hand_eye_sigma_mm", 0.5e-3, 1e-3),
            pose_translation_m: take(
                e.pose_repeatability_mm,
                "pose_repeatability_mm",
                0.1e-3,
                1e-3,
            ),
            pose_rotation_rad: take(
                e.pose_repeatability_deg,
                "pose_repeatability_deg",
                0.01f64.to_radians(),
                1f64.to_radians(),
            ),
            depth_scale: take(e.depth_scale_sigma, "depth_scale_sigma", 5e-4, 1.0),
            stated,
        }
    }
}

/// The known name closest to `key` when it is a near miss (edit distance at most 2, not equal).
pub fn near_miss<'a>(key: &str, known: &[&'a str]) -> Option<&'a str> {
    fn distance(a: &str, b: &str) -> usize {
        let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
        let mut prev: Vec<usize> = (0..=b.len()).collect();
        for (i, ca) in a.iter().enumerate() {
            let mut cur = vec![i + 1; b.len() + 1];
            for (j, cb) in b.iter().enumerate() {
                cur[j + 1] = (prev[j] + usize::from(ca != cb))
                    .min(prev[j + 1] + 1)
                    .min(cur[j] + 1);
            }
            prev = cur;
        }
        prev[b.len()]
    }
    let k = key.to_ascii_lowercase();
    known
        .iter()
        .map(|&n| (distance(&k, n), n))
        .filter(|&(d, n)| d > 0 && d <= 2.min(n.len() / 2))
        .min()
        .map(|(_, n)| n)
}

impl RobotEntry {
    /// An entry with the conventional layout under `<name>/`: `poses.csv` (KUKA), `intrinsics.json`,
    /// `depth/{frame}.png`, and an inline hand-eye.
    pub fn standard(name: &str, t_ee_cam: Isometry3<f64>) -> Self {
        RobotEntry {
            name: name.to_string(),
            poses: format!("{name}/poses.csv"),
            pose_format: PoseFormat::Kuka,
            intrinsics: format!("{name}/intrinsics.json"),
            hand_eye: HandEyeSpec::Inline(t_ee_cam),
            depth: format!("{name}/depth/{FRAME_PLACEHOLDER}.png"),
            color: None,
            hand_eye_sigma_deg: None,
            hand_eye_sigma_mm: None,
            pose_repeatability_mm: None,
            pose_repeatability_deg: None,
            depth_scale_sigma: None,
            frame: None,
            extra: toml::Table::new(),
        }
    }
}

/// The `cell.toml` manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellManifest {
    /// Must be [`CELL_FORMAT`].
    pub format: String,
    /// The reference robot's name; its base is `base1` in `T_base1_base2`.
    pub reference: String,
    /// The robots (`[[robot]]` tables), in file order.
    #[serde(rename = "robot")]
    pub robots: Vec<RobotEntry>,
    /// The optional tables (`[priors]`, `[board]`, `[markers]`, read by the methods that use them) and any
    /// other table, kept and written back. An unknown table that is a near miss of a known one (`[prior]`)
    /// is an error; other unknown tables get a warning.
    #[serde(flatten)]
    pub extra: toml::Table,
}

impl CellManifest {
    /// An empty manifest of the current format with the given reference robot.
    pub fn new(reference: &str) -> Self {
        CellManifest {
            format: CELL_FORMAT.to_string(),
            reference: reference.to_string(),
            robots: Vec::new(),
            extra: toml::Table::new(),
        }
    }

    /// Parses manifest text; `path` names the file in errors. Checks the format version, robot names and
    /// the reference, and the `{frame}` patterns.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self> {
        let m: CellManifest = toml::from_str(text)
            .map_err(|e| Error::format(path, e.to_string().trim_end().to_string()))?;
        m.validate().map_err(|msg| Error::format(path, msg))?;
        for (i, r) in m.robots.iter().enumerate() {
            if let Some(k) = r.extra.keys().next() {
                let hint = near_miss(k, ROBOT_KEYS)
                    .map(|n| format!(" (did you mean `{n}`?)"))
                    .unwrap_or_default();
                return Err(Error::format(
                    path,
                    format!(
                        "robot[{i}] ({:?}): unknown key `{k}`{hint}; the keys of a [[robot]] table are {}",
                        r.name,
                        ROBOT_KEYS.join(", ")
                    ),
                ));
            }
        }
        for k in m.extra.keys() {
            if MANIFEST_KEYS.contains(&k.as_str()) {
                continue;
            }
            if let Some(n) = near_miss(k, MANIFEST_KEYS) {
                return Err(Error::format(
                    path,
                    format!(
                        "unknown table or key `{k}`: did you mean `{n}`? (known: {})",
                        MANIFEST_KEYS.join(", ")
                    ),
                ));
            }
            log::warn!(
                "{}: `{k}` is not part of {CELL_FORMAT} (known: {}); kept but ignored",
                path.display(),
                MANIFEST_KEYS.join(", ")
            );
        }
        Ok(m)
    }

    /// Reads `<dir>/cell.toml`.
    pub fn read(dir: impl AsRef<Path>) -> Result<Self> {
        let path = dir.as_ref().join(MANIFEST_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        Self::from_toml_str(&text, &path)
    }

    /// Checks the schema rules that serde cannot; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.format != CELL_FORMAT {
            return Err(format!(
                "field `format` is {:?}; this depthcal reads {CELL_FORMAT:?}",
                self.format
            ));
        }
        if self.robots.is_empty() {
            return Err("no [[robot]] table; a cell needs at least one robot".into());
        }
        for (i, r) in self.robots.iter().enumerate() {
            let at = format!("robot[{i}] ({:?})", r.name);
            if r.name.trim().is_empty() {
                return Err(format!("robot[{i}]: field `name` is empty"));
            }
            if self.robots[..i].iter().any(|o| o.name == r.name) {
                return Err(format!("{at}: the robot name is used twice"));
            }
            if !r.depth.contains(FRAME_PLACEHOLDER) {
                return Err(format!(
                    "{at}: field `depth` = {:?} must contain {FRAME_PLACEHOLDER}",
                    r.depth
                ));
            }
            for (key, v) in [
                ("hand_eye_sigma_deg", r.hand_eye_sigma_deg),
                ("hand_eye_sigma_mm", r.hand_eye_sigma_mm),
                ("pose_repeatability_mm", r.pose_repeatability_mm),
                ("pose_repeatability_deg", r.pose_repeatability_deg),
                ("depth_scale_sigma", r.depth_scale_sigma),
            ] {
                if let Some(x) = v {
                    if !(x >= 0.0 && x.is_finite()) {
                        return Err(format!(
                            "{at}: field `{key}` = {x} must be a finite 1-σ ≥ 0"
                        ));
                    }
                }
            }
            if let Some(c) = &r.color {
                if !c.contains(FRAME_PLACEHOLDER) {
                    return Err(format!(
                        "{at}: field `color` = {c:?} must contain {FRAME_PLACEHOLDER}"
                    ));
                }
            }
        }
        if let Some(v) = self.extra.get(ALLOW_OUTSIDE_PATHS) {
            if !v.is_bool() {
                return Err(format!(
                    "field `{ALLOW_OUTSIDE_PATHS}` must be true or false, not {v}"
                ));
            }
        }
        if !self.robots.iter().any(|r| r.name == self.reference) {
            let names: Vec<&str> = self.robots.iter().map(|r| r.name.as_str()).collect();
            return Err(format!(
                "field `reference` = {:?} names no robot (robots: {names:?})",
                self.reference
            ));
        }
        Ok(())
    }

    /// Whether the manifest allows paths outside the cell directory (`allow_outside_paths = true`).
    pub fn allows_outside_paths(&self) -> bool {
        self.extra
            .get(ALLOW_OUTSIDE_PATHS)
            .and_then(|v| v.as_bool())
            .unwrap_or(false)
    }

    /// The manifest as TOML text.
    pub fn to_toml_string(&self) -> Result<String> {
        toml::to_string(self)
            .map_err(|e| Error::InvalidInput(format!("cannot write the cell manifest: {e}")))
    }

    /// Validates and writes `<dir>/cell.toml` atomically.
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<()> {
        let path = dir.as_ref().join(MANIFEST_FILE);
        self.validate()
            .map_err(|m| Error::InvalidInput(format!("{}: {m}", path.display())))?;
        let text = self.to_toml_string()?;
        crate::io::write_atomically(&path, |w| w.write_all(text.as_bytes()))
    }
}

/// `ground_truth.json`: the true transforms of a simulated or surveyed cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroundTruth {
    /// `T_base1_base2`: maps the second robot's base coordinates (the first non-reference robot in the
    /// manifest) into the reference robot's base, metres. JSON: 4 rows of 4 numbers.
    pub t_base1_base2: Option<Isometry3<f64>>,
    /// Every other key, kept as is (the simulator may add per-robot truths).
    pub extra: serde_json::Map<String, serde_json::Value>,
}

impl GroundTruth {
    /// Reads `<dir>/ground_truth.json`; `Ok(None)` when the file does not exist.
    pub fn read(dir: impl AsRef<Path>) -> Result<Option<Self>> {
        let path = dir.as_ref().join(GROUND_TRUTH_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Error::io(&path, e)),
        };
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::format(&path, format!("not valid JSON: {e}")))?;
        let serde_json::Value::Object(mut map) = v else {
            return Err(Error::format(&path, "expected a JSON object"));
        };
        let t = match map.remove("T_base1_base2") {
            None | Some(serde_json::Value::Null) => None,
            Some(v) => {
                let m = matrix_from_json(&v)
                    .map_err(|m| Error::format(&path, format!("T_base1_base2: {m}")))?;
                Some(
                    isometry_from_rows(&m, "T_base1_base2")
                        .map_err(|e| Error::format(&path, e.to_string()))?,
                )
            }
        };
        Ok(Some(GroundTruth {
            t_base1_base2: t,
            extra: map,
        }))
    }

    /// The true `T_reference_robot` of robot `name` against robot `reference` when the truth knows it: from
    /// the `robots` list (each entry's `name` and `T_base1_base`, as the simulator writes it) when it holds
    /// both, the identity when the two are one robot, else `T_base1_base2` when `reference` and `name` are
    /// the manifest's reference and first other robot (`first_other`).
    pub fn base_of(
        &self,
        name: &str,
        reference: &str,
        first_other: &str,
    ) -> Option<Isometry3<f64>> {
        if name == reference {
            return Some(Isometry3::identity());
        }
        let listed = |n: &str| -> Option<Isometry3<f64>> {
            let entry = self
                .extra
                .get("robots")?
                .as_array()?
                .iter()
                .find(|r| r.get("name").and_then(|v| v.as_str()) == Some(n))?;
            let m = matrix_from_json(entry.get("T_base1_base")?).ok()?;
            isometry_from_rows(&m, "T_base1_base").ok()
        };
        if let (Some(a), Some(b)) = (listed(reference), listed(name)) {
            return Some(a.inverse() * b);
        }
        (name == first_other)
            .then_some(self.t_base1_base2)
            .flatten()
    }

    /// Writes `<dir>/ground_truth.json` atomically.
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<()> {
        let path = dir.as_ref().join(GROUND_TRUTH_FILE);
        let mut map = self.extra.clone();
        if let Some(t) = &self.t_base1_base2 {
            map.insert(
                "T_base1_base2".into(),
                serde_json::to_value(isometry_to_nested(t)).unwrap(),
            );
        }
        let text = serde_json::to_string_pretty(&serde_json::Value::Object(map)).unwrap();
        crate::io::write_atomically(&path, |w| {
            w.write_all(text.as_bytes())?;
            w.write_all(b"\n")
        })
    }
}

/// One frame of a robot: its pose and image paths.
#[derive(Clone, Debug, PartialEq)]
pub struct CellFrame {
    /// Frame id (the pose file's `frame` column).
    pub id: String,
    /// `T_base_ee`, metres.
    pub t_base_ee: Isometry3<f64>,
    /// The depth image (resolved path).
    pub depth_path: PathBuf,
    /// The colour image (resolved path), if the robot has a `color` pattern.
    pub color_path: Option<PathBuf>,
    /// 1-based line of the pose file this frame comes from.
    pub pose_line: usize,
}

/// A robot of an opened cell: everything resolved, parsed and checked.
#[derive(Clone, Debug)]
pub struct CellRobot {
    /// The robot's name.
    pub name: String,
    /// Camera intrinsics (with `depth_scale`).
    pub intrinsics: Intrinsics,
    /// The hand-eye transform `T_ee_cam`, metres.
    pub t_ee_cam: Isometry3<f64>,
    /// The pose file (resolved path).
    pub poses_path: PathBuf,
    /// The intrinsics file (resolved path).
    pub intrinsics_path: PathBuf,
    /// The hand-eye file (resolved path), when `hand_eye` names one.
    pub hand_eye_path: Option<PathBuf>,
    /// The frames, in pose-file order.
    pub frames: Vec<CellFrame>,
    /// How uncertain the hand-eye, the poses and the depth are (stated or default).
    pub uncertainty: RobotUncertainty,
}

impl crate::fusion::DepthFrames for CellRobot {
    fn robot_name(&self) -> &str {
        &self.name
    }
    fn depth_intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }
    fn frame_count(&self) -> usize {
        self.frames.len()
    }
    fn load_depth(&self, i: usize) -> Result<DepthImage> {
        CellRobot::load_depth(self, i)
    }
    fn t_base_cam(&self, i: usize) -> Isometry3<f64> {
        CellRobot::t_base_cam(self, i)
    }
    fn depth_path(&self, i: usize) -> &Path {
        &self.frames[i].depth_path
    }
}

impl CellRobot {
    /// A robot of unit tests: frames `0000`, `0001`, … at flange poses `poses`, no files behind them.
    #[cfg(test)]
    pub(crate) fn for_tests(
        name: &str,
        intrinsics: Intrinsics,
        t_ee_cam: Isometry3<f64>,
        poses: &[Isometry3<f64>],
    ) -> CellRobot {
        CellRobot {
            name: name.into(),
            intrinsics,
            t_ee_cam,
            poses_path: PathBuf::from("poses.csv"),
            intrinsics_path: PathBuf::from("intrinsics.json"),
            hand_eye_path: None,
            uncertainty: Default::default(),
            frames: poses
                .iter()
                .enumerate()
                .map(|(i, p)| CellFrame {
                    id: format!("{i:04}"),
                    t_base_ee: *p,
                    depth_path: PathBuf::new(),
                    color_path: None,
                    pose_line: i + 2,
                })
                .collect(),
        }
    }

    /// `T_base_cam = T_base_ee · T_ee_cam` of frame `i`.
    pub fn t_base_cam(&self, i: usize) -> Isometry3<f64> {
        self.frames[i].t_base_ee * self.t_ee_cam
    }

    /// Reads frame `i`'s depth image and checks its size against the intrinsics.
    pub fn load_depth(&self, i: usize) -> Result<DepthImage> {
        let f = &self.frames[i];
        let img = read_depth_png(&f.depth_path)?;
        self.check_size(&f.depth_path, img.width, img.height)?;
        Ok(img)
    }

    fn check_size(&self, path: &Path, w: u32, h: u32) -> Result<()> {
        if (w, h) != (self.intrinsics.width, self.intrinsics.height) {
            return Err(Error::format(
                path,
                format!(
                    "depth image is {w}x{h} but robot {:?}'s intrinsics say {}x{}",
                    self.name, self.intrinsics.width, self.intrinsics.height
                ),
            ));
        }
        Ok(())
    }
}

/// An opened cell dataset.
#[derive(Clone, Debug)]
pub struct Cell {
    /// The cell directory.
    pub dir: PathBuf,
    /// The manifest as read.
    pub manifest: CellManifest,
    /// The robots, in manifest order.
    pub robots: Vec<CellRobot>,
}

/// Resolves a manifest path against the cell directory and keeps it there: `key` names the field in errors
/// (e.g. `robot[0] ("left"): field `poses``). Unless `allow_outside`, an absolute path, or one that leaves
/// `dir` after canonicalisation (`..`, a symlink), is an error; a temporary file of an atomic write always is.
/// The returned path is `dir` joined with `rel` (as the user spelled it). Errors never show file contents.
pub fn resolve_cell_path(
    dir: &Path,
    manifest: &Path,
    key: &str,
    rel: &str,
    allow_outside: bool,
) -> Result<PathBuf> {
    let joined = dir.join(rel);
    if crate::tempfiles::is_temp_path(&joined) {
        return Err(Error::format(
            manifest,
            format!(
                "{key} = {rel:?} names a temporary file of an interrupted write (.NAME.tmp-PID), not data"
            ),
        ));
    }
    if allow_outside {
        return Ok(joined);
    }
    let hint = format!(
        "paths in a cell must stay inside the cell directory {} (set `{ALLOW_OUTSIDE_PATHS} = true` at the \
         top of cell.toml to allow other paths)",
        dir.display()
    );
    if Path::new(rel).is_absolute() || rel.starts_with('~') {
        return Err(Error::format(
            manifest,
            format!("{key} = {rel:?} is an absolute path; {hint}"),
        ));
    }
    let root = dir.canonicalize().map_err(|e| Error::io(dir, e))?;
    // The deepest existing ancestor, canonicalised; the rest must not climb out with `..`.
    let mut existing = joined.as_path();
    let mut rest: Vec<&std::ffi::OsStr> = Vec::new();
    let resolved = loop {
        match existing.canonicalize() {
            Ok(c) => break Some(c),
            Err(_) => match (existing.parent(), existing.file_name()) {
                (Some(p), Some(n)) => {
                    rest.push(n);
                    existing = p;
                }
                _ => break None,
            },
        }
    };
    let inside = resolved.is_some_and(|c| c.starts_with(&root)) && !rest.iter().any(|n| *n == "..");
    if !inside {
        return Err(Error::format(
            manifest,
            format!("{key} = {rel:?} leads outside the cell directory; {hint}"),
        ));
    }
    Ok(joined)
}

/// Whether `path` (existing) lies inside `dir` after canonicalisation.
fn is_inside(dir: &Path, path: &Path) -> bool {
    match (dir.canonicalize(), path.canonicalize()) {
        (Ok(d), Ok(p)) => p.starts_with(d),
        _ => false,
    }
}

/// Substitutes the frame id into a path pattern.
pub fn frame_path(dir: &Path, pattern: &str, frame: &str) -> PathBuf {
    dir.join(pattern.replace(FRAME_PLACEHOLDER, frame))
}

/// Reads a hand-eye `T_ee_cam` JSON file: 16 numbers (row-major 4x4, metres), 4 rows of 4, or an object with a
/// key `T_ee_cam`, `transform` or `matrix` holding either.
pub fn read_hand_eye_file(path: &Path) -> Result<Isometry3<f64>> {
    read_hand_eye_json(path).map(|(t, _)| t)
}

/// The 1-σ a hand-eye JSON file states for its transform (`depthcal handeye --json` writes them): the
/// keys `hand_eye_sigma_deg` and `hand_eye_sigma_mm` of a JSON object, each optional.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandEyeFileSigma {
    /// Rotation 1-σ per axis, degrees.
    pub rotation_deg: Option<f64>,
    /// Translation 1-σ per axis, millimetres.
    pub translation_mm: Option<f64>,
}

/// Reads a hand-eye JSON file ([`read_hand_eye_file`]) with the 1-σ it states, if any. A stated 1-σ that
/// is not a finite number ≥ 0 is an error naming the key.
pub fn read_hand_eye_json(path: &Path) -> Result<(Isometry3<f64>, HandEyeFileSigma)> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::format(path, format!("not valid JSON: {e}")))?;
    let m =
        matrix_from_json(&v).map_err(|m| Error::format(path, format!("hand-eye T_ee_cam: {m}")))?;
    let t = isometry_from_rows(&m, "T_ee_cam").map_err(|e| Error::format(path, e.to_string()))?;
    let sigma = |key: &str| -> Result<Option<f64>> {
        match v.get(key) {
            None | Some(serde_json::Value::Null) => Ok(None),
            Some(x) => match x.as_f64() {
                Some(s) if s.is_finite() && s >= 0.0 => Ok(Some(s)),
                _ => Err(Error::format(
                    path,
                    format!("`{key}` must be a finite number >= 0, got {x}"),
                )),
            },
        }
    };
    Ok((
        t,
        HandEyeFileSigma {
            rotation_deg: sigma("hand_eye_sigma_deg")?,
            translation_mm: sigma("hand_eye_sigma_mm")?,
        },
    ))
}

impl Cell {
    /// Opens a cell directory: reads the manifest, every robot's poses, intrinsics and hand-eye, and checks that
    /// every pose row has a 16-bit depth PNG of the intrinsics' size (reading only the PNG headers). Each
    /// problem is an error naming the file and the row or field.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        if !dir.is_dir() {
            return Err(Error::io(
                &dir,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "the cell directory does not exist",
                ),
            ));
        }
        let manifest = CellManifest::read(&dir)?;
        let mut robots = Vec::with_capacity(manifest.robots.len());
        for entry in &manifest.robots {
            robots.push(Self::open_robot(
                &dir,
                entry,
                manifest.allows_outside_paths(),
            )?);
        }
        Ok(Cell {
            dir,
            manifest,
            robots,
        })
    }

    fn open_robot(dir: &Path, e: &RobotEntry, allow_outside: bool) -> Result<CellRobot> {
        let manifest = dir.join(MANIFEST_FILE);
        if let Some(f) = &e.frame {
            check_frame_id(f).map_err(|m| {
                Error::format(&manifest, format!("robot {:?}: field `frame`: {m}", e.name))
            })?;
        }
        let at = |field: &str| format!("robot {:?}: field `{field}`", e.name);
        let resolve = |field: &str, rel: &str| {
            resolve_cell_path(dir, &manifest, &at(field), rel, allow_outside)
        };
        let poses_path = resolve("poses", &e.poses)?;
        let intr_path = resolve("intrinsics", &e.intrinsics)?;
        let hand_eye_path = match &e.hand_eye {
            HandEyeSpec::Inline(_) => None,
            HandEyeSpec::File(p) => Some(resolve("hand_eye", p)?),
        };
        // A file outside the cell (allowed by the opt-in) is read, but its errors do not quote it.
        let quiet = |path: &Path, what: &str| {
            let outside = !is_inside(dir, path);
            let (path, what) = (path.to_path_buf(), what.to_string());
            move |err: Error| {
                if outside {
                    Error::format(
                        &path,
                        format!(
                            "not a valid {what} (the file is outside the cell directory: its content is \
                             not shown)"
                        ),
                    )
                } else {
                    err
                }
            }
        };
        let (_, records) = read_poses(&poses_path, Some(e.pose_format)).map_err(quiet(
            &poses_path,
            &format!("pose file of format {}", e.pose_format),
        ))?;
        let intrinsics =
            Intrinsics::from_json_file(&intr_path).map_err(quiet(&intr_path, "intrinsics file"))?;
        let (t_ee_cam, file_sigma) = match (&e.hand_eye, &hand_eye_path) {
            (HandEyeSpec::Inline(t), _) => (*t, HandEyeFileSigma::default()),
            (HandEyeSpec::File(_), Some(p)) => {
                read_hand_eye_json(p).map_err(quiet(p, "hand-eye file"))?
            }
            (HandEyeSpec::File(p), None) => read_hand_eye_json(&dir.join(p))?,
        };
        // The robot entry's own 1-σ keys win; else those of the hand-eye file; else the defaults.
        let mut stated = e.clone();
        stated.hand_eye_sigma_deg = e.hand_eye_sigma_deg.or(file_sigma.rotation_deg);
        stated.hand_eye_sigma_mm = e.hand_eye_sigma_mm.or(file_sigma.translation_mm);
        let mut robot = CellRobot {
            name: e.name.clone(),
            intrinsics,
            t_ee_cam,
            poses_path: poses_path.clone(),
            intrinsics_path: intr_path,
            hand_eye_path,
            frames: Vec::with_capacity(records.len()),
            uncertainty: RobotUncertainty::from_entry(&stated),
        };
        for PoseRecord { frame, pose, line } in records {
            let depth_rel = e.depth.replace(FRAME_PLACEHOLDER, &frame);
            let depth_path = resolve_cell_path(
                dir,
                &manifest,
                &format!(
                    "{} (frame {frame:?} of line {line} of the poses)",
                    at("depth")
                ),
                &depth_rel,
                allow_outside,
            )?;
            if !depth_path.is_file() {
                return Err(Error::format(
                    &poses_path,
                    format!(
                        "line {line}: frame {frame} has no depth image: {} does not exist (robot {:?}, pattern {:?})",
                        depth_path.display(),
                        e.name,
                        e.depth
                    ),
                ));
            }
            let (w, h) = read_depth_png_header(&depth_path)?;
            robot.check_size(&depth_path, w, h)?;
            let color_path = match &e.color {
                Some(c) => Some(resolve_cell_path(
                    dir,
                    &manifest,
                    &format!(
                        "{} (frame {frame:?} of line {line} of the poses)",
                        at("color")
                    ),
                    &c.replace(FRAME_PLACEHOLDER, &frame),
                    allow_outside,
                )?),
                None => None,
            };
            if let Some(c) = &color_path {
                if !c.is_file() {
                    return Err(Error::format(
                        &poses_path,
                        format!(
                            "line {line}: frame {frame} has no colour image: {} does not exist",
                            c.display()
                        ),
                    ));
                }
            }
            robot.frames.push(CellFrame {
                id: frame,
                t_base_ee: pose,
                depth_path,
                color_path,
                pose_line: line,
            });
        }
        Ok(robot)
    }

    /// The robot called `name`; the error lists the robots there are.
    pub fn robot(&self, name: &str) -> Result<&CellRobot> {
        self.robots.iter().find(|r| r.name == name).ok_or_else(|| {
            let names: Vec<&str> = self.robots.iter().map(|r| r.name.as_str()).collect();
            Error::InvalidInput(format!(
                "{}: no robot named {name:?} (robots: {names:?})",
                self.dir.join(MANIFEST_FILE).display()
            ))
        })
    }

    /// The ROS / TF frame id of robot `name`'s base: the robot entry's `frame`, else `{name}_base`.
    pub fn frame_id(&self, name: &str) -> String {
        self.manifest
            .robots
            .iter()
            .find(|r| r.name == name)
            .and_then(|r| r.frame.clone())
            .unwrap_or_else(|| format!("{name}_base"))
    }

    /// The base frame ids of every robot but the reference, in manifest order: `first_child` for the
    /// first of them (the child frame of the two-robot outputs), the others' `frame` in cell.toml, else
    /// `ROBOT_base` ([`Cell::frame_id`]).
    pub fn other_frame_ids(&self, first_child: &str) -> Vec<String> {
        let reference = &self.manifest.reference;
        self.robots
            .iter()
            .filter(|r| &r.name != reference)
            .enumerate()
            .map(|(k, r)| {
                if k == 0 {
                    first_child.to_string()
                } else {
                    self.frame_id(&r.name)
                }
            })
            .collect()
    }

    /// The two robots of a two-robot calibration: the reference and the first other one. Errors: a cell
    /// of one robot.
    pub fn robot_pair(&self) -> Result<(&CellRobot, &CellRobot)> {
        let reference = self.reference();
        let other = self
            .robots
            .iter()
            .find(|r| r.name != reference.name)
            .ok_or_else(|| {
                Error::InvalidInput(format!(
                    "{}: the cell needs two robots, it names only {:?}",
                    self.dir.join(MANIFEST_FILE).display(),
                    reference.name
                ))
            })?;
        Ok((reference, other))
    }

    /// The reference robot.
    pub fn reference(&self) -> &CellRobot {
        self.robots
            .iter()
            .find(|r| r.name == self.manifest.reference)
            .expect("validated manifest names its reference")
    }

    /// The ground truth, if the cell has `ground_truth.json`.
    pub fn ground_truth(&self) -> Result<Option<GroundTruth>> {
        GroundTruth::read(&self.dir)
    }
}

pub use crate::geometry::robot_formats::check_frame_id;

#[cfg(test)]
mod tests;
