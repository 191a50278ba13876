//! Robot-to-robot by square fiducial markers (ArUco / AprilTag) that both robots see.
//!
//! Per frame, each marker's `T_cam_marker` comes from its four corners by planar PnP; the aligned depth
//! then fixes the marker plane (a robust plane fit to the depth points inside the marker) and the corners
//! are re-placed where their pixel rays meet that plane, so the pose's distance, tilt and scale come from
//! depth and its in-plane position and yaw from the corners ([`refine_with_depth`]). The pose is brought into
//! the robot's base (robot pose × hand-eye), averaged over the frames per marker with a robust rotation
//! average and its spread reported ([`markers_in_base`]). `T_base1_base2` is the rigid fit of the corners
//! of every marker both robots saw, in base2 onto base1 ([`MarkerInitializer::estimate`]); with one marker
//! it is `T_base1_marker · T_base2_marker⁻¹`.
//!
//! Finding the markers in the colour images needs the `vision` feature (`depthcal::vision::initializers`).

use crate::calibration::average::{average_poses, AverageConfig, PoseAverage};
use crate::calibration::board_init::{BoardInBase, CheckerboardInitializer};
use crate::calibration::initializer::{InitialGuess, Initializer, InitializerInput};
use crate::camera::{DepthImage, Intrinsics};
use crate::cell::CellRobot;
use crate::error::{Error, Result};
use crate::geometry::plane::fit_plane_robust;
use crate::registration::rigid_fit::rigid_fit;
use nalgebra::{Isometry3, Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Settings of the marker method.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MarkerMethodConfig {
    /// Refine each marker pose with the aligned depth (default true); without, PnP alone.
    pub use_depth: bool,
    /// The depth-plane refinement.
    pub depth: DepthPlaneConfig,
    /// A sighting whose PnP RMS reprojection error exceeds this is dropped, pixels (default 2).
    pub max_rms_px: f64,
    /// Per marker, sightings farther than this from the first average are dropped before averaging
    /// again: rotation degrees, translation millimetres (default 2° and 15 mm; each at least 4x the median
    /// deviation).
    pub outlier_deg: f64,
    /// See `outlier_deg`.
    pub outlier_mm: f64,
}

impl Default for MarkerMethodConfig {
    fn default() -> Self {
        MarkerMethodConfig {
            use_depth: true,
            depth: DepthPlaneConfig::default(),
            max_rms_px: 2.0,
            outlier_deg: 2.0,
            outlier_mm: 15.0,
        }
    }
}

impl MarkerMethodConfig {
    /// Checks the ranges; the error names the field (`marker.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        self.depth.validate().map_err(|e| e.within("marker"))?;
        check::positive("marker.max_rms_px", self.max_rms_px)?;
        check::positive("marker.outlier_deg", self.outlier_deg)?;
        check::positive("marker.outlier_mm", self.outlier_mm)
    }
}

/// Settings of [`refine_with_depth`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DepthPlaneConfig {
    /// The plane is fitted to the depth pixels inside the marker's quadrilateral shrunk by this fraction
    /// towards its centre (default 0.1: away from the edges).
    pub shrink: f64,
    /// Fewer valid depth pixels than this: no depth refinement (default 30).
    pub min_points: usize,
    /// A plane whose inliers' RMS distance exceeds this is not the marker's sheet (an occlusion, an edge):
    /// no depth refinement, metres (default 0.006).
    pub max_plane_rms_m: f64,
    /// When the depth-placed marker is farther than this fraction of its distance from the PnP pose, the
    /// two disagree (a wrong size in cell.toml, a depth bias, colour not aligned to depth): the sighting is
    /// dropped (default 0.1).
    pub max_scale_disagreement: f64,
}

impl Default for DepthPlaneConfig {
    fn default() -> Self {
        DepthPlaneConfig {
            shrink: 0.1,
            min_points: 30,
            max_plane_rms_m: 0.006,
            max_scale_disagreement: 0.1,
        }
    }
}

impl DepthPlaneConfig {
    /// Checks the ranges; the error names the field (`depth.…`).
    pub fn validate(&self) -> Result<()> {
        use crate::error::check;
        if !(0.0..1.0).contains(&self.shrink) {
            return Err(Error::config(
                "depth.shrink",
                format!("must be a fraction in [0, 1), got {}", self.shrink),
            ));
        }
        check::at_least("depth.min_points", self.min_points, 3)?;
        check::positive("depth.max_plane_rms_m", self.max_plane_rms_m)?;
        check::positive("depth.max_scale_disagreement", self.max_scale_disagreement)
    }
}

/// What the depth under a marker said.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DepthFit {
    /// Depth points the plane was fitted to (inliers).
    pub points: usize,
    /// Their RMS distance from the plane, millimetres.
    pub plane_rms_mm: f64,
    /// Mean edge of the depth-placed marker, metres (compare with the configured size).
    pub edge_m: f64,
    /// Angle between the PnP pose's marker normal and the depth plane's, degrees.
    pub pnp_normal_deg: f64,
    /// Distance between the PnP and the depth-refined marker centres, millimetres.
    pub pnp_shift_mm: f64,
}

/// One marker seen in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerSighting {
    /// Frame id.
    pub frame: String,
    /// Marker id.
    pub id: u32,
    /// `T_cam_marker`, metres (depth-refined when `depth` is set).
    pub t_cam_marker: Isometry3<f64>,
    /// PnP RMS reprojection error, pixels.
    pub rms_px: f64,
    /// The depth refinement, when it ran.
    pub depth: Option<DepthFit>,
}

/// Refines a marker's PnP pose `t_pnp` with the aligned depth: fits a plane to the depth points inside the
/// (shrunk) quadrilateral `corners` (pixels), intersects the corners' pixel rays with it and fits the marker
/// frame's `object` corners (metres, same order) to those points. `None` when the depth cannot be used
/// (too few points, not planar); `Err(reason)` when depth and PnP disagree on the marker's distance.
pub fn refine_with_depth(
    corners: &[Point2<f64>; 4],
    object: &[Point3<f64>; 4],
    t_pnp: &Isometry3<f64>,
    intr: &Intrinsics,
    depth: &DepthImage,
    cfg: &DepthPlaneConfig,
) -> Option<std::result::Result<(Isometry3<f64>, DepthFit), String>> {
    let c = corners.iter().fold(Vector3::zeros(), |a, p| {
        a + Vector3::new(p.x, p.y, 0.0) / 4.0
    });
    let quad: Vec<Point2<f64>> = corners
        .iter()
        .map(|p| {
            Point2::new(
                c.x + (p.x - c.x) * (1.0 - cfg.shrink),
                c.y + (p.y - c.y) * (1.0 - cfg.shrink),
            )
        })
        .collect();
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for q in &quad {
        (u0, u1, v0, v1) = (u0.min(q.x), u1.max(q.x), v0.min(q.y), v1.max(q.y));
    }
    let (w, h) = (depth.width as i64, depth.height as i64);
    let ur = (u0.ceil().max(0.0) as i64, (u1.floor() as i64).min(w - 1));
    let vr = (v0.ceil().max(0.0) as i64, (v1.floor() as i64).min(h - 1));
    let mut pts = Vec::new();
    for v in vr.0..=vr.1 {
        for u in ur.0..=ur.1 {
            let (uf, vf) = (u as f64, v as f64);
            if !inside_convex(&quad, uf, vf) {
                continue;
            }
            let raw = depth.get(u as u32, v as u32);
            if raw == 0 {
                continue;
            }
            let p = intr.deproject([uf, vf], raw as f64 * intr.depth_scale);
            pts.push(Point3::new(p[0], p[1], p[2]));
        }
    }
    if pts.len() < cfg.min_points {
        return None;
    }
    let (plane, keep, rms) = fit_plane_robust(&pts, 3, 3.0, 2e-4)?;
    let inliers = keep.iter().filter(|k| **k).count();
    if inliers < cfg.min_points || rms > cfg.max_plane_rms_m {
        return None;
    }
    let mut on_plane = [Point3::origin(); 4];
    for (k, q) in corners.iter().enumerate() {
        let [x, y] = intr.pixel_ray([q.x, q.y]);
        on_plane[k] = plane.intersect_ray(&Vector3::new(x, y, 1.0))?;
    }
    let t = rigid_fit(object, &on_plane, None)?;
    let edge_m = (0..4)
        .map(|k| (on_plane[(k + 1) % 4] - on_plane[k]).norm())
        .sum::<f64>()
        / 4.0;
    let centre_pnp = t_pnp.translation.vector;
    let shift = (t.translation.vector - centre_pnp).norm();
    if shift > cfg.max_scale_disagreement * centre_pnp.norm() {
        return Some(Err(format!(
            "depth puts the marker {:.0} mm from where PnP does at {:.2} m (marker edge from depth {:.1} mm): \
             check size_m in [markers], and that colour is aligned to depth",
            shift * 1e3,
            centre_pnp.norm(),
            edge_m * 1e3
        )));
    }
    let n_pnp = t_pnp.rotation * Vector3::z();
    let n_depth = t.rotation * Vector3::z();
    Some(Ok((
        t,
        DepthFit {
            points: inliers,
            plane_rms_mm: rms * 1e3,
            edge_m,
            pnp_normal_deg: n_pnp.angle(&n_depth).to_degrees(),
            pnp_shift_mm: shift * 1e3,
        },
    )))
}

/// Whether `(u, v)` lies inside the convex quadrilateral `q` (either winding).
fn inside_convex(q: &[Point2<f64>], u: f64, v: f64) -> bool {
    let mut sign = 0.0f64;
    for k in 0..q.len() {
        let (a, b) = (q[k], q[(k + 1) % q.len()]);
        let cr = (b.x - a.x) * (v - a.y) - (b.y - a.y) * (u - a.x);
        if cr != 0.0 {
            if sign != 0.0 && cr.signum() != sign {
                return false;
            }
            sign = cr.signum();
        }
    }
    true
}

/// One marker's pose in one robot's base, averaged over the frames that saw it.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerInBase {
    /// The robot.
    pub robot: String,
    /// Marker id.
    pub id: u32,
    /// The black-square edge used, metres.
    pub size_m: f64,
    /// `T_base_marker` averaged over `frames` with its spread.
    pub average: PoseAverage,
    /// The frames averaged (in the order of `average.rotation_deg`).
    pub frames: Vec<String>,
    /// Frames dropped as outliers of the average.
    pub dropped: Vec<String>,
}

/// Each marker's `T_base_marker` from its sightings in the robot's frames (`T_base_ee · T_ee_cam ·
/// T_cam_marker`), averaged per marker with a robust rotation average; sightings far from the first average
/// are dropped (see [`MarkerMethodConfig::outlier_deg`]) and the rest averaged again. `size_of` gives
/// each id's edge. Sorted by id.
pub fn markers_in_base(
    robot: &CellRobot,
    sightings: &[MarkerSighting],
    size_of: &dyn Fn(u32) -> f64,
    cfg: &MarkerMethodConfig,
) -> Result<Vec<MarkerInBase>> {
    let mut by_id: BTreeMap<u32, Vec<(String, Isometry3<f64>)>> = BTreeMap::new();
    for s in sightings {
        let i = robot
            .frames
            .iter()
            .position(|f| f.id == s.frame)
            .ok_or_else(|| {
                Error::InvalidInput(format!(
                    "robot {:?} has no frame {:?} (a marker sighting names it)",
                    robot.name, s.frame
                ))
            })?;
        by_id
            .entry(s.id)
            .or_default()
            .push((s.frame.clone(), robot.t_base_cam(i) * s.t_cam_marker));
    }
    let avg_cfg = AverageConfig {
        l1_iterations: 50,
        ..AverageConfig::default()
    };
    let mut out = Vec::with_capacity(by_id.len());
    for (id, list) in by_id {
        let poses: Vec<Isometry3<f64>> = list.iter().map(|(_, p)| *p).collect();
        let first = average_poses(&poses, None, &avg_cfg)?;
        let median = crate::stats::upper_median;
        let lim_r = cfg.outlier_deg.max(4.0 * median(&first.rotation_deg));
        let lim_t = cfg.outlier_mm.max(4.0 * median(&first.translation_mm));
        let keep: Vec<bool> = (0..poses.len())
            .map(|k| first.rotation_deg[k] <= lim_r && first.translation_mm[k] <= lim_t)
            .collect();
        let kept: Vec<Isometry3<f64>> = poses
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(p, _)| *p)
            .collect();
        let average = if kept.len() == poses.len() {
            first
        } else {
            average_poses(&kept, None, &avg_cfg)?
        };
        let (frames, dropped): (Vec<_>, Vec<_>) =
            list.into_iter().zip(&keep).partition(|(_, &k)| k);
        out.push(MarkerInBase {
            robot: robot.name.clone(),
            id,
            size_m: size_of(id),
            average,
            frames: frames.into_iter().map(|((f, _), _)| f).collect(),
            dropped: dropped.into_iter().map(|((f, _), _)| f).collect(),
        });
    }
    Ok(out)
}

/// `T_base1_base2` from the markers both robots saw.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerInitializer {
    /// The reference robot's markers (base1).
    pub reference: Vec<MarkerInBase>,
    /// The other robot's markers (base2).
    pub other: Vec<MarkerInBase>,
}

/// The result of [`MarkerInitializer::estimate`].
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerEstimate {
    /// `T_base1_base2`.
    pub transform: Isometry3<f64>,
    /// 1-σ rotation, degrees.
    pub sigma_rotation_deg: f64,
    /// 1-σ translation, metres.
    pub sigma_translation_m: f64,
    /// The marker ids both robots saw.
    pub common: Vec<u32>,
    /// RMS distance of the fitted corners (base2 corners mapped into base1 against base1's), millimetres;
    /// 0 with one marker.
    pub fit_rms_mm: f64,
}

impl MarkerInitializer {
    /// The rigid fit of the common markers' corners (weighted by each marker's precision) with its
    /// uncertainty. Errors when no marker was seen by both robots, naming what each saw.
    pub fn estimate(&self) -> Result<MarkerEstimate> {
        let ids = |v: &[MarkerInBase]| v.iter().map(|m| m.id).collect::<Vec<_>>();
        let common: Vec<u32> = ids(&self.reference)
            .into_iter()
            .filter(|i| self.other.iter().any(|m| m.id == *i))
            .collect();
        if common.is_empty() {
            let name = |v: &[MarkerInBase]| v.first().map_or("?".to_string(), |m| m.robot.clone());
            return Err(Error::InvalidInput(format!(
                "no marker was seen by both robots: {} saw ids {:?}, {} saw ids {:?}; place a marker where both \
                 robots' cameras see it",
                name(&self.reference),
                ids(&self.reference),
                name(&self.other),
                ids(&self.other)
            )));
        }
        let (mut p1, mut p2, mut w) = (Vec::new(), Vec::new(), Vec::new());
        let (mut info_r, mut info_t) = (0.0, 0.0);
        for id in &common {
            let a = self.reference.iter().find(|m| m.id == *id).expect("common");
            let b = self.other.iter().find(|m| m.id == *id).expect("common");
            let side = |m: &MarkerInBase| {
                BoardInBase::from_average(&m.robot, &m.average, &format!("marker {}", m.id))
            };
            let (_, sr, st) = CheckerboardInitializer {
                reference: side(a),
                other: side(b),
            }
            .estimate();
            // Never claim better than 0.01° / 0.1 mm from one marker.
            let (sr, st) = (sr.max(0.01), st.max(1e-4));
            info_r += 1.0 / (sr * sr);
            info_t += 1.0 / (st * st);
            let h = a.size_m / 2.0;
            for (x, y) in [(-h, h), (h, h), (h, -h), (-h, -h)] {
                let q = Point3::new(x, y, 0.0);
                p1.push(a.average.mean * q);
                p2.push(b.average.mean * q);
                w.push(1.0 / (st * st));
            }
        }
        let transform = rigid_fit(&p2, &p1, Some(&w))
            .ok_or_else(|| Error::Failed("the marker corners gave no rigid fit".into()))?;
        let fit_rms_mm = if common.len() > 1 {
            let s: f64 = p2
                .iter()
                .zip(&p1)
                .map(|(a, b)| (transform * a - b).norm_squared())
                .sum();
            (s / p1.len() as f64).sqrt() * 1e3
        } else {
            0.0
        };
        let n_pts = p1.len() as f64;
        // Floors: on simulated cells the errors were 0.05-0.06° / 0.3-0.8 mm whatever the spreads said
        // (corner localisation and depth biases that averaging over frames does not remove).
        Ok(MarkerEstimate {
            transform,
            sigma_rotation_deg: info_r.recip().sqrt().max(0.05),
            sigma_translation_m: info_t
                .recip()
                .sqrt()
                .max(fit_rms_mm * 1e-3 / n_pts.sqrt())
                .max(5e-4),
            common,
            fit_rms_mm,
        })
    }
}

impl Initializer for MarkerInitializer {
    fn name(&self) -> &str {
        "marker"
    }
    fn needs_clouds(&self) -> bool {
        false
    }
    fn initialize(&self, _input: &InitializerInput) -> Result<InitialGuess> {
        let e = self.estimate()?;
        let side = |v: &[MarkerInBase]| {
            v.iter()
                .filter(|m| e.common.contains(&m.id))
                .map(|m| {
                    format!(
                        "{} #{}: {} frames, spread {:.3}° / {:.2} mm",
                        m.robot,
                        m.id,
                        m.frames.len(),
                        m.average.rotation_rms_deg,
                        m.average.translation_rms_mm
                    )
                })
                .collect::<Vec<_>>()
                .join("; ")
        };
        Ok(InitialGuess {
            transform: e.transform,
            sigma_rotation_deg: e.sigma_rotation_deg,
            sigma_translation_m: e.sigma_translation_m,
            detail: format!(
                "marker: {} common marker(s) {:?}, corner fit RMS {:.2} mm; {}; {}",
                e.common.len(),
                e.common,
                e.fit_rms_mm,
                side(&self.reference),
                side(&self.other)
            ),
            ambiguity: None,
            alternatives: Vec::new(),
        })
    }
}

/// Finds a robot's marker sightings in its colour images (`depthcal::vision::initializers` with the
/// `vision` feature; [`markers_need_vision`] without): the sightings and notes about frames not used.
pub type SightingFinder<'a> = dyn FnMut(
        &CellRobot,
        &crate::cell::MarkerTarget,
        &MarkerMethodConfig,
    ) -> Result<(Vec<MarkerSighting>, Vec<String>)>
    + 'a;

/// The marker initialiser of a cell: each robot's markers found by `find` in its colour images with the
/// `[markers]` table of `cell.toml`. Returns it with notes about frames and sightings not used.
pub fn marker_initializer_with(
    cell: &crate::cell::Cell,
    cfg: &MarkerMethodConfig,
    find: &mut SightingFinder<'_>,
) -> Result<(MarkerInitializer, Vec<String>)> {
    let (reference, other) = cell.robot_pair()?;
    let manifest = cell.dir.join(crate::cell::MANIFEST_FILE);
    let target = crate::cell::MarkerTarget::from_manifest_extra(&cell.manifest.extra, &manifest)?
        .ok_or_else(|| {
        Error::InvalidInput(format!(
            "{}: no [markers] table (dictionary, size_m): the marker method needs the markers' \
                 dictionary and printed size",
            manifest.display()
        ))
    })?;
    let mut notes = Vec::new();
    let mut sides = Vec::with_capacity(2);
    for r in [reference, other] {
        let (sightings, n) = find(r, &target, cfg)?;
        notes.extend(n.iter().map(|n| format!("robot {:?}: {n}", r.name)));
        let m = markers_in_base(r, &sightings, &|id| target.size_of(id), cfg)?;
        for k in &m {
            if !k.dropped.is_empty() {
                notes.push(format!(
                    "robot {:?}: marker {} dropped as an outlier in frames {}",
                    r.name,
                    k.id,
                    k.dropped.join(", ")
                ));
            }
        }
        sides.push((r, m, n));
    }
    let other = sides.pop().expect("two robots");
    let reference = sides.pop().expect("two robots");
    let ids = |m: &[MarkerInBase]| m.iter().map(|k| k.id).collect::<Vec<_>>();
    for (blind, seer) in [(&reference, &other), (&other, &reference)] {
        if blind.1.is_empty() {
            let (r, _, n) = blind;
            return Err(Error::InvalidInput(format!(
                "robot {:?} saw no marker of dictionary {} in its {} colour images{}; the marker method \
                 needs a marker both robots see:\n  {}",
                r.name,
                target.dictionary,
                r.frames.len(),
                if seer.1.is_empty() {
                    format!(", nor did robot {:?}", seer.0.name)
                } else {
                    format!(" (robot {:?} saw ids {:?})", seer.0.name, ids(&seer.1))
                },
                n.join("\n  ")
            )));
        }
    }
    let (reference, other) = (reference.1, other.1);
    Ok((MarkerInitializer { reference, other }, notes))
}

/// The [`SightingFinder`] of a build without the `vision` feature: an error saying how to get one.
pub fn markers_need_vision(
    r: &CellRobot,
    _target: &crate::cell::MarkerTarget,
    _cfg: &MarkerMethodConfig,
) -> Result<(Vec<MarkerSighting>, Vec<String>)> {
    Err(Error::InvalidInput(format!(
        "robot {:?}: finding markers in its colour images needs depthcal built with the `vision` feature \
         (OpenCV): `cargo build --release --features vision`",
        r.name
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::pose_error;
    use crate::geometry::transform::random_isometry;
    use crate::geometry::Rng;
    use nalgebra::{Translation3, UnitQuaternion};

    fn robot(name: &str, poses: &[Isometry3<f64>]) -> CellRobot {
        CellRobot::for_tests(
            name,
            Intrinsics::pinhole(640, 480, 600.0, 600.0, 320.0, 240.0),
            Isometry3::translation(0.0, 0.0, 0.05),
            poses,
        )
    }

    #[test]
    fn depth_plane_fixes_distance_and_tilt() {
        // A marker 0.5 m ahead, tilted; PnP's pose is given 3% too far and 4° off in tilt: the depth
        // plane and the corner rays put it back.
        let intr = Intrinsics::pinhole(640, 480, 600.0, 600.0, 320.0, 240.0);
        let truth = Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.5),
            UnitQuaternion::from_euler_angles(2.9, 0.3, 0.6),
        );
        let h = 0.04;
        let object = [(-h, h), (h, h), (h, -h), (-h, -h)].map(|(x, y)| Point3::new(x, y, 0.0));
        let corners = object.map(|p| {
            let c = truth * p;
            let [u, v] = intr.project([c.x, c.y, c.z]);
            Point2::new(u, v)
        });
        let n = truth.rotation * Vector3::z();
        let mut depth = DepthImage::zeros(640, 480);
        let mut rng = Rng::new(2);
        for v in 0..480u32 {
            for u in 0..640u32 {
                let [x, y] = intr.pixel_ray([u as f64, v as f64]);
                let d = Vector3::new(x, y, 1.0);
                let t = n.dot(&truth.translation.vector) / n.dot(&d);
                let z = t + 0.001 * rng.normal();
                depth.data[(v * 640 + u) as usize] = (z / intr.depth_scale).round() as u16;
            }
        }
        let off = Isometry3::from_parts(
            Translation3::from(truth.translation.vector * 0.03),
            UnitQuaternion::from_euler_angles(0.07, 0.0, 0.0),
        );
        let pnp = off * truth;
        let (t, fit) = refine_with_depth(
            &corners,
            &object,
            &pnp,
            &intr,
            &depth,
            &DepthPlaneConfig::default(),
        )
        .unwrap()
        .unwrap();
        let (r, t) = pose_error(&t, &truth);
        assert!(r < 0.3 && t < 1e-3, "{r}° / {t} m");
        assert!(
            (fit.edge_m - 0.08).abs() < 1e-3 && fit.points > 1000,
            "{fit:?}"
        );
        assert!(fit.pnp_normal_deg > 2.0);
        // A much wrong distance is reported, not averaged in.
        let far = Isometry3::from_parts(
            Translation3::from(truth.translation.vector * 1.3),
            truth.rotation,
        );
        let r = refine_with_depth(
            &corners,
            &object,
            &far,
            &intr,
            &depth,
            &DepthPlaneConfig::default(),
        );
        assert!(r.unwrap().unwrap_err().contains("size_m"));
        // No depth: no refinement.
        let r = refine_with_depth(
            &corners,
            &object,
            &pnp,
            &intr,
            &DepthImage::zeros(640, 480),
            &DepthPlaneConfig::default(),
        );
        assert!(r.is_none());
    }

    #[test]
    fn common_markers_give_the_transform_and_outliers_are_dropped() {
        let mut rng = Rng::new(9);
        let t_b1_b2 = random_isometry(&mut rng, 3.0, 1.2);
        let markers: Vec<Isometry3<f64>> = (0..3)
            .map(|_| random_isometry(&mut rng, 3.0, 0.3))
            .collect();
        let ee1: Vec<Isometry3<f64>> = (0..6)
            .map(|_| random_isometry(&mut rng, 3.0, 0.6))
            .collect();
        let ee2: Vec<Isometry3<f64>> = (0..6)
            .map(|_| random_isometry(&mut rng, 3.0, 0.6))
            .collect();
        let (r1, r2) = (robot("left", &ee1), robot("right", &ee2));
        let mut sight =
            |r: &CellRobot, t_base_world: &Isometry3<f64>, ids: &[u32], bad: Option<usize>| {
                let mut v = Vec::new();
                for (i, f) in r.frames.iter().enumerate() {
                    for &id in ids {
                        let t_cam_m =
                            r.t_base_cam(i).inverse() * t_base_world * markers[id as usize];
                        let noise = if bad == Some(i) {
                            Isometry3::translation(0.05, 0.0, 0.0)
                        } else {
                            Isometry3::translation(1e-4 * rng.normal(), 1e-4 * rng.normal(), 0.0)
                        };
                        v.push(MarkerSighting {
                            frame: f.id.clone(),
                            id,
                            t_cam_marker: t_cam_m * noise,
                            rms_px: 0.1,
                            depth: None,
                        });
                    }
                }
                v
            };
        let cfg = MarkerMethodConfig::default();
        let s1 = sight(&r1, &Isometry3::identity(), &[0, 1, 2], None);
        let s2 = sight(&r2, &t_b1_b2.inverse(), &[1, 2], Some(3));
        let m1 = markers_in_base(&r1, &s1, &|_| 0.08, &cfg).unwrap();
        let m2 = markers_in_base(&r2, &s2, &|_| 0.08, &cfg).unwrap();
        assert_eq!(m2.len(), 2);
        assert_eq!(m2[0].dropped, vec!["0003".to_string()]);
        let init = MarkerInitializer {
            reference: m1.clone(),
            other: m2,
        };
        let e = init.estimate().unwrap();
        assert_eq!(e.common, vec![1, 2]);
        let (r, t) = pose_error(&e.transform, &t_b1_b2);
        assert!(r < 0.05 && t < 1e-3, "{r}° / {t} m");
        assert!(e.sigma_translation_m > 1e-5 && e.sigma_translation_m < 5e-3);
        // A marker seen by one robot only.
        let lonely = MarkerInitializer {
            reference: m1[..1].to_vec(),
            other: init.other.clone(),
        };
        let err = lonely.estimate().unwrap_err().to_string();
        assert!(
            err.contains("both robots") && err.contains("left saw ids [0]"),
            "{err}"
        );
    }
}
