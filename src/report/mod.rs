//! The results of the commands as the library reports them: one `Serialize` type per result, in one
//! vocabulary. The CLI's `--json` prints these, `calibrate --output` writes them, the Python package
//! returns them.
//!
//! Conventions (schema version 1, named in each report's `schema` field, e.g. `depthcal.calibration/1`):
//! lengths in metres (`_m`; `register` reports in the clouds' unit, metres for depthcal's own clouds),
//! angles in degrees (`_deg`), times in milliseconds (`_ms`). A pose is always a [`PoseReport`]
//! (`matrix`, `xyz_m`, `quaternion_xyzw`, `kuka_xyzabc`); a value that may be absent is `null`.
//! Hand-eye residuals and the cell.toml hand-eye 1-σ stay in millimetres, the unit hand-eye tools and
//! the cell format use; image coordinates are in pixels (`_px`). docs/json.md lists every field.

pub mod calibration;
pub mod capture;
pub mod comparison;
pub mod fusion;
pub mod handeye;
pub mod handeye_depth;
pub mod intrinsics;
pub mod markers;
pub mod matching;
pub mod plan;
pub mod pose;
pub mod registration;
pub mod robots;
pub mod routes;
pub mod simulation;

pub use calibration::{CalibrationReport, CALIBRATION_SCHEMA};
pub use capture::{
    CaptureReport, ImportReport, RecordingReport, CAPTURE_SCHEMA, IMPORT_SCHEMA, RECORDING_SCHEMA,
};
pub use comparison::{ComparisonReport, COMPARISON_SCHEMA};
pub use fusion::{FusionReport, FUSION_SCHEMA};
pub use handeye::{HandEyeInputs, HandEyeReport, HANDEYE_SCHEMA};
pub use handeye_depth::{
    HandEyeDepthReport, JointHandEyeReport, HANDEYE_DEPTH_SCHEMA, HANDEYE_JOINT_SCHEMA,
};
pub use intrinsics::{IntrinsicsReport, INTRINSICS_SCHEMA};
pub use markers::{MarkerImageReport, MarkersReport, MARKERS_SCHEMA};
pub use matching::{MatchReport, MATCH_SCHEMA};
pub use plan::{PlanReport, PLAN_SCHEMA};
pub use pose::{ErrorReport, PoseReport, SigmaReport, Timings};
pub use registration::{RegistrationInputs, RegistrationReport, REGISTRATION_SCHEMA};
pub use routes::{RoutesReport, ROUTES_SCHEMA};
pub use simulation::{SimulationReport, SIMULATION_SCHEMA};
