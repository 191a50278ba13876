//! The report of `simulate`: [`SimulationReport`].

use super::pose::PoseReport;
use serde::Serialize;

/// The schema name and version of [`SimulationReport`].
pub const SIMULATION_SCHEMA: &str = "depthcal.simulation/1";

/// A simulated cell dataset written to disk, as `depthcal simulate --json` prints it (and the Python
/// package's `simulate` returns it).
#[derive(Clone, Debug, Serialize)]
pub struct SimulationReport {
    /// [`SIMULATION_SCHEMA`].
    pub schema: &'static str,
    /// The directory the cell dataset was written into.
    pub out_dir: String,
    /// The seed of everything random.
    pub seed: u64,
    /// The robots' names; the first is the reference.
    pub robots: Vec<String>,
    /// Frames per robot.
    pub frames_per_robot: usize,
    /// Depth resolution, `WIDTHxHEIGHT` pixels.
    pub resolution: String,
    /// Objects on the table.
    pub objects: usize,
    /// The true `T_base1_base2` (as in `ground_truth.json`): maps the other robot's base coordinates into
    /// the reference's; metres.
    #[serde(rename = "T_base1_base2")]
    pub t_base1_base2: PoseReport,
    /// Distance between the two bases, metres.
    pub base_distance_m: f64,
    /// Per robot (reference first): the fraction of the surface its views see that another robot's views
    /// also see, 0–1.
    pub shared_fraction: Vec<f64>,
    /// The view spread chosen for the asked overlap, 0–1.
    pub view_spread: f64,
    /// Files written.
    pub files: usize,
    /// Bytes written.
    pub bytes: u64,
    /// Wall time of generating and writing, seconds.
    pub seconds: f64,
}

#[cfg(feature = "sim")]
impl SimulationReport {
    /// The report of `cell`, simulated with `cfg` and written to `out_dir` (`stats`) in `seconds`.
    pub fn new(
        cell: &crate::sim::SimCell,
        cfg: &crate::sim::SimConfig,
        stats: &crate::sim::WriteStats,
        out_dir: &std::path::Path,
        seconds: f64,
    ) -> Self {
        let t = cell.t_base1_base2();
        SimulationReport {
            schema: SIMULATION_SCHEMA,
            out_dir: out_dir.display().to_string(),
            seed: cfg.seed,
            robots: cell.robots.iter().map(|r| r.name.clone()).collect(),
            frames_per_robot: cfg.frames,
            resolution: cfg.resolution.to_string(),
            objects: cell.scene.objects.len(),
            t_base1_base2: PoseReport::new(&t),
            base_distance_m: t.translation.vector.norm(),
            shared_fraction: cell.shared.clone(),
            view_spread: cell.view_spread,
            files: stats.files,
            bytes: stats.bytes,
            seconds,
        }
    }
}
