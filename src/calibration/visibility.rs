//! Free-space consistency of a robot-to-robot hypothesis.
//!
//! Every depth frame says not only where surfaces are but also that the space in front of them is empty.
//! Under a wrong `T_base1_base2` the other robot's surfaces land where the reference robot's cameras looked
//! straight through (a box floating over bare table, a table sliding through an object), while under the
//! truth they land on what those cameras saw, behind it, or outside their views. Counting such free-space
//! violations both ways tells the truth from hypotheses that overlap the clouds just as well, which is what
//! decides cells whose robots share only a third of the scene.
//!
//! Not everything a robot's frames saw is static scene: while one robot takes its frames the other stands
//! idle (in candle pose, by the usual protocol), so each robot's cloud holds the *other* robot's arm, which
//! is not there when that robot moves its own camera through the same space. The test therefore leaves out
//! the points in the viewing robot's own body cylinder ([`VisibilityConfig::in_robot_body`]: within
//! `robot_body_radius_m` of its base frame's `z` axis, from `robot_body_above_m` above its base up, under
//! the hypothesis being tested).

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
    /// The same weight in the refinement's choice among refined hypotheses
    /// ([`crate::calibration::hypotheses`]; default 0.01). Refined hypotheses have no misalignment left to
    /// excuse a violation: on foreign cells (docs/accuracy.md, "Right on any cell") the truth refined
    /// violated 0.1-1.2%, the wrong overlays that agreed with the clouds as well or better 3.4-13%, and a
    /// mirror overlay at 3.4% with three times the truth's agreement still out-scored it at 0.03.
    pub choice_penalty_scale: f64,
    /// Radius of a robot's body cylinder about its base axis, metres ([`VisibilityConfig::in_robot_body`];
    /// default 0.3: an iiwa or a UR10e in candle pose with a camera on its flange stays within about
    /// 0.25 m of its base axis; 0 leaves no point out).
    pub robot_body_radius_m: f64,
    /// The body cylinder starts this far above the base origin along the base axis, metres (default 0.15:
    /// the base and the first link do not move away between captures, the arm from the shoulder up does;
    /// an iiwa's shoulder joint is 0.34-0.36 m up, a UR's 0.15-0.18 m; the table top and low objects
    /// around a base mounted at table height stay in the test).
    pub robot_body_above_m: f64,
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        VisibilityConfig {
            sample_points: 500,
            margin_m: 0.02,
            max_self_violation: 0.02,
            penalty_scale: 0.03,
            choice_penalty_scale: 0.01,
            robot_body_radius_m: 0.3,
            robot_body_above_m: 0.15,
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
        check::positive("visibility.penalty_scale", self.penalty_scale)?;
        check::positive("visibility.choice_penalty_scale", self.choice_penalty_scale)?;
        check::non_negative("visibility.robot_body_radius_m", self.robot_body_radius_m)?;
        check::non_negative("visibility.robot_body_above_m", self.robot_body_above_m)
    }

    /// Whether `q` (in a robot's base frame, metres) lies in that robot's body cylinder: within
    /// `robot_body_radius_m` of the base's `z` axis and more than `robot_body_above_m` above the base
    /// origin. Each robot's cloud may hold the other robot's arm there, seen while it stood idle (in
    /// candle pose, by the usual protocol): not static scene.
    pub fn in_robot_body(&self, q: &nalgebra::Point3<f64>) -> bool {
        q.z > self.robot_body_above_m
            && q.x * q.x + q.y * q.y < self.robot_body_radius_m * self.robot_body_radius_m
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

/// Sampled points [`violation_fraction`] classifies together (a unit of its parallel work).
const VIOLATION_CHUNK: usize = 64;

/// A surface point that a camera sees at its own depth but from behind (its side faces away from the
/// camera by more than this cosine) cannot be what the camera saw.
const BACKFACE_COS: f64 = -0.2;

/// The fraction of `cloud`'s points (in the frame that `t_views_points` maps from) that some view of
/// `views` saw through, or saw at their depth from the side opposite to the one they were seen from (when
/// `cloud` has sides), among those that some view saw at all (in free space, on a surface, or behind one);
/// 0 when no point falls in a view. `views` belong to one robot and the frame `t_views_points` maps into
/// is its base frame: points in that robot's own body cylinder ([`VisibilityConfig::in_robot_body`]) are
/// not tested.
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
    let sample: Vec<usize> = (0..points.len()).step_by(step).collect();
    // Chunk by chunk: the chunk's points in the views' frame (those outside the viewing robot's body),
    // classified in every view at once ([`DepthView::classify_many`]). A point counts as violating when
    // some view saw through it or saw it at its depth from behind, else as decided when some view saw it
    // at all: the order of the views does not matter.
    let (free, decided) = sample
        .par_chunks(VIOLATION_CHUNK)
        .map(|chunk| {
            // At most VIOLATION_CHUNK points: kept on the stack.
            let mut at = [[0f64; VIOLATION_CHUNK]; 3];
            let mut sides = [nalgebra::Vector3::zeros(); VIOLATION_CHUNK];
            let mut m = 0;
            for &i in chunk {
                let q = t_views_points * to_p64(&points[i]);
                if cfg.in_robot_body(&q) {
                    continue;
                }
                for (c, v) in at.iter_mut().zip([q.x, q.y, q.z]) {
                    c[m] = v;
                }
                if let Some(s) = cloud.sides {
                    sides[m] = t_views_points.rotation * to_p64(&s[i]).coords;
                }
                m += 1;
            }
            let [x, y, z] = &at;
            let (x, y, z) = (&x[..m], &y[..m], &z[..m]);
            let (mut violated, mut seen) = ([false; VIOLATION_CHUNK], [false; VIOLATION_CHUNK]);
            let mut codes = [Seen::Unknown; VIOLATION_CHUNK];
            let codes = &mut codes[..m];
            for (v, c) in views.iter().zip(&centres) {
                v.classify_many(x, y, z, cfg.margin_m, codes);
                for (j, code) in codes.iter().enumerate() {
                    match code {
                        Seen::FreeSpace => violated[j] = true,
                        Seen::Unknown => {}
                        Seen::Surface => {
                            if cloud.sides.is_some() {
                                let n = &sides[j];
                                let q = nalgebra::Point3::new(x[j], y[j], z[j]);
                                let to_cam = c - q;
                                let len = to_cam.norm();
                                if n.norm() > 0.5
                                    && len > 0.0
                                    && n.dot(&to_cam) < BACKFACE_COS * len
                                {
                                    violated[j] = true;
                                }
                            }
                            seen[j] = true;
                        }
                        Seen::Occluded => seen[j] = true,
                    }
                }
            }
            let free = violated[..m].iter().filter(|&&b| b).count();
            let decided = violated[..m]
                .iter()
                .zip(&seen[..m])
                .filter(|(a, b)| **a || **b)
                .count();
            (free, decided)
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

/// The free-space test of the final transform.
#[derive(Clone, Debug, Serialize)]
pub struct FreeSpaceCheck {
    /// Mean of both ways' violation fractions at the final transform, 0–1.
    pub violation: f64,
    /// The worse of the two robots' own clouds against their own frames at the same margin, 0–1.
    pub own_violation: f64,
    /// The margin, metres.
    pub margin_m: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{DepthImage, Intrinsics};

    /// A robot's view of a wall 2 m ahead, its camera at the base origin looking along the base's `z`:
    /// a point in front of the wall is seen through unless it stands in that robot's body cylinder (on the
    /// base axis, higher than `robot_body_above_m`); a point on the wall is seen.
    #[test]
    fn the_viewing_robots_own_body_is_not_tested() {
        let intr = Intrinsics::pinhole(64, 48, 40.0, 40.0, 31.5, 23.5);
        let mut img = DepthImage::zeros(64, 48);
        img.data.iter_mut().for_each(|d| *d = 2000);
        let views = [DepthView::new(&img, &intr, &Isometry3::identity(), 4)];
        let points = [
            [0.0, 0.0, 1.0],
            [0.6, 0.0, 1.0],
            [0.6, 0.0, 2.0],
            [0.05, 0.0, 0.12],
        ];
        let cloud = RobotSight {
            points: &points,
            sides: None,
            views: &views,
        };
        let cfg = VisibilityConfig {
            sample_points: 100,
            ..VisibilityConfig::default()
        };
        // Body: the first point (on the axis, 1 m up). Not body: the second (0.6 m off the axis), the
        // third (on the wall) and the fourth (on the axis but below the body's start: the base).
        let f = violation_fraction(&cloud, &Isometry3::identity(), &views, &cfg);
        assert!((f - 2.0 / 3.0).abs() < 1e-12, "{f}");
        let none = VisibilityConfig {
            robot_body_radius_m: 0.0,
            ..cfg
        };
        let f = violation_fraction(&cloud, &Isometry3::identity(), &views, &none);
        assert!((f - 3.0 / 4.0).abs() < 1e-12, "{f}");
    }
}
