//! Getting depth frames into a cell dataset: appending frames to a robot of a `depthcal-cell/1` directory,
//! matching recorded frames to robot poses, and importing recordings.
//!
//! * [`append_frames`] adds frames (depth, optional colour, the pose `T_base_ee`) to one robot of a cell,
//!   creating the cell or the robot when they do not exist yet. Nothing is ever overwritten: a frame id that
//!   the robot already has, or an image file that already exists, is an error, and every check runs before
//!   the first file is written. Files are written atomically, images first, then the pose file, then
//!   `cell.toml`, so that an interrupted append leaves the cell as it was.
//! * [`PoseRows`] reads the pose file that goes with a recording: any pose format of
//!   [`crate::geometry::pose`], optionally with a `t_s` column (seconds, the recording's clock) after `frame`.
//! * [`match_frames`] pairs recorded depth frames with pose rows, by order or by timestamp
//!   ([`MatchMode`]), and colour frames with depth frames by timestamp.
//! * [`tf`] takes the poses from a recording's `/tf` and `/tf_static` instead ([`PoseRows::from_tf`]).
//! * [`import_recording`] runs the whole import of a [`Recording`]: ROS1 `.bag` files with the pure-Rust
//!   reader of [`rosbag`] (default build), and, with the cargo feature `realsense`, anything librealsense
//!   plays back (`realsense` module: ROS2 `.db3`, ROS1 `.bag`) plus live capture from a camera.

#[cfg(feature = "rosbag")]
pub mod rosbag;

#[cfg(feature = "realsense")]
pub mod realsense;

pub mod tf;

use crate::camera::{write_depth_png, DepthImage, Intrinsics};
use crate::camera::{write_rgb_png, RgbImage};
use crate::cell::{
    frame_path, read_hand_eye_file, Cell, CellManifest, HandEyeSpec, RobotEntry, FRAME_PLACEHOLDER,
    MANIFEST_FILE,
};
use crate::error::{Error, Result};
use crate::io::poses::{parse_poses, read_poses, PoseFormat, PoseRecord};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A frame to add to a robot of a cell.
#[derive(Clone, Debug)]
pub struct NewFrame {
    /// The frame id (the pose file's `frame` column; substituted for `{frame}` in the image paths).
    pub id: String,
    /// The flange pose `T_base_ee` when the frame was taken, metres.
    pub t_base_ee: Isometry3<f64>,
    /// The depth image, in units of the intrinsics' `depth_scale`.
    pub depth: DepthImage,
    /// The colour image, if one was taken.
    pub color: Option<RgbImage>,
    /// Where the frame came from, for messages (e.g. `rec.bag: /camera/depth/image_rect_raw message 12`).
    pub source: String,
    /// Where the pose came from, for messages (e.g. `poses.csv line 4`).
    pub pose_origin: String,
}

/// How a robot that is new to the cell is set up (ignored for settings a robot already has, which must
/// agree; see [`append_frames`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RobotSetup {
    /// The robot's name (a directory name in the cell).
    pub name: String,
    /// The hand-eye transform `T_ee_cam`, metres. Required when the robot is new; when given for a robot the
    /// cell already has, it must equal the manifest's.
    pub hand_eye: Option<Isometry3<f64>>,
    /// The pose file format of a new robot (default KUKA).
    pub pose_format: PoseFormat,
}

impl RobotSetup {
    /// A setup with the KUKA pose format.
    pub fn new(name: &str, hand_eye: Option<Isometry3<f64>>) -> Self {
        RobotSetup {
            name: name.to_string(),
            hand_eye,
            pose_format: PoseFormat::Kuka,
        }
    }
}

/// What [`append_frames`] did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AppendReport {
    /// The cell directory.
    pub cell_dir: PathBuf,
    /// The robot the frames were added to.
    pub robot: String,
    /// The cell did not exist before (its `cell.toml` was written for the first time).
    pub created_cell: bool,
    /// The robot did not exist before.
    pub created_robot: bool,
    /// The ids of the frames added, in order.
    pub frames: Vec<String>,
    /// Frames the robot has now.
    pub frames_total: usize,
    /// Whether colour images were stored.
    pub color: bool,
    /// Files written (images, pose file, intrinsics, manifest).
    pub files_written: usize,
    /// Bytes of the images written.
    pub image_bytes: u64,
}

fn check_robot_name(name: &str) -> Result<()> {
    if name.trim().is_empty()
        || name != name.trim()
        || name.contains(['/', '\\'])
        || name.starts_with('.')
    {
        return Err(Error::InvalidInput(format!(
            "robot name {name:?} must be a non-empty directory name (no slashes, no leading dot or spaces)"
        )));
    }
    Ok(())
}

fn check_frame_id(id: &str, origin: &str) -> Result<()> {
    if id.is_empty()
        || id != id.trim()
        || id.contains(['/', '\\', ','])
        || id == ".."
        || id.starts_with('#')
    {
        return Err(Error::InvalidInput(format!(
            "{origin}: frame id {id:?} must be non-empty, without slashes, commas, surrounding spaces or a leading #"
        )));
    }
    Ok(())
}

/// Largest relative difference between two intrinsics values still taken as equal.
const INTRINSICS_TOLERANCE: f64 = 1e-9;

/// The first field in which `a` and `b` differ (beyond `INTRINSICS_TOLERANCE`), as `(field, a, b)`.
pub fn intrinsics_difference(a: &Intrinsics, b: &Intrinsics) -> Option<(String, String, String)> {
    let close =
        |x: f64, y: f64| (x - y).abs() <= INTRINSICS_TOLERANCE * x.abs().max(y.abs()).max(1.0);
    if (a.width, a.height) != (b.width, b.height) {
        return Some((
            "width x height".into(),
            format!("{}x{}", a.width, a.height),
            format!("{}x{}", b.width, b.height),
        ));
    }
    if a.model != b.model {
        return Some(("model".into(), a.model.to_string(), b.model.to_string()));
    }
    for (name, x, y) in [
        ("fx", a.fx, b.fx),
        ("fy", a.fy, b.fy),
        ("ppx", a.ppx, b.ppx),
        ("ppy", a.ppy, b.ppy),
        ("depth_scale", a.depth_scale, b.depth_scale),
    ] {
        if !close(x, y) {
            return Some((name.into(), x.to_string(), y.to_string()));
        }
    }
    for i in 0..5 {
        if !close(a.coeffs[i], b.coeffs[i]) {
            return Some((
                format!("coeffs[{i}]"),
                a.coeffs[i].to_string(),
                b.coeffs[i].to_string(),
            ));
        }
    }
    None
}

/// The next `n` free frame ids of a robot: numbers after the largest numeric id in `existing`, zero-padded to
/// the width of the existing ids (at least 3 digits).
pub fn next_frame_ids(existing: &[String], n: usize) -> Vec<String> {
    let width = existing
        .iter()
        .filter(|s| s.bytes().all(|b| b.is_ascii_digit()))
        .map(|s| s.len())
        .max()
        .unwrap_or(0)
        .max(3);
    let next = existing
        .iter()
        .filter_map(|s| s.parse::<u64>().ok())
        .max()
        .map(|m| m + 1)
        .unwrap_or(0);
    let taken: std::collections::HashSet<&str> = existing.iter().map(|s| s.as_str()).collect();
    let mut out = Vec::with_capacity(n);
    let mut k = next;
    while out.len() < n {
        let id = format!("{k:0width$}");
        if !taken.contains(id.as_str()) {
            out.push(id);
        }
        k += 1;
    }
    out
}

/// The frame ids the robot `robot` of the cell in `dir` already has (empty when the cell or the robot does
/// not exist).
pub fn existing_frame_ids(dir: &Path, robot: &str) -> Result<Vec<String>> {
    if !dir.join(MANIFEST_FILE).is_file() {
        return Ok(Vec::new());
    }
    let manifest = CellManifest::read(dir)?;
    let Some(e) = manifest.robots.iter().find(|r| r.name == robot) else {
        return Ok(Vec::new());
    };
    let (_, recs) = read_poses(dir.join(&e.poses), Some(e.pose_format))?;
    Ok(recs.into_iter().map(|r| r.frame).collect())
}

fn read_hand_eye(dir: &Path, spec: &HandEyeSpec) -> Result<Isometry3<f64>> {
    match spec {
        HandEyeSpec::Inline(t) => Ok(*t),
        HandEyeSpec::File(p) => read_hand_eye_file(&dir.join(p)),
    }
}

fn same_transform(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    let (r, t) = crate::geometry::transform::pose_error(a, b);
    r < 1e-6 && t < 1e-9
}

/// A robot of the cell before frames are added to it: its manifest entry, and for a robot the cell already
/// has, its frame ids (with their pose-file lines) and its pose file's text.
struct RobotBefore {
    entry: RobotEntry,
    is_new: bool,
    ids: HashMap<String, usize>,
    pose_text: Option<String>,
}

/// One image file to write: where, for which frame, and whether it is the colour image.
type ImageJob<'a> = (PathBuf, &'a NewFrame, bool);

/// Adds `frames` (all taken with a camera of intrinsics `intrinsics`) to the robot `setup.name` of the cell in
/// `dir`.
///
/// * No `cell.toml` in `dir` (which may not exist yet): a new cell is made with this robot as the reference.
/// * The robot is new: `setup.hand_eye` is required; the robot gets the conventional layout under
///   `<name>/` (`poses.csv` in `setup.pose_format`, `intrinsics.json`, `depth/{frame}.png`, and
///   `color/{frame}.png` when the frames have colour).
/// * The robot exists: its intrinsics file must equal `intrinsics` (within 1e-9 relative) and a given
///   `setup.hand_eye` must equal the manifest's; the new rows are appended to its pose file (existing rows are
///   kept byte for byte) in its pose format. A robot with a colour pattern needs colour on every new frame;
///   one without stores depth only (colour is dropped with a warning).
///
/// Errors (nothing written): an empty `frames`, an id the robot already has or that repeats, a depth image
/// whose size differs from the intrinsics, an image file that already exists. On an error while writing, the
/// images written by this call are removed again and the cell stays as it was.
pub fn append_frames(
    dir: &Path,
    setup: &RobotSetup,
    intrinsics: &Intrinsics,
    frames: &[NewFrame],
) -> Result<AppendReport> {
    check_robot_name(&setup.name)?;
    intrinsics
        .validate()
        .map_err(|m| Error::InvalidInput(format!("camera intrinsics: {m}")))?;
    if frames.is_empty() {
        return Err(Error::InvalidInput(format!(
            "{}: no frames to add to robot {:?}",
            dir.display(),
            setup.name
        )));
    }
    let manifest_path = dir.join(MANIFEST_FILE);
    let had_cell = manifest_path.is_file();
    let mut manifest = if had_cell {
        CellManifest::read(dir)?
    } else {
        CellManifest::new(&setup.name)
    };
    let before = match manifest.robots.iter().find(|r| r.name == setup.name) {
        Some(e) => existing_robot(dir, e.clone(), setup, intrinsics)?,
        None => new_robot(dir, setup, frames)?,
    };
    let store_color = color_storage(dir, &before.entry, setup, frames)?;
    // Every check before the first write.
    check_new_frames(dir, &before, intrinsics, frames)?;
    let jobs = image_jobs(dir, &before.entry, setup, frames, store_color)?;
    if before.is_new {
        manifest.robots.push(before.entry.clone());
    }
    manifest
        .validate()
        .map_err(|m| Error::InvalidInput(format!("{}: {m}", manifest_path.display())))?;
    let image_bytes = write_appended(dir, &manifest, &before, intrinsics, frames, &jobs)?;
    let files_written = jobs.len() + if before.is_new { 3 } else { 1 };
    // The cell must open as a whole (catches anything the checks above missed).
    let cell = Cell::open(dir)?;
    let frames_total = cell.robot(&setup.name)?.frames.len();
    Ok(AppendReport {
        cell_dir: dir.to_path_buf(),
        robot: setup.name.clone(),
        created_cell: !had_cell,
        created_robot: before.is_new,
        frames: frames.iter().map(|f| f.id.clone()).collect(),
        frames_total,
        color: store_color,
        files_written,
        image_bytes,
    })
}

/// A robot the cell has: its frames so far; its intrinsics must equal the new frames' and a given hand-eye
/// the manifest's.
fn existing_robot(
    dir: &Path,
    e: RobotEntry,
    setup: &RobotSetup,
    intrinsics: &Intrinsics,
) -> Result<RobotBefore> {
    let poses_path = dir.join(&e.poses);
    let text = std::fs::read_to_string(&poses_path).map_err(|er| Error::io(&poses_path, er))?;
    let (_, recs) = parse_poses(&text, Some(e.pose_format), &poses_path)?;
    let ids = recs.into_iter().map(|r| (r.frame, r.line)).collect();
    let intr_path = dir.join(&e.intrinsics);
    let old = Intrinsics::from_json_file(&intr_path)?;
    if let Some((field, was, now)) = intrinsics_difference(&old, intrinsics) {
        return Err(Error::format(
            &intr_path,
            format!(
                "field `{field}` is {was} but the new frames' camera has {now}; the frames of one robot \
                 share one intrinsics file: add these frames to another robot name or another cell"
            ),
        ));
    }
    if let Some(t) = &setup.hand_eye {
        let old = read_hand_eye(dir, &e.hand_eye)?;
        if !same_transform(&old, t) {
            return Err(Error::format(
                dir.join(MANIFEST_FILE),
                format!(
                    "robot {:?} already has a different hand_eye (T_ee_cam); leave the hand-eye out to keep \
                     the cell's, or edit cell.toml",
                    setup.name
                ),
            ));
        }
    }
    Ok(RobotBefore {
        entry: e,
        is_new: false,
        ids,
        pose_text: Some(text),
    })
}

/// A robot new to the cell: the conventional layout, which must not exist yet; needs a hand-eye.
fn new_robot(dir: &Path, setup: &RobotSetup, frames: &[NewFrame]) -> Result<RobotBefore> {
    let Some(t) = setup.hand_eye else {
        return Err(Error::InvalidInput(format!(
            "robot {:?} is new to the cell {}: give its hand-eye T_ee_cam (a JSON file with the 4x4 \
             matrix in metres, or `identity` until it is calibrated)",
            setup.name,
            dir.display()
        )));
    };
    let mut e = RobotEntry::standard(&setup.name, t);
    e.pose_format = setup.pose_format;
    if frames.iter().all(|f| f.color.is_some()) {
        e.color = Some(format!("{}/color/{FRAME_PLACEHOLDER}.png", setup.name));
    }
    for p in [&e.poses, &e.intrinsics] {
        let p = dir.join(p);
        if p.exists() {
            return Err(Error::InvalidInput(format!(
                "{}: exists already but robot {:?} is not in {}; it is never overwritten: remove it or \
                 choose another robot name",
                p.display(),
                setup.name,
                dir.join(MANIFEST_FILE).display()
            )));
        }
    }
    Ok(RobotBefore {
        entry: e,
        is_new: true,
        ids: HashMap::new(),
        pose_text: None,
    })
}

/// Whether colour is stored: a robot with a colour pattern needs colour on every new frame; one without drops
/// colour (with a warning).
fn color_storage(
    dir: &Path,
    entry: &RobotEntry,
    setup: &RobotSetup,
    frames: &[NewFrame],
) -> Result<bool> {
    if entry.color.is_some() {
        if let Some(f) = frames.iter().find(|f| f.color.is_none()) {
            return Err(Error::InvalidInput(format!(
                "{}: frame {} has no colour image, but robot {:?} stores colour for every frame ({:?})",
                f.source, f.id, setup.name, entry.color
            )));
        }
        return Ok(true);
    }
    if frames.iter().any(|f| f.color.is_some()) {
        log::warn!(
            "robot {:?} of {} has no colour pattern; colour images are not stored",
            setup.name,
            dir.display()
        );
    }
    Ok(false)
}

/// The new frames' ids are valid, new and distinct, and their images have the intrinsics' size.
fn check_new_frames(
    dir: &Path,
    before: &RobotBefore,
    intrinsics: &Intrinsics,
    frames: &[NewFrame],
) -> Result<()> {
    let mut new_ids: HashMap<&str, &NewFrame> = HashMap::new();
    for f in frames {
        check_frame_id(&f.id, &f.pose_origin)?;
        if let Some(line) = before.ids.get(&f.id) {
            return Err(Error::InvalidInput(format!(
                "{}: frame id {} is already in {} (line {line}); frames are never overwritten: use other ids",
                f.pose_origin,
                f.id,
                dir.join(&before.entry.poses).display()
            )));
        }
        if let Some(prev) = new_ids.insert(&f.id, f) {
            return Err(Error::InvalidInput(format!(
                "{}: frame id {} repeats the id of {}",
                f.pose_origin, f.id, prev.pose_origin
            )));
        }
        if (f.depth.width, f.depth.height) != (intrinsics.width, intrinsics.height)
            || f.depth.data.len() != f.depth.width as usize * f.depth.height as usize
        {
            return Err(Error::InvalidInput(format!(
                "{}: depth image is {}x{} but the intrinsics say {}x{}",
                f.source, f.depth.width, f.depth.height, intrinsics.width, intrinsics.height
            )));
        }
        if let Some(c) = &f.color {
            if c.data.len() != c.width as usize * c.height as usize * 3 || c.width == 0 {
                return Err(Error::InvalidInput(format!(
                    "{}: colour image has {} bytes for {}x{} RGB pixels",
                    f.source,
                    c.data.len(),
                    c.width,
                    c.height
                )));
            }
        }
    }
    Ok(())
}

/// The image files to write, none of which may exist.
fn image_jobs<'a>(
    dir: &Path,
    entry: &RobotEntry,
    setup: &RobotSetup,
    frames: &'a [NewFrame],
    store_color: bool,
) -> Result<Vec<ImageJob<'a>>> {
    let mut jobs: Vec<ImageJob> = Vec::new();
    for f in frames {
        jobs.push((frame_path(dir, &entry.depth, &f.id), f, false));
        if store_color {
            let pat = entry.color.as_ref().expect("colour pattern");
            jobs.push((frame_path(dir, pat, &f.id), f, true));
        }
    }
    for (p, f, _) in &jobs {
        if p.exists() {
            return Err(Error::InvalidInput(format!(
                "{}: exists already (frame {} of robot {:?} from {}); it is never overwritten: remove the file \
                 if no pose row refers to it, or use another frame id",
                p.display(),
                f.id,
                setup.name,
                f.pose_origin
            )));
        }
    }
    Ok(jobs)
}

/// Writes the images, then the intrinsics (new robot), then the pose file, then cell.toml (new robot); on an
/// error removes what this call wrote. Returns the bytes of image written.
fn write_appended(
    dir: &Path,
    manifest: &CellManifest,
    before: &RobotBefore,
    intrinsics: &Intrinsics,
    frames: &[NewFrame],
    jobs: &[ImageJob],
) -> Result<u64> {
    let entry = &before.entry;
    let create_parent = |p: &Path| match p.parent() {
        Some(parent) => std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e)),
        None => Ok(()),
    };
    let mut written: Vec<PathBuf> = Vec::new();
    let result = (|| -> Result<u64> {
        let mut bytes = 0;
        for (p, f, is_color) in jobs {
            create_parent(p)?;
            if *is_color {
                write_rgb_png(p, f.color.as_ref().expect("checked"))?;
            } else {
                write_depth_png(p, &f.depth)?;
            }
            written.push(p.clone());
            bytes += std::fs::metadata(p).map_err(|e| Error::io(p, e))?.len();
        }
        if before.is_new {
            let p = dir.join(&entry.intrinsics);
            create_parent(&p)?;
            intrinsics.write_json_file(&p)?;
            written.push(p);
        }
        let poses_path = dir.join(&entry.poses);
        let mut text = before
            .pose_text
            .clone()
            .unwrap_or_else(|| format!("{}\n", entry.pose_format.header()));
        if !text.ends_with('\n') {
            text.push('\n');
        }
        for f in frames {
            text.push_str(&f.id);
            text.push(',');
            text.push_str(&entry.pose_format.format_values(&f.t_base_ee));
            text.push('\n');
        }
        create_parent(&poses_path)?;
        crate::io::write_atomically(&poses_path, |w| w.write_all(text.as_bytes()))?;
        if before.is_new {
            written.push(poses_path);
            manifest.write(dir)?;
        }
        Ok(bytes)
    })();
    if result.is_err() {
        for p in &written {
            let _ = std::fs::remove_file(p);
        }
    }
    result
}

/// The name of the optional timestamp column of a recording's pose file (seconds, after `frame`).
pub const TIME_COLUMN: &str = "t_s";

/// The rows of a pose file for a recording: frame ids, poses and, when the file has a `t_s` column, the time of
/// each row.
///
/// The file is a pose CSV of any format (`kuka`, `matrix`, `xyzquat`; see [`crate::geometry::pose`]); it may
/// have a column `t_s` right after `frame`: the time in seconds, on the recording's clock, at which the robot
/// stood at that pose (needed by [`MatchMode::Time`]). Example: `frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg`.
#[derive(Clone, Debug)]
pub struct PoseRows {
    /// The file read.
    pub path: PathBuf,
    /// Its pose format.
    pub format: PoseFormat,
    /// The rows (with their 1-based line numbers).
    pub records: Vec<PoseRecord>,
    /// The `t_s` value of each row, seconds, when the file has that column.
    pub times_s: Option<Vec<f64>>,
    /// Where each row came from, when not from a line of `path` (rows taken from a recording's TF:
    /// [`PoseRows::from_tf`]).
    pub origins: Option<Vec<String>>,
}

impl PoseRows {
    /// Parses pose-file text (see [`PoseRows`]); `path` names the file in errors.
    pub fn parse(text: &str, format: Option<PoseFormat>, path: &Path) -> Result<Self> {
        let mut header_seen = false;
        let mut has_time = false;
        let mut stripped = String::with_capacity(text.len());
        let mut times = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let t = line.trim();
            if t.is_empty() || t.starts_with('#') {
                stripped.push_str(line);
                stripped.push('\n');
                continue;
            }
            let mut cols: Vec<&str> = line.split(',').collect();
            if !header_seen {
                header_seen = true;
                has_time = cols.len() > 1 && cols[1].trim().eq_ignore_ascii_case(TIME_COLUMN);
            } else if has_time {
                let Some(s) = cols.get(1) else {
                    return Err(Error::format(
                        path,
                        format!(
                            "line {}: expected a {TIME_COLUMN} column after frame",
                            i + 1
                        ),
                    ));
                };
                let v: f64 = s
                    .trim()
                    .parse()
                    .ok()
                    .filter(|v: &f64| v.is_finite())
                    .ok_or_else(|| {
                        Error::format(
                            path,
                            format!(
                                "line {}: column {TIME_COLUMN}: {:?} is not a finite number",
                                i + 1,
                                s.trim()
                            ),
                        )
                    })?;
                times.push(v);
            }
            if has_time && cols.len() > 1 {
                cols.remove(1);
            }
            stripped.push_str(&cols.join(","));
            stripped.push('\n');
        }
        let (format, records) = parse_poses(&stripped, format, path)?;
        Ok(PoseRows {
            path: path.to_path_buf(),
            format,
            records,
            times_s: has_time.then_some(times),
            origins: None,
        })
    }

    /// Reads a pose file (see [`PoseRows::parse`]).
    pub fn read(path: impl AsRef<Path>, format: Option<PoseFormat>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::parse(&text, format, path)
    }

    /// `"<file> line <n>"` of row `i` (or where it came from, see [`PoseRows::origins`]).
    pub fn origin(&self, i: usize) -> String {
        match self.origins.as_ref().and_then(|o| o.get(i)) {
            Some(o) => o.clone(),
            None => format!("{} line {}", self.path.display(), self.records[i].line),
        }
    }
}

/// How recorded depth frames are paired with pose rows.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", tag = "mode")]
pub enum MatchMode {
    /// The k-th depth frame of the recording (in timestamp order) takes the k-th pose row. The recording must
    /// hold exactly as many depth frames as the file has rows.
    Order,
    /// Each pose row takes the depth frame nearest in time to its `t_s` value; the distance must not exceed
    /// `tolerance_s` seconds, and no two rows may take the same frame. Frames no row takes are skipped.
    Time {
        /// Largest accepted distance between a row's `t_s` and its frame's timestamp, seconds.
        tolerance_s: f64,
    },
}

/// Settings of [`match_frames`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// How depth frames are paired with pose rows (default [`MatchMode::Order`]).
    pub mode: MatchMode,
    /// Largest distance between a depth frame's and its colour frame's timestamps, seconds (default 0.02,
    /// below the 33 ms frame period at 30 fps). Colour frames are paired with depth frames by nearest timestamp.
    pub color_tolerance_s: f64,
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            mode: MatchMode::Order,
            color_tolerance_s: 0.02,
        }
    }
}

impl MatchConfig {
    /// Checks the ranges; the error names the field (`mode.tolerance_s`, `color_tolerance_s`).
    pub fn validate(&self) -> Result<()> {
        if let MatchMode::Time { tolerance_s } = self.mode {
            crate::error::check::non_negative("mode.tolerance_s", tolerance_s)?;
        }
        crate::error::check::non_negative("color_tolerance_s", self.color_tolerance_s)
    }
}

/// One recorded frame as a recording lists it: its timestamp and the key to read it with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameStamp {
    /// Timestamp, seconds (the recording's clock).
    pub t_s: f64,
    /// An opaque key for [`Recording::read_frames`].
    pub key: u64,
}

/// A stream of a recording: its name (topic or stream) and its frames in timestamp order.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamFrames {
    /// The topic or stream name (for messages).
    pub name: String,
    /// The frames, sorted by timestamp.
    pub frames: Vec<FrameStamp>,
}

/// One depth frame paired with a pose row (and maybe a colour frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameMatch {
    /// Index of the pose row in [`PoseRows::records`].
    pub row: usize,
    /// Index of the depth frame in the depth stream.
    pub depth: usize,
    /// Index of the colour frame in the colour stream, when colour is paired.
    pub color: Option<usize>,
}

fn fmt_s(t: f64) -> String {
    format!("{t:.6}")
}

/// Pairs the depth frames of a recording with the pose rows (see [`MatchMode`]), and each matched depth frame
/// with the colour frame nearest in time when `color` is given. Errors name the pose file and row, or the
/// stream and frame.
pub fn match_frames(
    rows: &PoseRows,
    depth: &StreamFrames,
    color: Option<&StreamFrames>,
    cfg: &MatchConfig,
    recording: &Path,
) -> Result<Vec<FrameMatch>> {
    cfg.validate()?;
    let n = depth.frames.len();
    if n == 0 {
        return Err(Error::format(
            recording,
            format!("the depth stream {} holds no frames", depth.name),
        ));
    }
    let span = format!(
        "the depth frames of {} span t = {} .. {} s",
        depth.name,
        fmt_s(depth.frames[0].t_s),
        fmt_s(depth.frames[n - 1].t_s)
    );
    let mut out: Vec<FrameMatch> = match cfg.mode {
        MatchMode::Order => {
            let m = rows.records.len();
            if m > n {
                return Err(Error::format(
                    &rows.path,
                    format!(
                        "line {}: pose row {} (frame {}) has no depth frame: {} holds only {n} depth frames on {} \
                         (--match order pairs the k-th frame with the k-th row)",
                        rows.records[n].line,
                        n + 1,
                        rows.records[n].frame,
                        recording.display(),
                        depth.name
                    ),
                ));
            }
            if n > m {
                return Err(Error::format(
                    &rows.path,
                    format!(
                        "has {m} pose rows but {} holds {n} depth frames on {}; --match order needs one row per \
                         frame (depth frame {} at t = {} s has no row). To pick frames by time, add a {TIME_COLUMN} \
                         column and use --match time",
                        recording.display(),
                        depth.name,
                        m + 1,
                        fmt_s(depth.frames[m].t_s)
                    ),
                ));
            }
            (0..m)
                .map(|i| FrameMatch {
                    row: i,
                    depth: i,
                    color: None,
                })
                .collect()
        }
        MatchMode::Time { tolerance_s } => {
            if !(tolerance_s.is_finite() && tolerance_s >= 0.0) {
                return Err(Error::Config {
                    field: "match.tolerance_s".into(),
                    msg: format!("must be ≥ 0 seconds, found {tolerance_s}"),
                });
            }
            let Some(times) = &rows.times_s else {
                return Err(Error::format(
                    &rows.path,
                    format!(
                        "--match time needs a {TIME_COLUMN} column after frame (e.g. header frame,{TIME_COLUMN},{})",
                        rows.format.columns()[1..].join(",")
                    ),
                ));
            };
            let mut taken: HashMap<usize, usize> = HashMap::new();
            let mut out = Vec::with_capacity(times.len());
            for (i, &t) in times.iter().enumerate() {
                let k = nearest(&depth.frames, t).expect("non-empty");
                let d = (depth.frames[k].t_s - t).abs();
                if d > tolerance_s {
                    return Err(Error::format(
                        &rows.path,
                        format!(
                            "line {}: no depth frame within {:.1} ms of {TIME_COLUMN} = {} (frame {}): the nearest is at \
                             {} s, {:.1} ms away; {span}",
                            rows.records[i].line,
                            tolerance_s * 1e3,
                            fmt_s(t),
                            rows.records[i].frame,
                            fmt_s(depth.frames[k].t_s),
                            d * 1e3
                        ),
                    ));
                }
                if let Some(&j) = taken.get(&k) {
                    return Err(Error::format(
                        &rows.path,
                        format!(
                            "line {}: row {} takes the same depth frame (t = {} s) as line {}; the rows are closer \
                             in time than the frame period",
                            rows.records[i].line,
                            rows.records[i].frame,
                            fmt_s(depth.frames[k].t_s),
                            rows.records[j].line
                        ),
                    ));
                }
                taken.insert(k, i);
                out.push(FrameMatch {
                    row: i,
                    depth: k,
                    color: None,
                });
            }
            out
        }
    };
    if let Some(c) = color {
        let tol = cfg.color_tolerance_s;
        for m in &mut out {
            let t = depth.frames[m.depth].t_s;
            let k = nearest(&c.frames, t).filter(|&k| (c.frames[k].t_s - t).abs() <= tol);
            let Some(k) = k else {
                return Err(Error::format(
                    recording,
                    format!(
                        "depth frame at t = {} s ({}, pose row {}) has no colour frame on {} within {:.1} ms",
                        fmt_s(t),
                        depth.name,
                        rows.origin(m.row),
                        c.name,
                        tol * 1e3
                    ),
                ));
            };
            m.color = Some(k);
        }
    }
    Ok(out)
}

/// Index of the frame nearest in time to `t` (frames sorted by time), `None` when there are none.
fn nearest(frames: &[FrameStamp], t: f64) -> Option<usize> {
    if frames.is_empty() {
        return None;
    }
    let i = frames.partition_point(|f| f.t_s < t);
    let mut best = i.min(frames.len() - 1);
    if i > 0 && (t - frames[i - 1].t_s).abs() <= (frames[best].t_s - t).abs() {
        best = i - 1;
    }
    Some(best)
}

/// What a recording holds: its file, the depth camera's intrinsics and the frames of its streams.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordingInfo {
    /// The recording's file.
    pub path: PathBuf,
    /// The depth camera's intrinsics with its depth scale.
    pub intrinsics: Intrinsics,
    /// The depth frames, in timestamp order.
    pub depth: StreamFrames,
    /// The colour frames, when the recording has colour and it was asked for.
    pub color: Option<StreamFrames>,
}

/// A recording that can be imported into a cell: what it holds ([`RecordingInfo`]) and a way to read chosen
/// frames.
pub trait Recording {
    /// What the recording holds.
    fn info(&self) -> &RecordingInfo;
    /// Reads the depth frames with keys `depth` and the colour frames with keys `color` (keys from
    /// [`FrameStamp::key`]), in the order given. Colour is converted to RGB8.
    fn read_frames(
        &mut self,
        depth: &[u64],
        color: &[u64],
    ) -> Result<(Vec<DepthImage>, Vec<RgbImage>)>;

    /// The recording's file.
    fn path(&self) -> &Path {
        &self.info().path
    }
    /// The depth camera's intrinsics with its depth scale.
    fn intrinsics(&self) -> &Intrinsics {
        &self.info().intrinsics
    }
    /// The depth frames, in timestamp order.
    fn depth(&self) -> &StreamFrames {
        &self.info().depth
    }
    /// The colour frames, when the recording has colour and it was asked for.
    fn color(&self) -> Option<&StreamFrames> {
        self.info().color.as_ref()
    }
}

/// What [`import_recording`] did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    /// The recording imported.
    pub recording: PathBuf,
    /// The depth stream read (topic or stream name).
    pub depth_stream: String,
    /// The colour stream read, if any.
    pub color_stream: Option<String>,
    /// Depth frames in the recording.
    pub depth_frames_in_recording: usize,
    /// The intrinsics written (or checked against the robot's).
    pub intrinsics: Intrinsics,
    /// Timestamps of the imported frames, seconds, in the order of [`AppendReport::frames`].
    pub stamps_s: Vec<f64>,
    /// What was appended to the cell.
    pub append: AppendReport,
}

/// Imports `recording` into robot `setup.name` of the cell in `cell_dir`: pairs its depth frames with the rows
/// of `rows` ([`match_frames`]), reads the paired frames and appends them ([`append_frames`]) with the frame
/// ids and poses of the rows.
pub fn import_recording(
    recording: &mut dyn Recording,
    rows: &PoseRows,
    cfg: &MatchConfig,
    setup: &RobotSetup,
    cell_dir: &Path,
) -> Result<ImportReport> {
    let path = recording.path().to_path_buf();
    let matches = match_frames(rows, recording.depth(), recording.color(), cfg, &path)?;
    let depth_keys: Vec<u64> = matches
        .iter()
        .map(|m| recording.depth().frames[m.depth].key)
        .collect();
    let color_keys: Vec<u64> = match recording.color() {
        Some(c) => matches
            .iter()
            .map(|m| c.frames[m.color.expect("colour matched")].key)
            .collect(),
        None => Vec::new(),
    };
    let (depths, colors) = recording.read_frames(&depth_keys, &color_keys)?;
    let depth_name = recording.depth().name.clone();
    let mut colors = colors.into_iter();
    let mut frames = Vec::with_capacity(matches.len());
    let mut stamps = Vec::with_capacity(matches.len());
    for (m, depth) in matches.iter().zip(depths) {
        let rec = &rows.records[m.row];
        let t = recording.depth().frames[m.depth].t_s;
        stamps.push(t);
        frames.push(NewFrame {
            id: rec.frame.clone(),
            t_base_ee: rec.pose,
            depth,
            color: colors.next(),
            source: format!(
                "{}: {depth_name} frame {} (t = {} s)",
                path.display(),
                m.depth + 1,
                fmt_s(t)
            ),
            pose_origin: rows.origin(m.row),
        });
    }
    let setup = RobotSetup {
        pose_format: rows.format,
        ..setup.clone()
    };
    let intrinsics = recording.intrinsics().clone();
    let append = append_frames(cell_dir, &setup, &intrinsics, &frames)?;
    Ok(ImportReport {
        recording: path,
        depth_stream: depth_name,
        color_stream: recording.color().map(|c| c.name.clone()),
        depth_frames_in_recording: recording.depth().frames.len(),
        intrinsics,
        stamps_s: stamps,
        append,
    })
}

#[cfg(test)]
mod tests;
