//! The settings of `calibrate` ([`CalibrateConfig`]): every stage's configuration in one place, with the
//! defaults tuned for fused robot clouds and the checks that name a bad field. The depth initialiser's
//! defaults ([`GlobalRegistration::default`]) come from here, so that `calibrate` and a hand-built
//! initialiser agree.

use crate::calibration::consistency::ConsistencyConfig;
use crate::calibration::handeye::depth::check::HandEyeCheckConfig;
use crate::calibration::initializer::{GlobalRegistration, SearchConfig};
use crate::calibration::pose_scatter::PoseScatterConfig;
use crate::calibration::visibility::VisibilityConfig;
use crate::error::{Error, Result};
use crate::fusion::FuseConfig;
use crate::registration::correspondence::MatchConfig;
use crate::registration::{IcpConfig, IcpFactor, RansacConfig, RegisterConfig, RobustKernel};
use serde::{Deserialize, Serialize};

/// Settings of `calibrate` ([`crate::calibration::robot_to_robot::calibrate`]) and of every stage it runs:
/// one settings layer for the library, the CLI and Python.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrateConfig {
    /// Fusion of each robot's frames (default: automatic voxel at 4 pixel footprints, at most 11 mm, no
    /// outlier removal (the trimmed ICP and the robust kernel deal with stray points), no normals
    /// (registration estimates its own)).
    pub fuse: FuseConfig,
    /// Registration settings for the refinement (and for the depth initialiser): three ICP levels and
    /// one-way feature matches by default.
    pub register: RegisterConfig,
    /// Use the `[priors]` of `cell.toml` (default true).
    pub use_priors: bool,
    /// Seed of every randomised step: calibrate's one seed (the initialisers and the refinement take it;
    /// `register.seed` must be left out).
    pub seed: u64,
    /// The marker method's settings (`--method marker`).
    pub marker: crate::calibration::marker_init::MarkerMethodConfig,
    /// The 2D-feature method's settings (`--method features`).
    pub features: crate::calibration::feature_init::FeatureMethodConfig,
    /// The check of each robot's own frames against each other ([`crate::calibration::consistency`]).
    pub consistency: ConsistencyConfig,
    /// Registration uses only the fused points within this multiple of the robot's median range (the
    /// distance from a point to the cameras that saw it); `None` keeps every point. Default 2.5: depth noise
    /// grows with the square of the range, so a surface at 2.5 times the median range is about six times
    /// noisier than the workspace the cameras look at, and a wide far floor or wall then outweighs the
    /// shared objects in every stage (measured on foreign cells with a floor in view: untrusted without
    /// the cut, 0.007° / 0.13 mm with it; 2.0 cost the demo cell 0.02° / 0.25 mm). The cut is made in
    /// the fusion, before its surface fit (`fuse.max_range_factor` is set from it and must be left
    /// out). The free-space test, the pose scatter and the hand-eye check still use whole frames.
    pub max_range_factor: Option<f64>,
    /// `--refine-hand-eye`: the per-robot hand-eye refinements from depth, the joint refinement of both
    /// hand-eyes with `T_base1_base2`, and whether its base-to-base transform is adopted
    /// (docs/handeye.md#hand-eye-from-depth).
    pub refine_hand_eye: crate::calibration::handeye::depth::joint::RefineHandEyeConfig,
    /// The check of each robot's stated hand-eye (and its 1-σ) against its own depth frames
    /// ([`crate::calibration::handeye::depth::check`]); an inconsistent one makes the result untrusted.
    pub hand_eye_check: HandEyeCheckConfig,
    /// The free-space test of hypotheses and of the result ([`crate::calibration::visibility`]); its
    /// `robot_body_radius_m` also leaves the other robot's body out of the refinement under each
    /// hypothesis ([`crate::calibration::hypotheses`]).
    pub visibility: VisibilityConfig,
    /// The depth initialiser's searches ([`SearchConfig`]).
    pub search: SearchConfig,
    /// Each robot's pose scatter from its own frames, and the frames moved by it before they are fused
    /// ([`crate::calibration::pose_scatter`]).
    pub pose_scatter: PoseScatterConfig,
    /// Two robots' base origins stand at least this far apart, metres (default 0.12; 0 turns it off). Not
    /// a prior of the cell but a fact of any cell: two bases cannot share one footprint, and the smallest
    /// common arm's is 128 mm across (a UR3's). The global search drops hypotheses that put the bases
    /// closer, and a result that does is not trusted. On cells whose robots each see mostly their own
    /// side of the workspace, the clouds laid on each other (the bases 6-77 mm apart) explained the data
    /// better than the truth and were the answer on 4 of 10 wrong low-overlap cells (docs/accuracy.md).
    pub min_base_distance_m: f64,
    /// The largest 1-σ over rotation directions, degrees, that the registration alone (its covariance
    /// without the inputs': hand-eyes, poses) may leave in a trusted result (default 1°; `None`: no
    /// bound). With [`CalibrateConfig::max_registration_sigma_m`] ten times what a right answer is held to
    /// on the simulated cells (0.1° / 2 mm): an answer the geometry pins only that loosely is not one to
    /// use, however its hold test came out. Measured on ~1,300 sweep cells: right and trusted answers
    /// leave at most 0.74° / 6.0 mm, the real 7-Scenes cell 0.19° / 11.2 mm (docs/accuracy.md).
    pub max_registration_sigma_deg: Option<f64>,
    /// The same over translation directions, metres (default 0.02; `None`: no bound).
    pub max_registration_sigma_m: Option<f64>,
    /// Cells of three or more robots: the pose graph over the pairwise results
    /// (`calibration::multi_robot`, which builds on this module).
    pub pose_graph: crate::calibration::pose_graph::PoseGraphConfig,
}

impl Default for CalibrateConfig {
    fn default() -> Self {
        CalibrateConfig {
            fuse: FuseConfig {
                auto_voxel_factor: 4.0,
                // Coarser than 11 mm, the fused clouds blur the objects that pin the rotation: on the 178
                // kept cells whose automatic voxel was coarser (424-pixel cameras, a far floor in the first
                // frame), 128 right and trusted and 3 wrong and trusted became 140 and 0 (chosen on seeds
                // 5000-9005; over 1290 cells of seeds 1000-11005, with the precision bound below, 7 wrong
                // and trusted became 2: docs/accuracy.md, "The fusion voxel's largest edge").
                max_auto_voxel_m: Some(0.011),
                outlier: None,
                normals: None,
                // Each frame's depth in 4x4-pixel blocks, for the free-space test of the hypotheses.
                depth_views: Some(4),
                ..FuseConfig::default()
            },
            register: RegisterConfig {
                icp_levels: 3,
                // GICP with Tukey's kernel: from the truth on simulated cells it settles at a median
                // 0.010° / 0.15 mm (worst of 6: 0.037° / 0.31 mm) where point-to-plane with Huber settled at
                // 0.059° / 0.79 mm (worst 0.126° / 1.66 mm) (`tools/refine_probe.rs`).
                icp: IcpConfig {
                    factor: IcpFactor::Gicp,
                    kernel: RobustKernel::Tukey,
                    // Pairs between different surfaces (a face one robot saw against the edge of one the
                    // other saw) bias the yaw where the robots share little.
                    max_normal_angle_deg: Some(30.0),
                    // GICP creeps along a cell's weakest direction: a foreign table cell needed 108
                    // iterations at its middle level (40 left it 0.25° / 2.8 mm off and unconverged).
                    // Cells that converge early do not pay for the larger budget.
                    max_iterations: 150,
                    ..IcpConfig::default()
                },
                // One-way matches: the priors already prune hypotheses hard, and on cells whose robots
                // share little (35-50%) the mutual filter left too few true matches (measured).
                matching: MatchConfig {
                    mutual: false,
                    ..MatchConfig::default()
                },
                // Many distinct hypotheses for the free-space test to choose from: at low overlap the
                // truth is rarely among RANSAC's 50 best by feature inliers.
                ransac: RansacConfig {
                    verify_top: 300,
                    ..RansacConfig::default()
                },
                // GICP on fused cells leaves a smaller systematic part than the generic floor assumes:
                // with 0.12 voxel the normalised errors of seeded cells had an RMS of 0.21 (`cell_sweep`).
                systematic_voxel_fraction: 0.04,
                // Fused clouds know which side each surface was seen from.
                sided: true,
                ..RegisterConfig::default()
            },
            use_priors: true,
            seed: 0,
            marker: Default::default(),
            features: Default::default(),
            consistency: ConsistencyConfig::default(),
            max_range_factor: Some(2.5),
            refine_hand_eye: Default::default(),
            hand_eye_check: HandEyeCheckConfig::default(),
            visibility: VisibilityConfig::default(),
            search: SearchConfig::default(),
            pose_scatter: PoseScatterConfig::default(),
            min_base_distance_m: 0.12,
            max_registration_sigma_deg: Some(1.0),
            max_registration_sigma_m: Some(0.02),
            pose_graph: Default::default(),
        }
    }
}

impl CalibrateConfig {
    /// Checks the ranges of every field and nested configuration; the error names the field, e.g.
    /// `register.icp.max_iterations`. [`crate::calibration::robot_to_robot::calibrate_request`] calls it first.
    pub fn validate(&self) -> Result<()> {
        self.fuse.validate()?;
        self.register.validate().map_err(|e| e.within("register"))?;
        if self.register.seed != RegisterConfig::default().seed && self.register.seed != self.seed {
            return Err(Error::config(
                "register.seed",
                format!(
                    "calibrate has one seed, `seed` ({}); set it there instead of register.seed ({})",
                    self.seed, self.register.seed
                ),
            ));
        }
        if self.register.ransac.constraint != Default::default() {
            return Err(Error::config(
                "register.ransac.constraint",
                "calibrate takes its pose constraint from the cell's [priors] (cell.toml); state the priors there",
            ));
        }
        self.marker.validate()?;
        self.features.validate()?;
        self.consistency.validate()?;
        if let Some(f) = self.max_range_factor {
            crate::error::check::positive("max_range_factor", f)?;
        }
        if self.fuse.max_range_factor.is_some() {
            return Err(Error::config(
                "fuse.max_range_factor",
                "calibrate has one range cut, `max_range_factor`; set it there",
            ));
        }
        self.refine_hand_eye.validate()?;
        self.hand_eye_check.validate()?;
        self.visibility.validate()?;
        self.pose_scatter.validate()?;
        self.search.validate()?;
        crate::error::check::non_negative("min_base_distance_m", self.min_base_distance_m)?;
        if let Some(v) = self.max_registration_sigma_deg {
            crate::error::check::positive("max_registration_sigma_deg", v)?;
        }
        if let Some(v) = self.max_registration_sigma_m {
            crate::error::check::positive("max_registration_sigma_m", v)?;
        }
        self.pose_graph.validate()?;
        Ok(())
    }
}

impl Default for GlobalRegistration {
    /// The depth initialiser as `calibrate` runs it: [`CalibrateConfig`]'s registration, free-space test and
    /// searches.
    fn default() -> Self {
        let c = CalibrateConfig::default();
        GlobalRegistration {
            config: c.register,
            visibility: Some(c.visibility),
            search: c.search,
        }
    }
}
