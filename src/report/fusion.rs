//! The report of `fuse`: [`FusionReport`].

use crate::fusion::FusedCloud;
use serde::Serialize;

/// The schema name and version of [`FusionReport`].
pub const FUSION_SCHEMA: &str = "depthcal.fusion/1";

/// One robot's frames fused into one cloud in its base frame, as `depthcal fuse --json` prints it.
#[derive(Clone, Debug, Serialize)]
pub struct FusionReport {
    /// [`FUSION_SCHEMA`].
    pub schema: &'static str,
    /// The robot.
    pub robot: String,
    /// The cloud file written, if any.
    pub output: Option<String>,
    /// Frames fused.
    pub frames: usize,
    /// Points deprojected from all frames.
    pub points_in: usize,
    /// Of those, samples outside the crop box.
    pub points_cropped: usize,
    /// Voxel edge, metres.
    pub voxel_size_m: f64,
    /// Occupied voxels.
    pub voxels: usize,
    /// Voxels dropped for too few samples.
    pub sparse_removed: usize,
    /// Points removed by the statistical outlier filter.
    pub outliers_removed: usize,
    /// Points in the result.
    pub points: usize,
    /// The result carries normals.
    pub normals: bool,
    /// Wall time, seconds.
    pub seconds: f64,
}

impl FusionReport {
    /// The report of `fused` for `robot`, written to `output`, in `seconds`.
    pub fn new(fused: &FusedCloud, robot: &str, output: Option<String>, seconds: f64) -> Self {
        let s = &fused.stats;
        FusionReport {
            schema: FUSION_SCHEMA,
            robot: robot.to_string(),
            output,
            frames: s.frames,
            points_in: s.points_in,
            points_cropped: s.points_cropped,
            voxel_size_m: s.voxel_size_m,
            voxels: s.voxels,
            sparse_removed: s.sparse_removed,
            outliers_removed: s.outliers_removed,
            points: s.points_out,
            normals: fused.cloud.normals.is_some(),
            seconds,
        }
    }
}
