//! The report of `register`: [`RegistrationReport`].

use super::pose::{matrix6_rows, AmbiguityReport, ErrorReport, PoseReport, SigmaReport, Timings};
use crate::registration::quality::Degeneracy;
use crate::registration::Registration;
use nalgebra::Isometry3;
use serde::Serialize;

/// The schema name and version of [`RegistrationReport`].
pub const REGISTRATION_SCHEMA: &str = "depthcal.registration/1";

/// What the report says about the inputs, beyond the [`Registration`] itself.
#[derive(Clone, Debug, Default)]
pub struct RegistrationInputs {
    /// The source cloud's file, if it came from one.
    pub source: Option<String>,
    /// The target cloud's file, if it came from one.
    pub target: Option<String>,
    /// Points read (source, target).
    pub points: [usize; 2],
    /// Seed of the randomised steps.
    pub seed: u64,
    /// A known true source→target transform: the report then gives the error against it.
    pub truth: Option<Isometry3<f64>>,
    /// Wall time of the whole run, milliseconds (the caller's clock: reading included).
    pub total_ms: f64,
}

/// Point counts of a registration.
#[derive(Clone, Debug, Serialize)]
pub struct PointCounts {
    /// Source points read.
    pub source: usize,
    /// Target points read.
    pub target: usize,
    /// Source points of the global stage (downsampled).
    pub source_downsampled: usize,
    /// Target points of the global stage (downsampled).
    pub target_downsampled: usize,
}

/// The global stage (FPFH + RANSAC + verification).
#[derive(Clone, Debug, Serialize)]
pub struct GlobalReport {
    /// Feature correspondences.
    pub correspondences: usize,
    /// Correspondences consistent with the chosen hypothesis.
    pub inliers: usize,
    /// RANSAC samples drawn.
    pub iterations: usize,
    /// Fitness of the chosen hypothesis on the downsampled clouds, 0–1.
    pub fitness: f64,
    /// The transform before ICP.
    pub transform: PoseReport,
}

/// The result of registering a source cloud onto a target, as `depthcal register --json` prints it.
/// Lengths are in the clouds' unit (metres for depthcal's own clouds), angles in degrees.
#[derive(Clone, Debug, Serialize)]
pub struct RegistrationReport {
    /// [`REGISTRATION_SCHEMA`].
    pub schema: &'static str,
    /// The source cloud's file.
    pub source: Option<String>,
    /// The target cloud's file.
    pub target: Option<String>,
    /// Maps source points into the target frame.
    pub transform: PoseReport,
    /// Fraction of source points with a target point within the final correspondence distance, 0–1.
    pub fitness: f64,
    /// RMS distance of those pairs.
    pub inlier_rmse_m: f64,
    /// Overlap estimated by the trimming, 0–1.
    pub overlap: f64,
    /// Every ICP level met its tolerances.
    pub converged: bool,
    /// ICP iterations over all levels.
    pub iterations: usize,
    /// Covariance of `[rx, ry, rz (rad), tx, ty, tz]`, a left increment about the target origin.
    pub covariance: [[f64; 6]; 6],
    /// Information matrix `JᵀWJ`, same order.
    pub information: [[f64; 6]; 6],
    /// What the covariance's rows mean.
    pub covariance_parameters: &'static str,
    /// 1-σ per axis.
    pub sigma: SigmaReport,
    /// The information matrix leaves a direction weakly constrained.
    pub degenerate: bool,
    /// The degeneracy analysis.
    pub degeneracy: Degeneracy,
    /// Voxel of the global stage.
    pub voxel_m: f64,
    /// Median point spacing (source, target).
    pub spacing_m: [f64; 2],
    /// Point counts.
    pub points: PointCounts,
    /// The global stage, absent when an initial guess was given.
    pub global: Option<GlobalReport>,
    /// Seed of the randomised steps.
    pub seed: u64,
    /// Things the user should know.
    pub warnings: Vec<String>,
    /// Whether the result can be trusted.
    pub trusted: bool,
    /// Each failed check, in words.
    pub reasons: Vec<String>,
    /// What to try.
    pub suggestions: Vec<String>,
    /// Fraction of source points on a target surface at the result, 0–1.
    pub surface_agreement: f64,
    /// A far-away runner-up that scored almost as well.
    pub ambiguity: Option<AmbiguityReport>,
    /// The error against the truth, when one was given.
    pub error_vs_truth: Option<ErrorReport>,
    /// Wall time per stage, milliseconds.
    pub timings_ms: Timings,
    /// Wall time of the whole run, milliseconds.
    pub total_ms: f64,
}

impl RegistrationReport {
    /// The report of `r`.
    pub fn new(r: &Registration, inputs: &RegistrationInputs) -> Self {
        let error = inputs
            .truth
            .map(|t| crate::geometry::transform::pose_error(&r.transform, &t));
        RegistrationReport {
            schema: REGISTRATION_SCHEMA,
            source: inputs.source.clone(),
            target: inputs.target.clone(),
            transform: PoseReport::new(&r.transform),
            fitness: r.fitness,
            inlier_rmse_m: r.inlier_rmse,
            overlap: r.overlap,
            converged: r.converged,
            iterations: r.iterations,
            covariance: matrix6_rows(&r.covariance),
            information: matrix6_rows(&r.information),
            covariance_parameters:
                "[rx, ry, rz (rad), tx, ty, tz (cloud units)], left increment about the target origin",
            sigma: SigmaReport::from_covariance(&r.covariance),
            degenerate: r.degeneracy.is_degenerate(),
            degeneracy: r.degeneracy.clone(),
            voxel_m: r.voxel,
            spacing_m: r.spacing,
            points: PointCounts {
                source: inputs.points[0],
                target: inputs.points[1],
                source_downsampled: r.global_points[0],
                target_downsampled: r.global_points[1],
            },
            global: r.global.as_ref().map(|g| GlobalReport {
                correspondences: g.correspondences,
                inliers: g.inliers,
                iterations: g.iterations,
                fitness: g.fitness,
                transform: PoseReport::new(&g.transform),
            }),
            seed: inputs.seed,
            warnings: r.warnings.clone(),
            trusted: r.trust.trusted,
            reasons: r.trust.reasons.clone(),
            suggestions: r.trust.suggestions.clone(),
            surface_agreement: r.surface_agreement,
            ambiguity: r.ambiguity.as_ref().map(AmbiguityReport::new),
            error_vs_truth: ErrorReport::from_opt(error),
            timings_ms: Timings(r.timings_ms.clone()),
            total_ms: inputs.total_ms,
        }
    }
}
