//! The refinement's choice among a search's hypotheses of `T_base1_base2`, made at full resolution.
//!
//! A global search ranks its hypotheses on coarse clouds (feature inliers, a short ICP on a sample). Where
//! a cell is nearly symmetric (two robots facing each other across a square table) a wrong overlay can
//! outrank the truth there and still explain far less of the data once refined. So every distinct
//! hypothesis handed on is refined by the same trimmed robust ICP as the answer, and judged by what it
//! explains at the finest level:
//!
//! 1. the other robot's body is left out under each hypothesis ([`without_robot_bodies`]): each robot's
//!    cloud holds the other robot's arm, seen while it stood idle, which the other robot's own cloud never
//!    holds;
//! 2. each refined hypothesis is scored by its surface agreement (the share of the finest level's
//!    source points that lie on a target surface with a matching normal, each direction of the surfaces
//!    weighted alike so that a table laid on a table at any turn does not outweigh the objects' faces:
//!    [`Registration::balanced_agreement`]) and tested against both robots' free space
//!    ([`FreeSpaceTest`]);
//! 3. the answer is the best-scoring one among those that pass the free-space test (among all when none
//!    does), the score being the agreement weighed by the free-space test
//!    (`exp(−excess / choice_penalty_scale)`, [`VisibilityConfig::choice_penalty_scale`], the excess
//!    being the violation beyond what each robot's own frames show against its own cloud, the test's
//!    noise level): on foreign cells the truth violated 0.1-1.2% where wrong overlays that agreed as well
//!    or better violated 3-13% ("Right on any cell" in docs/accuracy.md); a far-away one that also passes and scores almost as well
//!    ([`crate::registration::RegisterConfig::ambiguity_ratio`]) makes the answer ambiguous: both explain
//!    the data at full resolution.

use crate::calibration::fused::FusedCell;
use crate::calibration::initializer::sight;
use crate::calibration::visibility::FreeSpaceCheck;
use crate::calibration::visibility::{
    free_space_violation, self_consistent_margin, RobotSight, VisibilityConfig,
};
use crate::error::Result;
use crate::geometry::cloud::{to_p64, PointCloud};
use crate::geometry::transform::pose_error;
use crate::registration::pipeline::{cloud_fingerprint, prepare_refinement, Ambiguity};
use crate::registration::{
    register_request, PreparedLevels, RegisterConfig, RegisterRequest, Registration,
};
use nalgebra::Isometry3;
use rayon::prelude::*;

/// Largest free-space violation of a trusted calibration beyond what each robot's own frames show.
/// Measured on simulated cells: the truth 0.4–1.5%, wrong answers that align the clouds as well 8–17%.
pub const MAX_FREE_SPACE_EXCESS: f64 = 0.05;

/// Both robots' sight of their fused clouds and frames, with the margin their own frames allow: the
/// free-space test of any `T_base1_base2`, prepared once.
pub struct FreeSpaceTest<'a> {
    reference: RobotSight<'a>,
    other: RobotSight<'a>,
    config: VisibilityConfig,
    own_violation: f64,
}

impl<'a> FreeSpaceTest<'a> {
    /// The test for a fused cell, `None` unless both clouds carry their depth views. The margin grows from
    /// `cfg.margin_m` until each robot's own cloud agrees with its own frames
    /// ([`self_consistent_margin`]).
    pub fn new(fused: &'a FusedCell, cfg: &VisibilityConfig) -> Option<Self> {
        let (a, b) = (&fused.reference, &fused.other);
        if a.views.is_empty() || b.views.is_empty() {
            return None;
        }
        let (reference, other) = (sight(a, true), sight(b, true));
        let (margin_m, own_violation) = self_consistent_margin(&reference, &other, cfg);
        Some(FreeSpaceTest {
            reference,
            other,
            config: VisibilityConfig {
                margin_m,
                ..cfg.clone()
            },
            own_violation,
        })
    }

    /// The test of `t_base1_base2`.
    pub fn check(&self, t_base1_base2: &Isometry3<f64>) -> FreeSpaceCheck {
        FreeSpaceCheck {
            violation: free_space_violation(
                &self.reference,
                &self.other,
                t_base1_base2,
                &self.config,
            ),
            own_violation: self.own_violation,
            margin_m: self.config.margin_m,
        }
    }
}

impl FreeSpaceCheck {
    /// Whether the violation stays within [`MAX_FREE_SPACE_EXCESS`] of each robot's own.
    pub fn passes(&self) -> bool {
        self.violation <= self.own_violation + MAX_FREE_SPACE_EXCESS
    }
}

/// The points of `cloud` outside the body cylinder ([`VisibilityConfig::in_robot_body`]) of the robot
/// whose base frame `t_cloud_body` maps into the cloud's frame.
fn without_body(
    cloud: &PointCloud,
    t_cloud_body: &Isometry3<f64>,
    body: &VisibilityConfig,
) -> PointCloud {
    let t_body_cloud = t_cloud_body.inverse();
    let keep: Vec<usize> = (0..cloud.points.len())
        .filter(|&i| !body.in_robot_body(&(t_body_cloud * to_p64(&cloud.points[i]))))
        .collect();
    cloud.retain_indices(&keep)
}

/// Both fused clouds without the other robot's body under `t_base1_base2`: the reference's cloud less the
/// points in robot 2's body cylinder, the other's less those in robot 1's
/// ([`VisibilityConfig::in_robot_body`]). A radius of 0 keeps every point.
pub fn without_robot_bodies(
    fused: &FusedCell,
    t_base1_base2: &Isometry3<f64>,
    body: &VisibilityConfig,
) -> (PointCloud, PointCloud) {
    if body.robot_body_radius_m <= 0.0 {
        return (fused.reference.cloud.clone(), fused.other.cloud.clone());
    }
    (
        without_body(&fused.reference.cloud, t_base1_base2, body),
        without_body(&fused.other.cloud, &t_base1_base2.inverse(), body),
    )
}

/// One hypothesis refined at full resolution and judged.
#[derive(Clone, Debug)]
pub struct Judged {
    /// Where the refinement started.
    pub start: Isometry3<f64>,
    /// The refinement (its transform is `T_base1_base2`).
    pub registration: Registration,
    /// The free-space test of the refined transform, when the clouds carry their frames.
    pub free_space: Option<FreeSpaceCheck>,
}

/// What the report keeps of a judged hypothesis.
#[derive(Clone, Debug)]
pub struct JudgedSummary {
    /// The refined `T_base1_base2`.
    pub transform: Isometry3<f64>,
    /// Its surface agreement at the finest level, 0–1 ([`Judged::agreement`]).
    pub agreement: f64,
    /// Its refinement's fitness, 0–1.
    pub fitness: f64,
    /// Its free-space violation, 0–1 (`None` without depth views).
    pub free_space_violation: Option<f64>,
    /// It passes the free-space test.
    pub passes_free_space: bool,
    /// What the choice ranks by: the agreement weighed by the free-space test,
    /// `agreement · exp(−excess / choice_penalty_scale)`, the excess being the violation beyond each
    /// robot's own frames' against its own cloud ([`VisibilityConfig::choice_penalty_scale`]).
    pub score: f64,
    /// It is the answer.
    pub chosen: bool,
}

impl Judged {
    /// The report's summary of it, its score weighed with `penalty_scale`
    /// ([`VisibilityConfig::choice_penalty_scale`]); not chosen yet.
    pub fn summary(&self, penalty_scale: f64) -> JudgedSummary {
        let violation = self.free_space.as_ref().map(|f| f.violation);
        // Only the violation beyond what each robot's own frames show against its own cloud counts: below
        // that level the test cannot tell one hypothesis from another.
        let excess = self
            .free_space
            .as_ref()
            .map_or(0.0, |f| (f.violation - f.own_violation).max(0.0));
        JudgedSummary {
            transform: self.registration.transform,
            agreement: self.agreement(),
            fitness: self.registration.fitness,
            free_space_violation: violation,
            passes_free_space: self.passes_free_space(),
            score: self.agreement() * (-excess / penalty_scale).exp(),
            chosen: false,
        }
    }

    /// The share of the finest level's source points on a target surface after refinement, every
    /// direction of the surfaces weighted alike ([`Registration::balanced_agreement`]; the fitness when
    /// that was not measured).
    pub fn agreement(&self) -> f64 {
        let a = self.registration.balanced_agreement;
        if a.is_finite() {
            a
        } else {
            self.registration.fitness
        }
    }

    /// Whether it passes the free-space test (true without one).
    pub fn passes_free_space(&self) -> bool {
        self.free_space.as_ref().is_none_or(FreeSpaceCheck::passes)
    }
}

/// Refines each start with `rcfg` on the fused clouds without the other robot's body under that start
/// ([`without_robot_bodies`] with `body`), and judges it: its agreement and, with `test`, its free-space
/// check. In the order of `starts`, less the starts whose refinement failed (a hypothesis far off can
/// leave ICP without any pair: it explains nothing); the first failure when every one failed. The starts
/// are refined side by side (each refinement is deterministic at any thread count, and the results are
/// taken in the order of `starts`).
pub fn refine_and_judge(
    fused: &FusedCell,
    starts: &[Isometry3<f64>],
    rcfg: &RegisterConfig,
    body: &VisibilityConfig,
    test: Option<&FreeSpaceTest>,
    prepared: &PreparedLevels,
) -> Result<Vec<Judged>> {
    // Clouds that several hypotheses share (no robot body cut, or the same cut) get their levels prepared
    // once, before the refinements start side by side and would each prepare them at once. The clouds are
    // told apart by their fingerprints (a collision only prepares levels no one asks for: the memo
    // compares whole clouds) and made again where needed, so that no more of them are held at once than
    // before.
    let prints: Vec<(u64, u64)> = starts
        .par_iter()
        .map(|start| {
            let (reference, other) = without_robot_bodies(fused, start, body);
            (cloud_fingerprint(&reference), cloud_fingerprint(&other))
        })
        .collect();
    for (k, p) in prints.iter().enumerate() {
        if !prints[..k].contains(p) && prints[k + 1..].contains(p) {
            let (reference, other) = without_robot_bodies(fused, &starts[k], body);
            prepare_refinement(&other, &reference, rcfg, prepared)?;
        }
    }
    let refined: Vec<Result<Judged>> = starts
        .par_iter()
        .map(|start| {
            let (reference, other) = without_robot_bodies(fused, start, body);
            let registration = register_request(RegisterRequest {
                initial: Some(start),
                prepared: Some(prepared),
                ..RegisterRequest::new(&other, &reference, rcfg)
            })?;
            let free_space = test.map(|t| t.check(&registration.transform));
            Ok(Judged {
                start: *start,
                registration,
                free_space,
            })
        })
        .collect();
    let mut judged = Vec::with_capacity(starts.len());
    let mut first_error = None;
    for (k, r) in refined.into_iter().enumerate() {
        match r {
            Ok(j) => judged.push(j),
            Err(e) => {
                log::info!("hypothesis {k} left out: its refinement failed: {e}");
                first_error.get_or_insert(e);
            }
        }
    }
    match first_error {
        Some(e) if judged.is_empty() => Err(e),
        _ => Ok(judged),
    }
}

/// The index of the answer among `judged` (not empty) and, if one, a far-away rival that explains the data
/// almost as well: the best score among those that pass the free-space test (among all when none does);
/// a rival passes it too, lies farther than `cfg.ambiguity_min_deg` or `cfg.ambiguity_min_voxels` ×
/// `voxel` (the global voxel) from the answer and scores at least `cfg.ambiguity_ratio` times as much.
/// Ties go to the earlier one.
pub fn choose(
    judged: &[JudgedSummary],
    voxel: f64,
    cfg: &RegisterConfig,
) -> (usize, Option<Ambiguity>) {
    let any_passes = judged.iter().any(|j| j.passes_free_space);
    let mut best = 0;
    let mut best_score = f64::NEG_INFINITY;
    for (k, j) in judged.iter().enumerate() {
        if (j.passes_free_space || !any_passes) && j.score > best_score {
            best = k;
            best_score = j.score;
        }
    }
    let b = &judged[best];
    let rival = judged.iter().enumerate().find_map(|(k, j)| {
        if k == best || !j.passes_free_space || !b.passes_free_space {
            return None;
        }
        let (rot_deg, trans) = pose_error(&j.transform, &b.transform);
        let far = rot_deg > cfg.ambiguity_min_deg || trans > cfg.ambiguity_min_voxels * voxel;
        let ratio = j.score / b.score.max(f64::MIN_POSITIVE);
        (far && ratio >= cfg.ambiguity_ratio).then_some(Ambiguity {
            runner_up: j.transform,
            score_ratio: ratio,
            best_score: b.score,
            rotation_deg: rot_deg,
            translation: trans,
        })
    });
    (best, rival)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn a_body_is_the_cylinder_above_the_other_base() {
        let body = VisibilityConfig::default(); // 0.3 m radius, from 0.15 m above the base
                                                // Robot 2's base 1.4 m along x, yawed 180°, upright.
        let t = Isometry3::new(
            Vector3::new(1.4, 0.0, 0.0),
            Vector3::z() * std::f64::consts::PI,
        );
        let cloud = PointCloud::from_points(vec![
            [1.4, 0.1, 0.9],  // robot 2's arm, 0.1 m from its axis, 0.9 m up
            [1.2, 0.0, 0.3],  // 0.2 m from its axis, 0.3 m up
            [1.3, 0.0, 0.05], // beside its base at table height: static
            [1.0, 0.0, 0.5],  // 0.4 m from its axis: scene
            [0.0, 0.0, 1.0],  // on robot 1's own axis: kept in robot 1's own cloud
        ]);
        let kept = without_body(&cloud, &t, &body);
        assert_eq!(
            kept.points,
            vec![[1.3, 0.0, 0.05], [1.0, 0.0, 0.5], [0.0, 0.0, 1.0]]
        );
        // From robot 2's side, robot 1's axis stands 1.4 m in front of it too.
        let kept = without_body(&cloud, &t.inverse(), &body);
        assert_eq!(kept.points.len(), 3, "{:?}", kept.points);
        // A tilted base: the cylinder follows the base's z (here base1's -y).
        let tilted = Isometry3::new(Vector3::zeros(), Vector3::x() * std::f64::consts::FRAC_PI_2);
        let c = PointCloud::from_points(vec![[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -0.1, 0.0]]);
        assert_eq!(
            without_body(&c, &tilted, &body).points,
            vec![[0.0, 0.0, 1.0], [0.0, -0.1, 0.0]]
        );
        // Radius 0: nothing is body.
        let none = VisibilityConfig {
            robot_body_radius_m: 0.0,
            ..body
        };
        assert_eq!(without_body(&cloud, &t, &none).points.len(), 5);
    }

    fn summary(yaw_deg: f64, x: f64, agreement: f64, passes: bool) -> JudgedSummary {
        JudgedSummary {
            transform: Isometry3::new(
                Vector3::new(x, 0.0, 0.0),
                Vector3::z() * yaw_deg.to_radians(),
            ),
            agreement,
            fitness: agreement,
            free_space_violation: Some(if passes { 0.01 } else { 0.2 }),
            passes_free_space: passes,
            score: agreement,
            chosen: false,
        }
    }

    #[test]
    fn the_answer_scores_best_among_those_that_pass_the_free_space_test() {
        let cfg = RegisterConfig::default(); // a rival at 90% and beyond 2° or 3 voxels
        let voxel = 0.01;
        // The best agreement fails the free-space test: the best that passes wins, no rival.
        let j = [
            summary(0.0, 1.4, 0.5, true),
            summary(180.0, 0.5, 0.8, false),
            summary(0.5, 1.4, 0.3, true),
        ];
        let (best, rival) = choose(&j, voxel, &cfg);
        assert_eq!(best, 0);
        assert!(rival.is_none());
        // None passes: the best agreement, and nothing is called ambiguous.
        let j = [
            summary(0.0, 1.4, 0.5, false),
            summary(180.0, 0.5, 0.6, false),
        ];
        let (best, rival) = choose(&j, voxel, &cfg);
        assert_eq!(best, 1);
        assert!(rival.is_none());
        // A far hypothesis that passes and agrees 92% as well is a rival; 85% is not.
        let j = [
            summary(0.0, 1.4, 0.5, true),
            summary(180.0, 1.4, 0.46, true),
        ];
        let (best, rival) = choose(&j, voxel, &cfg);
        assert_eq!(best, 0);
        let r = rival.expect("a rival");
        assert!((r.score_ratio - 0.92).abs() < 1e-9 && (r.rotation_deg - 180.0).abs() < 1e-6);
        let j = [
            summary(0.0, 1.4, 0.5, true),
            summary(180.0, 1.4, 0.425, true),
        ];
        assert!(choose(&j, voxel, &cfg).1.is_none());
        // The same answer found twice (1° and 2 voxels apart) is no rival.
        let j = [summary(0.0, 1.4, 0.5, true), summary(1.0, 1.42, 0.5, true)];
        let (best, rival) = choose(&j, voxel, &cfg);
        assert_eq!(best, 0);
        assert!(rival.is_none());
        // Ties go to the earlier one.
        let j = [summary(0.0, 1.4, 0.5, true), summary(0.1, 1.4, 0.5, true)];
        assert_eq!(choose(&j, voxel, &cfg).0, 0);
    }

    /// A start that leaves ICP without a pair is left out; with no start left, its error is the result.
    #[test]
    fn a_start_that_explains_nothing_is_left_out() {
        // The inside corner of a box, 1 cm grid, as both robots' clouds.
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (a, b) = (i as f32 * 0.01, j as f32 * 0.01);
                points.extend([[a, b, 0.0], [a, 0.0, b + 0.01], [0.0, a + 0.01, b + 0.01]]);
            }
        }
        let cloud = crate::fusion::FusedCloud {
            cloud: PointCloud::from_points(points),
            ..Default::default()
        };
        let fused = FusedCell::from_clouds(
            cloud.clone(),
            cloud,
            crate::calibration::priors::CellPriors::none(),
        );
        let body = VisibilityConfig {
            robot_body_radius_m: 0.0,
            ..VisibilityConfig::default()
        };
        let far = Isometry3::translation(50.0, 0.0, 0.0);
        let near = Isometry3::translation(0.005, -0.003, 0.002);
        let rcfg = RegisterConfig::default();
        let judged = refine_and_judge(
            &fused,
            &[far, near],
            &rcfg,
            &body,
            None,
            &PreparedLevels::new(),
        )
        .unwrap();
        assert_eq!(judged.len(), 1);
        assert_eq!(judged[0].start, near);
        assert!(judged[0].registration.transform.translation.vector.norm() < 2e-3);
        assert!(
            refine_and_judge(&fused, &[far], &rcfg, &body, None, &PreparedLevels::new()).is_err()
        );
    }
}
