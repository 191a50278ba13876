//! Which poses to capture next: for a calibrated cell, which degrees of freedom of each hand-eye and of
//! `T_base1_base2` are weakly constrained by the frames it has, and a few more flange poses (within the span
//! of the existing ones) that would constrain them most (`depthcal plan`).
//!
//! **Hand-eyes.** Each robot's hand-eye is fitted from its own depth frames (a short
//! [`refine_hand_eye_from_depth`]); its covariance names the weak parameters in camera axes and the flange
//! motion that leaves them free, and [`super::handeye::depth::plan`] proposes rotations that observe them.
//!
//! **Base-to-base.** The registration's part of the calibration's covariance (the inputs' part, hand-eyes and
//! pose repeatability, is not lowered by more views) is split into principal directions, rotations scaled to
//! millimetres at the clouds' RMS radius; a direction above `weak_sigma_mm` is weak. More views constrain it
//! when they make more of the scene shared: a point of one robot's cloud that the other robot has not seen
//! becomes a point-to-plane constraint `J = [p × n; n]` (reference base frame) once the other robot sees it.
//! The candidates are each robot's existing camera poses turned about the point they look at (by
//! `turns_deg`, about the camera's x and y axes), whose flange stays within the span of the existing flange
//! positions; a candidate sees a point when it lies in its image, within the robot's depth range, faces the
//! camera and is the nearest surface in its z-buffer cell. Each candidate's information is added to the
//! registration's (its inverse covariance, with the points weighted by the ratio of the registered to the
//! scored cloud sizes and the fit's residual) and the candidates are picked greedily by the largest 1-σ
//! they leave. The figures are predictions to rank poses by, not promises.

use crate::calibration::fused::FusedCell;
use crate::calibration::handeye::depth::observe::{directions, DofObservability, WeakDirection};
use crate::calibration::handeye::depth::plan::SuggestedPose;
use crate::calibration::handeye::depth::{refine_hand_eye_from_depth, HandEyeDepthConfig};
use crate::calibration::robot_to_robot::Calibration;
use crate::cell::{Cell, CellRobot};
use crate::error::{Error, Result};
use crate::geometry::pose::KukaPose;
use crate::geometry::PointCloud;
use crate::index::KdIndex;
use crate::preprocess::normals::{estimate_normals, NormalConfig};
use crate::preprocess::voxel::voxel_downsample;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, Unit, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Settings of [`plan_cell`]. Lengths in metres unless named otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlanConfig {
    /// Flange poses to propose for the base-to-base transform (default 4).
    pub base_poses: usize,
    /// A base-to-base direction is weak when its 1-σ exceeds this, millimetres (rotations at the clouds'
    /// RMS radius) (default 0.5).
    pub weak_sigma_mm: f64,
    /// Voxel of the clouds the candidate views are scored on (default 0.02).
    pub voxel_m: f64,
    /// A point is already shared when the other robot's cloud has a point within this many voxels
    /// (default 1.5).
    pub shared_voxels: f64,
    /// Turns of each existing camera about the point it looks at, degrees (default `[15, 30]`).
    pub turns_deg: Vec<f64>,
    /// Z-buffer cell of the occlusion test, pixels (default 8).
    pub zbuffer_px: u32,
    /// A point faces a camera when its normal is within this of the direction to it, degrees (default 75).
    pub max_incidence_deg: f64,
    /// The hand-eye fits' settings (default: two gates, 6 iterations each, as `calibrate`'s hand-eye check).
    pub hand_eye: HandEyeDepthConfig,
}

impl Default for PlanConfig {
    fn default() -> Self {
        PlanConfig {
            base_poses: 4,
            weak_sigma_mm: 0.5,
            voxel_m: 0.02,
            shared_voxels: 1.5,
            turns_deg: vec![15.0, 30.0],
            zbuffer_px: 8,
            max_incidence_deg: 75.0,
            hand_eye: crate::calibration::handeye::depth::check::HandEyeCheckConfig::default()
                .depth,
        }
    }
}

impl PlanConfig {
    /// Checks the ranges; the error names the field (`plan.voxel_m`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check::positive;
        positive("plan.weak_sigma_mm", self.weak_sigma_mm)?;
        positive("plan.voxel_m", self.voxel_m)?;
        positive("plan.shared_voxels", self.shared_voxels)?;
        if self.turns_deg.is_empty()
            || self
                .turns_deg
                .iter()
                .any(|t| !(t.is_finite() && *t > 0.0 && *t <= 90.0))
        {
            return Err(Error::config(
                "plan.turns_deg",
                format!(
                    "must be a non-empty list of angles in (0, 90], found {:?}",
                    self.turns_deg
                ),
            ));
        }
        if self.zbuffer_px == 0 {
            return Err(Error::config("plan.zbuffer_px", "must be at least 1"));
        }
        if !(self.max_incidence_deg > 0.0 && self.max_incidence_deg < 90.0) {
            return Err(Error::config(
                "plan.max_incidence_deg",
                format!("must be within (0, 90), found {}", self.max_incidence_deg),
            ));
        }
        self.hand_eye.validate_within("plan.hand_eye")
    }
}

/// One robot's hand-eye: what its frames leave weak and which poses would help.
#[derive(Clone, Debug, Serialize)]
pub struct HandEyePlan {
    /// The robot.
    pub robot: String,
    /// Each of the six parameters' 1-σ and status (camera axes).
    pub dofs: Vec<DofObservability>,
    /// The weak directions, in words.
    pub weak_directions: Vec<WeakDirection>,
    /// Flange poses that would observe them.
    pub suggested_poses: Vec<SuggestedPose>,
    /// The fit could not run (too few frames): why.
    pub note: Option<String>,
}

/// A weak direction of `T_base1_base2`.
#[derive(Clone, Debug, Serialize)]
pub struct BaseWeakDirection {
    /// In words, in the reference base frame.
    pub description: String,
    /// The unit direction `[rx, ry, rz, tx, ty, tz]` (rotations scaled by the RMS radius).
    pub vector: [f64; 6],
    /// Its 1-σ, millimetres (rotations at the RMS radius).
    pub sigma_mm: f64,
}

/// A flange pose proposed for the base-to-base transform.
#[derive(Clone, Debug, Serialize)]
pub struct BasePoseSuggestion {
    /// The robot to move.
    pub robot: String,
    /// The frame whose pose it turns.
    pub from_frame: String,
    /// The turn about the point the camera looks at, degrees, about `axis_camera` (camera frame).
    pub rotation_deg: f64,
    /// The turn axis, a unit vector in the camera frame.
    pub axis_camera: [f64; 3],
    /// The flange pose `T_base_ee`, KUKA `[X, Y, Z (mm), A, B, C (degrees)]`.
    pub kuka_xyzabc: [f64; 6],
    /// Points of the other robot's cloud (at `voxel_m`) the robot has not seen that this view would see.
    pub new_shared_points: usize,
    /// The largest base-to-base 1-σ (mm, rotations at the RMS radius) predicted with this pose and the ones
    /// above it.
    pub predicted_sigma_mm: f64,
}

/// What [`plan_cell`] found.
#[derive(Clone, Debug, Serialize)]
pub struct CellPlan {
    /// Per robot (cell order).
    pub hand_eyes: Vec<HandEyePlan>,
    /// The RMS radius of the reference cloud about its centroid, metres (the rotation scale).
    pub radius_m: f64,
    /// The largest base-to-base 1-σ of the registration now, mm (rotations at the RMS radius).
    pub base_sigma_mm: f64,
    /// The base-to-base directions above `weak_sigma_mm`.
    pub base_weak_directions: Vec<BaseWeakDirection>,
    /// Flange poses for them, best first (empty when none is weak or no candidate helps).
    pub base_suggested_poses: Vec<BasePoseSuggestion>,
    /// Candidate views scored.
    pub candidates: usize,
}

/// Words for a direction of `T_base1_base2` (reference base frame `base`).
fn base_direction_words(v: &Vector6<f64>, base: &str) -> String {
    let axis = |a: &Vector3<f64>| {
        let k = a.iamax();
        if a[k].abs() >= 0.95 * a.norm() {
            format!("{base}'s {} axis", ["x", "y", "z"][k])
        } else {
            let u = a / a.norm().max(1e-300);
            let u = if u[k] < 0.0 { -u } else { u };
            format!(
                "({:.2}, {:.2}, {:.2}) in {base}'s frame (mostly its {} axis)",
                u.x,
                u.y,
                u.z,
                ["x", "y", "z"][k]
            )
        }
    };
    let (r, t) = (
        v.fixed_rows::<3>(0).into_owned(),
        v.fixed_rows::<3>(3).into_owned(),
    );
    let (rn, tn) = (r.norm(), t.norm());
    let all = (rn * rn + tn * tn).sqrt();
    if tn >= 0.9 * all {
        format!("translation along {}", axis(&t))
    } else if rn >= 0.9 * all {
        format!("rotation about {}", axis(&r))
    } else {
        format!(
            "a rotation about {} coupled with a translation along {}",
            axis(&r),
            axis(&t)
        )
    }
}

/// The hand-eye plan of one robot.
fn hand_eye_plan(
    robot: &CellRobot,
    views: &[crate::camera::DepthView],
    cfg: &PlanConfig,
) -> Result<HandEyePlan> {
    if robot.frames.len() < cfg.hand_eye.min_frames {
        return Ok(HandEyePlan {
            robot: robot.name.clone(),
            dofs: Vec::new(),
            weak_directions: Vec::new(),
            suggested_poses: Vec::new(),
            note: Some(format!(
                "{} frames: the hand-eye fit needs at least {}",
                robot.frames.len(),
                cfg.hand_eye.min_frames
            )),
        });
    }
    let views = (!views.is_empty()).then_some(views);
    let r = refine_hand_eye_from_depth(robot, views, &cfg.hand_eye)?;
    Ok(HandEyePlan {
        robot: robot.name.clone(),
        dofs: r.dofs,
        weak_directions: r.weak_directions,
        suggested_poses: r.suggested_poses,
        note: None,
    })
}

/// A robot's cloud prepared for scoring: downsampled points with surface normals oriented to the side
/// they were seen from, in its own base frame.
struct Scored {
    points: Vec<Vector3<f64>>,
    normals: Vec<Vector3<f64>>,
}

fn scored_cloud(cloud: &PointCloud, voxel: f64) -> Result<Scored> {
    let down = voxel_downsample(cloud, voxel)?;
    let index = KdIndex::new(&down.points);
    let normals = estimate_normals(
        &down.points,
        &index,
        &NormalConfig {
            radius: Some(3.0 * voxel),
            max_neighbors: 30,
        },
    );
    let sides = down.normals.clone();
    let mut out = Scored {
        points: Vec::with_capacity(down.len()),
        normals: Vec::with_capacity(down.len()),
    };
    for (i, p) in down.points.iter().enumerate() {
        let mut n = Vector3::new(
            normals[i][0] as f64,
            normals[i][1] as f64,
            normals[i][2] as f64,
        );
        if n.norm().is_nan() || n.norm() <= 0.5 {
            continue;
        }
        if let Some(s) = sides.as_ref().and_then(|s| s.get(i)) {
            if n.dot(&Vector3::new(s[0] as f64, s[1] as f64, s[2] as f64)) < 0.0 {
                n = -n;
            }
        }
        out.points
            .push(Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        out.normals.push(n);
    }
    Ok(out)
}

/// The candidate views of one robot: each existing camera turned about the point it looks at.
struct Candidate {
    robot: usize,
    from_frame: String,
    rotation_deg: f64,
    axis_camera: Vector3<f64>,
    t_base_ee: Isometry3<f64>,
    t_base_cam: Isometry3<f64>,
}

fn candidates(robot: &CellRobot, k: usize, look_range: f64, cfg: &PlanConfig) -> Vec<Candidate> {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for f in &robot.frames {
        lo = lo.inf(&f.t_base_ee.translation.vector);
        hi = hi.sup(&f.t_base_ee.translation.vector);
    }
    let margin = Vector3::repeat(0.05);
    let (lo, hi) = (lo - margin, hi + margin);
    let x = robot.t_ee_cam;
    let look = Vector3::new(0.0, 0.0, look_range);
    let mut out = Vec::new();
    for f in &robot.frames {
        for axis in [Vector3::x(), Vector3::y()] {
            for &deg in &cfg.turns_deg {
                for sign in [1.0, -1.0] {
                    let rot = UnitQuaternion::from_axis_angle(
                        &Unit::new_normalize(axis),
                        sign * deg.to_radians(),
                    );
                    let about = Translation3::from(look)
                        * Isometry3::from_parts(Translation3::identity(), rot)
                        * Translation3::from(-look);
                    let t_base_ee = f.t_base_ee * x * about * x.inverse();
                    let p = t_base_ee.translation.vector;
                    if (0..3).all(|i| p[i] >= lo[i] && p[i] <= hi[i]) {
                        out.push(Candidate {
                            robot: k,
                            from_frame: f.id.clone(),
                            rotation_deg: sign * deg,
                            axis_camera: axis,
                            t_base_ee,
                            t_base_cam: t_base_ee * x,
                        });
                    }
                }
            }
        }
    }
    out
}

/// The median depth each robot's frames saw (metres) and its 5th-95th percentile range, from the views.
fn depth_range(fused: &crate::fusion::FusedCloud) -> Option<(f64, f64, f64)> {
    let mut z: Vec<f32> = fused
        .views
        .iter()
        .flat_map(|v| v.near.iter().copied().filter(|&d| d > 0.0).step_by(7))
        .collect();
    if z.len() < 10 {
        let mut r = fused.ranges();
        r.retain(|d| d.is_finite() && *d > 0.0);
        z = r;
    }
    if z.is_empty() {
        return None;
    }
    z.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| z[((z.len() - 1) as f64 * f).round() as usize] as f64;
    Some((q(0.5), q(0.05), q(0.95)))
}

/// The information `Σ J Jᵀ` (unweighted) of the points of `pts` (this robot's base frame) that candidate
/// `c` sees, in the reference base frame (`t_ref_base`); and how many it sees.
#[allow(clippy::too_many_arguments)]
fn view_information(
    c: &Candidate,
    robot: &CellRobot,
    pts: &Scored,
    new: &[bool],
    occluders: &[Vector3<f64>],
    (zmin, zmax): (f64, f64),
    t_ref_base: &Isometry3<f64>,
    cfg: &PlanConfig,
) -> (Matrix6<f64>, usize) {
    let intr = &robot.intrinsics;
    let cam_inv = c.t_base_cam.inverse();
    let cell = cfg.zbuffer_px as f64;
    let (gw, gh) = (
        (intr.width as f64 / cell).ceil() as usize,
        (intr.height as f64 / cell).ceil() as usize,
    );
    let slot = |q: &Vector3<f64>| -> Option<usize> {
        if q.z < zmin || q.z > zmax {
            return None;
        }
        let [u, v] = intr.project([q.x, q.y, q.z]);
        if !(u >= 0.0 && v >= 0.0 && u < intr.width as f64 && v < intr.height as f64) {
            return None;
        }
        Some((v / cell) as usize * gw + (u / cell) as usize)
    };
    let mut zbuf = vec![f64::INFINITY; gw * gh];
    for p in occluders {
        let q = cam_inv * Point3::from(*p);
        if let Some(k) = slot(&q.coords) {
            zbuf[k] = zbuf[k].min(q.z);
        }
    }
    let cos_max = cfg.max_incidence_deg.to_radians().cos();
    let tol = 2.0 * cfg.voxel_m;
    let mut h = Matrix6::zeros();
    let mut seen = 0;
    for (i, p) in pts.points.iter().enumerate() {
        if !new[i] {
            continue;
        }
        let q = cam_inv * Point3::from(*p);
        let Some(k) = slot(&q.coords) else { continue };
        if q.z > zbuf[k] + tol {
            continue;
        }
        let to_cam = (c.t_base_cam.translation.vector - p).normalize();
        if pts.normals[i].dot(&to_cam) < cos_max {
            continue;
        }
        let pr = t_ref_base * Point3::from(*p);
        let nr = t_ref_base.rotation * pts.normals[i];
        let j = Vector6::new(
            pr.y * nr.z - pr.z * nr.y,
            pr.z * nr.x - pr.x * nr.z,
            pr.x * nr.y - pr.y * nr.x,
            nr.x,
            nr.y,
            nr.z,
        );
        h += j * j.transpose();
        seen += 1;
    }
    (h, seen)
}

/// The RMS distance of `points` from their centroid, metres (at least 1 mm): the length at which a
/// rotation's 1-σ is counted in millimetres.
pub fn rms_radius(points: &[[f32; 3]]) -> f64 {
    let n = points.len().max(1) as f64;
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| {
        a + Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }) / n;
    (points
        .iter()
        .map(|p| (Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64) - centroid).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
        .max(1e-3)
}

/// The largest 1-σ of covariance `cov`, millimetres (rotations counted at radius `l`, metres).
pub fn directions_sigma_mm(cov: &Matrix6<f64>, l: f64) -> f64 {
    directions(&((cov + cov.transpose()) * 0.5), l)
        .first()
        .map_or(f64::INFINITY, |d| d.1 * 1e3)
}

/// The largest 1-σ (mm-equivalent at radius `l`) of the inverse of information `h`.
fn largest_sigma_mm(h: &Matrix6<f64>, l: f64) -> f64 {
    h.try_inverse()
        .map_or(f64::INFINITY, |c| directions_sigma_mm(&c, l))
}

/// Plans the next captures of a calibrated cell: `cal` and `fused` from [`crate::calibration::robot_to_robot::calibrate_request`]
/// (refined, with the fused clouds and their depth views). Errors: a bad configuration, an unrefined
/// calibration or missing clouds, a hand-eye fit that fails.
pub fn plan_cell(
    cell: &Cell,
    cal: &Calibration,
    fused: &FusedCell,
    cfg: &PlanConfig,
) -> Result<CellPlan> {
    plan_pair(cell.robot_pair()?, cal, fused, cfg)
}

/// [`plan_cell`] for the two robots of `cal` (its reference first) and their fused clouds `fused`: a pair
/// of a cell of three or more robots ([`crate::calibration::plan_robots`]).
pub fn plan_pair(
    (reference, other): (&CellRobot, &CellRobot),
    cal: &Calibration,
    fused: &FusedCell,
    cfg: &PlanConfig,
) -> Result<CellPlan> {
    cfg.validate()?;
    if !cal.refined || fused.reference.cloud.is_empty() || fused.other.cloud.is_empty() {
        return Err(Error::InvalidInput(
            "the plan needs a refined calibration with both fused clouds".into(),
        ));
    }
    let robots = [reference, other];
    let clouds = [&fused.reference, &fused.other];
    let hand_eyes = robots
        .par_iter()
        .zip(clouds.par_iter())
        .map(|(r, c)| hand_eye_plan(r, &c.views, cfg))
        .collect::<Result<Vec<_>>>()?;

    // The registration's part of the covariance, and its information.
    let reg = cal.covariance - cal.inputs_covariance;
    let reg = (reg + reg.transpose()) * 0.5;
    let eig = reg.symmetric_eigen();
    let floor = eig.eigenvalues.max().max(1e-18) * 1e-12;
    let mut h0 = Matrix6::zeros();
    for k in 0..6 {
        let v = eig.eigenvectors.column(k);
        h0 += v * v.transpose() / eig.eigenvalues[k].max(floor);
    }
    let l = rms_radius(&fused.reference.cloud.points);
    let base_name = format!("the {} base", reference.name);
    let weak: Vec<BaseWeakDirection> = directions(&reg, l)
        .into_iter()
        .filter(|(_, s)| s * 1e3 > cfg.weak_sigma_mm)
        .map(|(v, s)| BaseWeakDirection {
            description: base_direction_words(&v, &base_name),
            vector: [v[0], v[1], v[2], v[3], v[4], v[5]],
            sigma_mm: s * 1e3,
        })
        .collect();
    let base_sigma_mm = largest_sigma_mm(&h0, l);
    let mut plan = CellPlan {
        hand_eyes,
        radius_m: l,
        base_sigma_mm,
        base_weak_directions: weak,
        base_suggested_poses: Vec::new(),
        candidates: 0,
    };
    if plan.base_weak_directions.is_empty() || cfg.base_poses == 0 {
        return Ok(plan);
    }

    // Both clouds at the scoring voxel, each in its own base; which points the other robot has not seen.
    let t = cal.transform; // base2 -> base1
    let to_ref = [Isometry3::identity(), t];
    let scored = [
        scored_cloud(&fused.reference.cloud, cfg.voxel_m)?,
        scored_cloud(&fused.other.cloud, cfg.voxel_m)?,
    ];
    let in_ref: Vec<Vec<[f32; 3]>> = (0..2)
        .map(|k| {
            scored[k]
                .points
                .iter()
                .map(|p| {
                    let q = to_ref[k] * Point3::from(*p);
                    [q.x as f32, q.y as f32, q.z as f32]
                })
                .collect()
        })
        .collect();
    let index = [KdIndex::new(&in_ref[0]), KdIndex::new(&in_ref[1])];
    let r2 = ((cfg.shared_voxels * cfg.voxel_m).powi(2)) as f32;
    // For robot k: the other robot's points (in k's base) that k's cloud has no point near.
    let mut per_robot = Vec::new();
    for k in 0..2 {
        let o = 1 - k;
        let base_from_ref = to_ref[k].inverse();
        let pts: Vec<Vector3<f64>> = in_ref[o]
            .iter()
            .map(|p| (base_from_ref * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).coords)
            .collect();
        let normals: Vec<Vector3<f64>> = scored[o]
            .normals
            .iter()
            .map(|nn| base_from_ref.rotation * (to_ref[o].rotation * nn))
            .collect();
        let new: Vec<bool> = in_ref[o]
            .par_iter()
            .map(|p| !index[k].any_closer_than(p, r2))
            .collect();
        let mut occluders = pts.clone();
        occluders.extend(scored[k].points.iter().copied());
        let weight = clouds[o].cloud.len() as f64 / scored[o].points.len().max(1) as f64;
        per_robot.push((
            Scored {
                points: pts,
                normals,
            },
            new,
            occluders,
            weight,
        ));
    }
    let sigma = cal.inlier_rmse.unwrap_or(0.002).max(5e-4);
    let mut cands = Vec::new();
    let mut ranges = Vec::new();
    for k in 0..2 {
        let Some((look, zmin, zmax)) = depth_range(clouds[k]) else {
            ranges.push((0.0, 0.0));
            continue;
        };
        ranges.push((zmin * 0.9, zmax * 1.1));
        cands.extend(candidates(robots[k], k, look, cfg));
    }
    plan.candidates = cands.len();
    let infos: Vec<(Matrix6<f64>, usize)> = cands
        .par_iter()
        .map(|c| {
            let (s, new, occ, w) = &per_robot[c.robot];
            let (h, seen) = view_information(
                c,
                robots[c.robot],
                s,
                new,
                occ,
                ranges[c.robot],
                &to_ref[c.robot],
                cfg,
            );
            (h * (*w / (sigma * sigma)), seen)
        })
        .collect();
    let mut h = h0;
    let mut taken = vec![false; cands.len()];
    let mut current = base_sigma_mm;
    for _ in 0..cfg.base_poses {
        let best = (0..cands.len())
            .filter(|&i| !taken[i] && infos[i].1 > 0)
            .map(|i| (i, largest_sigma_mm(&(h + infos[i].0), l)))
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        let Some((i, s)) = best else { break };
        // A pose that lowers the largest 1-σ by less than 2% is not worth proposing.
        if s > 0.98 * current {
            break;
        }
        taken[i] = true;
        h += infos[i].0;
        current = s;
        let c = &cands[i];
        let kp = KukaPose::from_isometry(&c.t_base_ee);
        plan.base_suggested_poses.push(BasePoseSuggestion {
            robot: robots[c.robot].name.clone(),
            from_frame: c.from_frame.clone(),
            rotation_deg: c.rotation_deg,
            axis_camera: [c.axis_camera.x, c.axis_camera.y, c.axis_camera.z],
            kuka_xyzabc: [kp.x_mm, kp.y_mm, kp.z_mm, kp.a_deg, kp.b_deg, kp.c_deg],
            new_shared_points: infos[i].1,
            predicted_sigma_mm: s,
        });
    }
    Ok(plan)
}
