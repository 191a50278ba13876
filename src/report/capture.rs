//! The reports of `capture`, `import` and `import --list`: [`CaptureReport`], [`ImportReport`] and
//! [`RecordingReport`].

use crate::camera::Intrinsics;
use crate::capture::tf::{TfBuffer, TfEdge};
use crate::capture::{AppendReport, RecordingInfo};
use serde::Serialize;

/// The schema name and version of [`CaptureReport`].
pub const CAPTURE_SCHEMA: &str = "depthcal.capture/1";
/// The schema name and version of [`ImportReport`].
pub const IMPORT_SCHEMA: &str = "depthcal.import/1";
/// The schema name and version of [`RecordingReport`].
pub const RECORDING_SCHEMA: &str = "depthcal.recording/1";

/// Frames taken from a live camera into a robot of a cell dataset, as `depthcal capture --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct CaptureReport {
    /// [`CAPTURE_SCHEMA`].
    pub schema: &'static str,
    /// The camera's name.
    pub camera: String,
    /// The camera's serial number.
    pub serial: String,
    /// The depth stream's intrinsics (pixels) with its depth scale (metres per unit), as written to the cell.
    pub intrinsics: Intrinsics,
    /// The cell directory.
    pub cell_dir: String,
    /// The robot the frames were added to.
    pub robot: String,
    /// The ids of the frames taken, in order.
    pub frames: Vec<String>,
    /// Frames the robot has now.
    pub frames_total: usize,
    /// The cell did not exist before.
    pub created_cell: bool,
    /// The robot did not exist before.
    pub created_robot: bool,
    /// Colour images were stored.
    pub color: bool,
}

impl CaptureReport {
    /// The report of the appends `appends` (one per batch of frames taken, in order; at least one) from the
    /// camera `camera` (serial `serial`) with the depth intrinsics `intrinsics`.
    pub fn new(
        camera: &str,
        serial: &str,
        intrinsics: &Intrinsics,
        appends: &[AppendReport],
    ) -> crate::Result<Self> {
        let (Some(first), Some(last)) = (appends.first(), appends.last()) else {
            return Err(crate::Error::InvalidInput(
                "a capture report needs at least one batch of frames".into(),
            ));
        };
        Ok(CaptureReport {
            schema: CAPTURE_SCHEMA,
            camera: camera.to_string(),
            serial: serial.to_string(),
            intrinsics: intrinsics.clone(),
            cell_dir: first.cell_dir.display().to_string(),
            robot: first.robot.clone(),
            frames: appends.iter().flat_map(|r| r.frames.clone()).collect(),
            frames_total: last.frames_total,
            created_cell: first.created_cell,
            created_robot: first.created_robot,
            color: last.color,
        })
    }
}

/// A recording imported into a robot of a cell dataset, as `depthcal import --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct ImportReport {
    /// [`IMPORT_SCHEMA`].
    pub schema: &'static str,
    /// The recording imported.
    pub recording: String,
    /// The depth stream read (topic or stream name).
    pub depth_stream: String,
    /// The colour stream read; `null` without colour.
    pub color_stream: Option<String>,
    /// Depth frames in the recording.
    pub depth_frames_in_recording: usize,
    /// The intrinsics written (or checked against the robot's): pixels, depth scale in metres per unit.
    pub intrinsics: Intrinsics,
    /// Timestamps of the imported frames, seconds (the recording's clock), in the order of `append.frames`.
    pub stamps_s: Vec<f64>,
    /// What was appended to the cell.
    pub append: AppendReport,
    /// Wall time of the import, seconds.
    pub seconds: f64,
}

impl ImportReport {
    /// The report of the import `r`, done in `seconds`.
    pub fn new(r: &crate::capture::ImportReport, seconds: f64) -> Self {
        ImportReport {
            schema: IMPORT_SCHEMA,
            recording: r.recording.display().to_string(),
            depth_stream: r.depth_stream.clone(),
            color_stream: r.color_stream.clone(),
            depth_frames_in_recording: r.depth_frames_in_recording,
            intrinsics: r.intrinsics.clone(),
            stamps_s: r.stamps_s.clone(),
            append: r.append.clone(),
            seconds,
        }
    }
}

/// What a recording holds, as `depthcal import --list --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingReport {
    /// [`RECORDING_SCHEMA`].
    pub schema: &'static str,
    /// The recording's file.
    pub recording: String,
    /// The depth stream (topic or stream name).
    pub depth_stream: String,
    /// Its frames.
    pub depth_frames: usize,
    /// Their timestamps, seconds (the recording's clock), in order.
    pub depth_stamps_s: Vec<f64>,
    /// The colour stream; `null` when there is none or it was not asked for.
    pub color_stream: Option<String>,
    /// Its frames; `null` without a colour stream.
    pub color_frames: Option<usize>,
    /// The depth camera's intrinsics (pixels) with its depth scale (metres per unit).
    pub intrinsics: Intrinsics,
    /// The transforms of `/tf` and `/tf_static`, by child frame (empty when not read).
    pub tf: Vec<TfEdge>,
}

impl RecordingReport {
    /// The report of the recording `info` with its transforms `tf`.
    pub fn new(info: &RecordingInfo, tf: &TfBuffer) -> Self {
        RecordingReport {
            schema: RECORDING_SCHEMA,
            recording: info.path.display().to_string(),
            depth_stream: info.depth.name.clone(),
            depth_frames: info.depth.frames.len(),
            depth_stamps_s: info.depth.frames.iter().map(|f| f.t_s).collect(),
            color_stream: info.color.as_ref().map(|c| c.name.clone()),
            color_frames: info.color.as_ref().map(|c| c.frames.len()),
            intrinsics: info.intrinsics.clone(),
            tf: tf.edges(),
        }
    }
}
