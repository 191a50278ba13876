//! Free-space consistency of a robot-to-robot hypothesis.
//!
//! Every depth frame says not only where surfaces are but also that the space in front of them is empty.
//! Under a wrong `T_base1_base2` the other robot's surfaces land where the reference robot's cameras looked
//! straight through (a box floating over bare table, a table sliding through an object), while under the
//! truth they land on what those cameras saw, behind it, or outside their views. Counting such free-space
//! violations both ways tells the truth from hypotheses that overlap the clouds just as well, which is what
//! decides cells whose robots share only a third of the scene.

use crate::camera::{DepthView, Seen};
use crate::geometry::cloud::to_p64;
use nalgebra::Isometry3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`free_space_violation`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VisibilityConfig {
    /// Points tested per cloud, a stride sample (default 500: the violation fractions that matter differ
    /// by several percent).
    pub sample_points: usize,
    /// A point is in free space when it lies in front of the nearest depth seen in its pixel block by more
    /// than this, metres (default 0.02). The smallest margin used: see [`VisibilityConfig::max_self_violation`].
    pub margin_m: f64,
    /// The margin grows (by 1.5x steps, to 20x `margin_m` at most) until each robot's own cloud violates its
    /// own frames' free space at most this often (default 0.02): robot poses and hand-eye that are only
    /// centimetre-accurate make a robot's frames disagree among themselves, and the test must not demand
    /// more of the other robot than of the robot itself. Measured: simulated cells 0.3-1.3% at 2 cm; the
    /// 7-Scenes real-depth cell (cm-accurate poses) 6-10% at 2 cm.
    pub max_self_violation: f64,
    /// A hypothesis's score is multiplied by `exp(−violation / penalty_scale)` (default 0.03). Measured on
    /// simulated cells sharing 40% of the scene: the truth violates 0.4-1.5%, the wrong hypotheses that
    /// out-score it on alignment alone 8-17%.
    pub penalty_scale: f64,
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        VisibilityConfig {
            sample_points: 500,
            margin_m: 0.02,
            max_self_violation: 0.02,
            penalty_scale: 0.03,
        }
    }
}

impl VisibilityConfig {
    /// Checks the ranges; the error names the field (`visibility.…`).
    pub fn validate(&self) -> crate::Result<()> {
        use crate::error::check;
        check::at_least("visibility.sample_points", self.sample_points, 1)?;
        check::non_negative("visibility.margin_m", self.margin_m)?;
        check::non_negative("visibility.max_self_violation", self.max_self_violation)?;
        check::positive("visibility.penalty_scale", self.penalty_scale)
    }
}

/// One robot's side of the free-space test: its fused points (base frame), optionally the side each was
/// seen from (unit directions toward its cameras, [`crate::fusion::FusedCloud::sight_directions`]), and its
/// frames' depth views.
#[derive(Clone, Copy, Debug)]
pub struct RobotSight<'a> {
    /// Fused points, base frame, metres.
    pub points: &'a [[f32; 3]],
    /// Per point, a unit direction toward the cameras that saw it (optional).
    pub sides: Option<&'a [[f32; 3]]>,
    /// The robot's frames' depth views.
    pub views: &'a [DepthView],
}

impl<'a> RobotSight<'a> {
    /// A robot's fused cloud as the free-space test sees it (with sides when the cloud has viewpoints).
    pub fn of(fused: &'a crate::fusion::FusedCloud, sides: &'a [[f32; 3]]) -> Self {
        RobotSight {
            points: &fused.cloud.points,
            sides: (sides.len() == fused.cloud.points.len()).then_some(sides),
            views: &fused.views,
        }
    }
}

/// A surface point that a camera sees at its own depth but from behind (its side faces away from the
/// camera by more than this cosine) cannot be what the camera saw.
const BACKFACE_COS: f64 = -0.2;

/// The fraction of `cloud`'s points (in the frame that `t_views_points` maps from) that some view of
/// `views` saw through, or saw at their depth from the side opposite to the one they were seen from (when
/// `cloud` has sides), among those that some view saw at all (in free space, on a surface, or behind one);
/// 0 when no point falls in a view.
pub fn violation_fraction(
    cloud: &RobotSight,
    t_views_points: &Isometry3<f64>,
    views: &[DepthView],
    cfg: &VisibilityConfig,
) -> f64 {
    let points = cloud.points;
    let step = points.len().div_ceil(cfg.sample_points.max(1)).max(1);
    let centres: Vec<nalgebra::Point3<f64>> = views
        .iter()
        .map(|v| nalgebra::Point3::from(v.t_cam_base.inverse().translation.vector))
        .collect();
    let (free, decided) = (0..points.len())
        .into_par_iter()
        .step_by(step)
        .map(|i| {
            let q = t_views_points * to_p64(&points[i]);
            let side = cloud
                .sides
                .map(|s| t_views_points.rotation * to_p64(&s[i]).coords);
            let mut seen = false;
            for (v, c) in views.iter().zip(&centres) {
                match v.classify(&q, cfg.margin_m) {
                    Seen::FreeSpace => return (1usize, 1usize),
                    Seen::Unknown => {}
                    Seen::Surface => {
                        if let Some(n) = side {
                            let to_cam = c - q;
                            let len = to_cam.norm();
                            if n.norm() > 0.5 && len > 0.0 && n.dot(&to_cam) < BACKFACE_COS * len {
                                return (1, 1);
                            }
                        }
                        seen = true;
                    }
                    _ => seen = true,
                }
            }
            (0, seen as usize)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if decided == 0 {
        0.0
    } else {
        free as f64 / decided as f64
    }
}

/// Free-space violations of `T_base1_base2` both ways: the other robot's points against the reference
/// robot's views and the reference's points against the other's views; the mean of the two fractions.
pub fn free_space_violation(
    reference: &RobotSight,
    other: &RobotSight,
    t_base1_base2: &Isometry3<f64>,
    cfg: &VisibilityConfig,
) -> f64 {
    let a = violation_fraction(other, t_base1_base2, reference.views, cfg);
    let b = violation_fraction(reference, &t_base1_base2.inverse(), other.views, cfg);
    0.5 * (a + b)
}

/// The free-space margin for two robots' clouds and views (metres): the smallest of `cfg.margin_m · 1.5^k`
/// (at most 20 · `cfg.margin_m`) at which each robot's own cloud violates its own views at most
/// `cfg.max_self_violation` (see [`VisibilityConfig::max_self_violation`]); returns it with the worse
/// self-violation there.
pub fn self_consistent_margin(
    reference: &RobotSight,
    other: &RobotSight,
    cfg: &VisibilityConfig,
) -> (f64, f64) {
    let id = Isometry3::identity();
    let mut m = cfg.margin_m;
    loop {
        let c = VisibilityConfig {
            margin_m: m,
            ..cfg.clone()
        };
        let own = violation_fraction(reference, &id, reference.views, &c).max(violation_fraction(
            other,
            &id,
            other.views,
            &c,
        ));
        if own <= cfg.max_self_violation || m * 1.5 > 20.0 * cfg.margin_m {
            return (m, own);
        }
        m *= 1.5;
    }
}
