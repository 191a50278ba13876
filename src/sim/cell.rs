//! Simulated cells of two or more robots (`robot_names`, 2 to 8): the layout of the robot bases around the table, each robot's hand-eye and
//! flange poses, rendering of every frame, and writing the whole as a `depthcal-cell/1` dataset with
//! `ground_truth.json`.
//!
//! Frames: `world` is the table frame of [`Scene`]. Robot `i` has its base frame `base_i` (z up, or tilted by
//! a degree or two with `bases_level = false`); `T_world_base` places it. The answer a calibration must find
//! is `T_base1_base2 = T_world_base1⁻¹ · T_world_base2` (maps the second robot's base coordinates into the
//! reference robot's base).
//!
//! Everything written is self-consistent: the poses are rendered exactly as they read back from the KUKA
//! pose file (6 decimals of mm and degrees) and the hand-eye as it reads back from `cell.toml`.

use super::camera::{Resolution, SimCamera};
use super::noise::{NoiseConfig, NoiseLevel};
use super::overlap::{shared_fractions, SharedConfig};
use super::render::{render_frame, write_rgb_png, RenderedFrame};
use super::scene::{Scene, SceneConfig};
use crate::camera::write_depth_png;
use crate::cell::{CellManifest, GroundTruth, RobotEntry, FRAME_PLACEHOLDER};
use crate::error::{Error, Result};
use crate::fusion::CropBox;
use crate::geometry::transform::{isometry_from_rows, isometry_to_nested, isometry_to_rows};
use crate::geometry::Rng;
use crate::io::poses::{write_poses, PoseFormat, PoseRecord};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Settings of a simulated cell. Every field has a default; lengths in metres, angles in degrees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// The seed of everything random (scene, layout, hand-eyes, poses, noise). Default 1.
    pub seed: u64,
    /// Frames per robot (default 20).
    pub frames: usize,
    /// Depth stream resolution (default 640x480).
    pub resolution: Resolution,
    /// Metres per depth unit of the written depth images (default 0.001; RealSense also offers e.g. 0.0001,
    /// which limits the range to 6.5 m).
    pub depth_scale: f64,
    /// Noise level (default `default`); ignored when `noise` is given.
    pub noise_level: NoiseLevel,
    /// An explicit noise model (overrides `noise_level`).
    pub noise: Option<NoiseConfig>,
    /// How much of the scene both robots see, 0–1 (default 0.7): the fraction of the surface each robot's
    /// views see that the other robot's views also see (1 cm voxels, mean of both robots; with more robots,
    /// the mean over every robot and every other robot). The simulator
    /// places the views to meet it: a view spread from 0 (each robot looks at its own side of the workspace,
    /// close and steep, within ±25° of azimuth) to 1 (both circle the table at ±145°, from the whole distance
    /// and elevation ranges) is chosen by bisection on a sparse ray cast. Where the scene cannot reach the
    /// target (a small table seen from afar is always shared), the nearest reachable value is used; the
    /// achieved fractions are in `ground_truth.json` (`shared_fraction`).
    pub overlap: f64,
    /// The table and its objects.
    pub scene: SceneConfig,
    /// Robot names, 2 to 8 of them; the first is the reference (default `left`, `right`; see
    /// [`SimConfig::default_robot_names`]). With more than two, the bases stand evenly round the table: the
    /// reference at azimuth 180°, robot `i` at 180° + 360°·i/N, each ± `base_azimuth_jitter_deg` (at most a
    /// quarter of the spacing).
    pub robot_names: Vec<String>,
    /// Nominal distance between the two bases, metres (default 1.2); each base stands at half of it from the
    /// table centre, each ±`base_distance_jitter_m`/2 (with more robots, every base at that radius).
    pub base_distance_m: f64,
    /// Random variation of the base distance, metres (default 0.1).
    pub base_distance_jitter_m: f64,
    /// The second base sits opposite the first around the table ± this azimuth, degrees (default 25).
    pub base_azimuth_jitter_deg: f64,
    /// Each base's yaw is "facing the table centre" ± this, degrees (default 180: any yaw, so that
    /// `T_base1_base2` has a random yaw).
    pub base_yaw_range_deg: f64,
    /// Height range of the base origins relative to the table top, metres (default `[-0.08, 0.02]`).
    pub base_height_m: [f64; 2],
    /// Bases upright (z exactly up). With `false` each base is tilted by up to `base_tilt_deg` about a random
    /// horizontal axis (default true).
    pub bases_level: bool,
    /// Largest base tilt when `bases_level` is false, degrees (default 2).
    pub base_tilt_deg: f64,
    /// Range of camera distances from the aim point near the workspace centre, metres (default
    /// `[0.35, 0.8]`).
    pub view_distance_m: [f64; 2],
    /// Range of camera elevations above the table plane, degrees (default `[25, 75]`).
    pub view_elevation_deg: [f64; 2],
    /// Random roll of each view about the optical axis, ± degrees (default 30).
    pub view_roll_deg: f64,
    /// Largest lateral (x, y) offset of the camera from the flange, metres (default 0.05); the offset along
    /// the flange z is 0.03–0.12 m.
    pub hand_eye_offset_m: f64,
    /// Largest tilt of the camera axis from the flange z axis, degrees (default 10); the rotation about it is
    /// random.
    pub hand_eye_tilt_deg: f64,
    /// Render and write colour images (default true).
    pub color: bool,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            seed: 1,
            frames: 20,
            resolution: Resolution::Vga,
            depth_scale: crate::camera::DEFAULT_DEPTH_SCALE,
            noise_level: NoiseLevel::Default,
            noise: None,
            overlap: 0.7,
            scene: SceneConfig::default(),
            robot_names: SimConfig::default_robot_names(2),
            base_distance_m: 1.2,
            base_distance_jitter_m: 0.1,
            base_azimuth_jitter_deg: 25.0,
            base_yaw_range_deg: 180.0,
            base_height_m: [-0.08, 0.02],
            bases_level: true,
            base_tilt_deg: 2.0,
            view_distance_m: [0.35, 0.8],
            view_elevation_deg: [25.0, 75.0],
            view_roll_deg: 30.0,
            hand_eye_offset_m: 0.05,
            hand_eye_tilt_deg: 10.0,
            color: true,
        }
    }
}

impl SimConfig {
    /// Most robots a simulated cell holds.
    pub const MAX_ROBOTS: usize = 8;

    /// The default names of `n` robots: `left`, `right`, then `robot3`, `robot4`, ….
    pub fn default_robot_names(n: usize) -> Vec<String> {
        (0..n)
            .map(|i| match i {
                0 => "left".to_string(),
                1 => "right".to_string(),
                _ => format!("robot{}", i + 1),
            })
            .collect()
    }

    /// `n` robots (2 to [`SimConfig::MAX_ROBOTS`]): keeps `robot_names` when it already names `n`, else the
    /// default names ([`SimConfig::default_robot_names`]). The error names `robots`.
    pub fn set_robots(&mut self, n: usize) -> Result<()> {
        if !(2..=Self::MAX_ROBOTS).contains(&n) {
            return Err(Error::Config {
                field: "robots".into(),
                msg: format!(
                    "--robots {n}: a simulated cell holds 2 to {} robots",
                    Self::MAX_ROBOTS
                ),
            });
        }
        if self.robot_names.len() != n {
            self.robot_names = Self::default_robot_names(n);
        }
        Ok(())
    }

    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("sim.{field}"),
                msg,
            })
        };
        if self.frames == 0 {
            return bad("frames", "must be at least 1".into());
        }
        if !(self.depth_scale.is_finite() && self.depth_scale > 0.0 && self.depth_scale <= 0.01) {
            return bad(
                "depth_scale",
                format!(
                    "must be in (0, 0.01] metres per unit, found {}",
                    self.depth_scale
                ),
            );
        }
        if !(0.0..=1.0).contains(&self.overlap) {
            return bad(
                "overlap",
                format!("must be in [0, 1], found {}", self.overlap),
            );
        }
        let names = &self.robot_names;
        let distinct = names
            .iter()
            .enumerate()
            .all(|(i, n)| !names[..i].contains(n));
        if !(2..=Self::MAX_ROBOTS).contains(&names.len())
            || !distinct
            || names
                .iter()
                .any(|n| n.is_empty() || n.contains(['/', '\\']) || n.starts_with('.'))
        {
            return bad(
                "robot_names",
                format!(
                    "need 2 to {} different names usable as directory names, found {:?}",
                    Self::MAX_ROBOTS,
                    self.robot_names
                ),
            );
        }
        if !(self.base_distance_m > 0.2 && self.base_distance_m.is_finite()) {
            return bad(
                "base_distance_m",
                format!("must exceed 0.2 m, found {}", self.base_distance_m),
            );
        }
        let range_ok = |r: [f64; 2]| r[0].is_finite() && r[1].is_finite() && r[0] <= r[1];
        if !range_ok(self.view_distance_m) || self.view_distance_m[0] <= 0.05 {
            return bad(
                "view_distance_m",
                format!(
                    "must be [lo, hi] with 0.05 < lo ≤ hi, found {:?}",
                    self.view_distance_m
                ),
            );
        }
        if !range_ok(self.view_elevation_deg)
            || self.view_elevation_deg[0] < 1.0
            || self.view_elevation_deg[1] > 89.0
        {
            return bad(
                "view_elevation_deg",
                format!(
                    "must be [lo, hi] with 1 ≤ lo ≤ hi ≤ 89, found {:?}",
                    self.view_elevation_deg
                ),
            );
        }
        if !range_ok(self.base_height_m) {
            return bad(
                "base_height_m",
                format!("must be [lo, hi], found {:?}", self.base_height_m),
            );
        }
        for (f, v) in [
            ("base_distance_jitter_m", self.base_distance_jitter_m),
            ("base_azimuth_jitter_deg", self.base_azimuth_jitter_deg),
            ("base_yaw_range_deg", self.base_yaw_range_deg),
            ("base_tilt_deg", self.base_tilt_deg),
            ("view_roll_deg", self.view_roll_deg),
            ("hand_eye_offset_m", self.hand_eye_offset_m),
            ("hand_eye_tilt_deg", self.hand_eye_tilt_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(f, format!("must be ≥ 0, found {v}"));
            }
        }
        if let Some(n) = &self.noise {
            n.validate()?;
        }
        self.scene.validate()
    }

    /// The noise model in force: `noise` if given, else the one of `noise_level`.
    pub fn noise_model(&self) -> NoiseConfig {
        self.noise
            .clone()
            .unwrap_or_else(|| self.noise_level.config())
    }
}

/// One simulated robot: where its base stands, its camera and hand-eye, and its flange poses.
#[derive(Clone, Debug)]
pub struct SimRobot {
    /// The robot's name.
    pub name: String,
    /// Pose of the base in the world (table) frame, metres.
    pub t_world_base: Isometry3<f64>,
    /// The hand-eye transform `T_ee_cam`, metres (as it reads back from `cell.toml`).
    pub t_ee_cam: Isometry3<f64>,
    /// The depth camera.
    pub camera: SimCamera,
    /// Flange poses `T_base_ee` (as they read back from the KUKA pose file), with frame ids.
    pub poses: Vec<PoseRecord>,
}

impl SimRobot {
    /// `T_base_cam` of frame `k`.
    pub fn t_base_cam(&self, k: usize) -> Isometry3<f64> {
        self.poses[k].pose * self.t_ee_cam
    }

    /// `T_world_cam` of frame `k`.
    pub fn t_world_cam(&self, k: usize) -> Isometry3<f64> {
        self.t_world_base * self.t_base_cam(k)
    }
}

/// A simulated two-robot cell in memory: the scene, the robots and their poses. Frames are rendered on
/// demand ([`SimCell::render`]) or all at once when writing ([`SimCell::write`]).
#[derive(Clone, Debug)]
pub struct SimCell {
    /// The settings it was made from.
    pub config: SimConfig,
    /// The noise model in force.
    pub noise: NoiseConfig,
    /// The scene.
    pub scene: Scene,
    /// The robots (two or more); the first is the reference.
    pub robots: Vec<SimRobot>,
    /// The view spread chosen for `config.overlap`, 0–1 (see [`SimConfig::overlap`]).
    pub view_spread: f64,
    /// Per robot (reference first): the fraction of the surface its views see that another robot's views
    /// also see, the mean over the other robots (1 cm voxels, noise-free sparse ray cast).
    pub shared: Vec<f64>,
}

/// Sizes of a written dataset.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WriteStats {
    /// Files written.
    pub files: usize,
    /// Bytes written.
    pub bytes: u64,
    /// Frames rendered (all robots).
    pub frames: usize,
}

fn rot_z(a: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a)
}

/// Round trip through the text forms the dataset stores, so the rendered poses equal those read back.
fn as_read_back_kuka(t: &Isometry3<f64>) -> Result<Isometry3<f64>> {
    let text = PoseFormat::Kuka.format_values(t);
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.parse::<f64>().expect("formatted number"))
        .collect();
    PoseFormat::Kuka
        .parse_values(&v)
        .map_err(|m| Error::InvalidInput(format!("simulated pose: {m}")))
}

fn as_read_back_hand_eye(t: &Isometry3<f64>) -> Result<Isometry3<f64>> {
    let mut rows = isometry_to_rows(t);
    for v in &mut rows {
        *v = (*v * 1e12).round() / 1e12;
    }
    isometry_from_rows(&rows, "T_ee_cam")
}

/// Camera pose looking from `pos` at `target`, image x horizontal, rolled by `roll` about the optical axis.
fn look_at(pos: Vector3<f64>, target: Vector3<f64>, roll: f64) -> Isometry3<f64> {
    let z = (target - pos).normalize();
    let x = z.cross(&Vector3::z()).normalize();
    let y = z.cross(&x);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let q = UnitQuaternion::from_rotation_matrix(&r)
        * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll);
    Isometry3::from_parts(Translation3::from(pos), q)
}

/// The random part of one view (uniforms and normals), drawn once; [`ViewDraw::view`] maps it to a camera
/// pose for a given view spread.
#[derive(Clone, Copy, Debug)]
struct ViewDraw {
    azimuth: f64,
    elevation: f64,
    distance: f64,
    aim: [f64; 2],
    aim_z: f64,
    roll: f64,
}

impl ViewDraw {
    fn draw(r: &mut Rng) -> Self {
        ViewDraw {
            azimuth: r.next_f64(),
            elevation: r.next_f64(),
            distance: r.next_f64(),
            aim: [r.normal(), r.normal()],
            aim_z: r.next_f64(),
            roll: r.uniform(-1.0, 1.0),
        }
    }

    /// `T_world_cam` of view `k` of a robot standing on side `phi` (radians, azimuth of its base around the
    /// table), for view spread `s` in 0–1. At `s = 1` the views use the configured ranges in full and swing
    /// ±145° around the workspace centre; as `s` falls they close in on the robot's own side: azimuths within
    /// ±(25° + 120°·s), aim points shifted toward the robot by (1 − s)·0.9 of the table's inscribed radius,
    /// elevations moved toward 80–89° (looking down) and distances toward the near end of the range.
    fn view(&self, cfg: &SimConfig, phi: f64, s: f64, k: usize) -> Isometry3<f64> {
        let lerp = |a: f64, b: f64| a + (b - a) * s;
        let swing = (25.0 + 120.0 * s).to_radians();
        let ws = cfg.scene.workspace_radius_m;
        let inscribed = 0.5 * cfg.scene.table_size_m[0].min(cfg.scene.table_size_m[1]);
        let shift = (1.0 - s) * 0.9 * inscribed;
        let [e0, e1] = cfg.view_elevation_deg;
        let (e0, e1) = (lerp(e0.max(80.0), e0), lerp(89.0, e1));
        let [d0, d1] = cfg.view_distance_m;
        let d1 = d0 + (d1 - d0) * (0.2 + 0.8 * s);
        let side = Vector3::new(phi.cos(), phi.sin(), 0.0);
        let aim_r = (ws * 1.1).max(shift).max(0.03);
        let n = cfg.frames as f64;
        let a = phi + swing * (2.0 * (k as f64 + self.azimuth) / n - 1.0);
        let e = (e0 + (e1 - e0) * self.elevation).to_radians();
        let d = d0 + (d1 - d0) * self.distance;
        let mut aim = side * shift + Vector3::new(0.05 * self.aim[0], 0.05 * self.aim[1], 0.0);
        let r = aim.xy().norm();
        if r > aim_r {
            aim *= aim_r / r;
        }
        aim.z = 0.06 * self.aim_z;
        let pos = aim + d * Vector3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin());
        look_at(pos, aim, self.roll * cfg.view_roll_deg.to_radians())
    }
}

/// The view spread in 0–1 whose shared fraction (mean of both robots') is closest to `target`, by bisection
/// on `shared_at` (which grows with the spread, up to noise); returns it with its shared fractions.
fn solve_spread(target: f64, shared_at: impl Fn(f64) -> Vec<f64>) -> (f64, Vec<f64>) {
    let mean = |f: &[f64]| f.iter().sum::<f64>() / f.len().max(1) as f64;
    let mut best = (1.0, shared_at(1.0));
    let consider = |s: f64, f: Vec<f64>, best: &mut (f64, Vec<f64>)| {
        if (mean(&f) - target).abs() < (mean(&best.1) - target).abs() {
            *best = (s, f);
        }
    };
    if mean(&best.1) <= target {
        return best;
    }
    let f0 = shared_at(0.0);
    let m0 = mean(&f0);
    consider(0.0, f0, &mut best);
    if m0 >= target {
        return best;
    }
    let (mut lo, mut hi) = (0.0, 1.0);
    for _ in 0..8 {
        let mid = 0.5 * (lo + hi);
        let f = shared_at(mid);
        let m = mean(&f);
        consider(mid, f, &mut best);
        if (m - target).abs() < 0.01 {
            break;
        }
        if m < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    best
}

impl SimCell {
    /// Makes the cell: the scene, the base layout, each robot's hand-eye and flange poses (no rendering).
    /// Same config (seed included), same cell.
    pub fn generate(cfg: &SimConfig) -> Result<Self> {
        cfg.validate()?;
        let seed = cfg.seed;
        let scene_seed = Rng::stream(seed, 2).next_u64();
        let scene = Scene::random(&cfg.scene, scene_seed)?;
        let mut camera = SimCamera::d435(cfg.resolution);
        camera.intrinsics.depth_scale = cfg.depth_scale;
        camera.max_depth_m = camera.max_depth_m.min(cfg.depth_scale * u16::MAX as f64);
        let mut layout = Rng::stream(seed, 1);
        let az_jit = cfg.base_azimuth_jitter_deg.to_radians();
        let n = cfg.robot_names.len();
        // The reference at 180°, the others evenly round the table (two robots: facing each other).
        let az_jit = if n > 2 {
            az_jit.min(0.25 * 2.0 * PI / n as f64)
        } else {
            az_jit
        };
        let phis: Vec<f64> = std::iter::once(PI)
            .chain((1..n).map(|i| {
                let nominal = PI + 2.0 * PI * i as f64 / n as f64;
                let nominal = if nominal >= 2.0 * PI {
                    nominal - 2.0 * PI
                } else {
                    nominal
                };
                nominal + layout.uniform(-az_jit, az_jit)
            }))
            .collect();
        let yaw_range = cfg.base_yaw_range_deg.to_radians();
        let width = ((cfg.frames.max(1) - 1).to_string().len()).max(3);
        let mut robots = Vec::with_capacity(n);
        let mut layouts = Vec::with_capacity(n);
        for (i, &phi) in phis.iter().enumerate() {
            let r =
                cfg.base_distance_m / 2.0 + layout.uniform(-0.5, 0.5) * cfg.base_distance_jitter_m;
            let z = layout.uniform(cfg.base_height_m[0], cfg.base_height_m[1]);
            let yaw = phi + PI + layout.uniform(-yaw_range, yaw_range);
            let tilt_axis = layout.uniform(0.0, 2.0 * PI);
            let tilt = layout.uniform(0.0, cfg.base_tilt_deg.to_radians());
            let mut rot = rot_z(yaw);
            if !cfg.bases_level {
                let axis = nalgebra::Unit::new_normalize(Vector3::new(
                    tilt_axis.cos(),
                    tilt_axis.sin(),
                    0.0,
                ));
                rot = UnitQuaternion::from_axis_angle(&axis, tilt) * rot;
            }
            let t_world_base =
                Isometry3::from_parts(Translation3::new(r * phi.cos(), r * phi.sin(), z), rot);

            let mut he = Rng::stream(seed, 10 + i as u64);
            let o = cfg.hand_eye_offset_m;
            let tilt = cfg.hand_eye_tilt_deg.to_radians();
            let t_ee_cam = Isometry3::from_parts(
                Translation3::new(he.uniform(-o, o), he.uniform(-o, o), he.uniform(0.03, 0.12)),
                rot_z(he.uniform(-PI, PI))
                    * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), he.uniform(-tilt, tilt))
                    * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), he.uniform(-tilt, tilt)),
            );
            let t_ee_cam = as_read_back_hand_eye(&t_ee_cam)?;

            // The random part of each view; where the views go also depends on the spread chosen below.
            let mut pr = Rng::stream(seed, 20 + i as u64);
            let draws: Vec<ViewDraw> = (0..cfg.frames).map(|_| ViewDraw::draw(&mut pr)).collect();
            robots.push(SimRobot {
                name: cfg.robot_names[i].clone(),
                t_world_base,
                t_ee_cam,
                camera: camera.clone(),
                poses: Vec::new(),
            });
            layouts.push((phi, draws));
        }
        // Choose the view spread whose shared fraction is closest to the requested overlap, then write the
        // poses as they read back from the KUKA pose file.
        let views_at = |s: f64| -> Vec<Vec<Isometry3<f64>>> {
            layouts
                .iter()
                .map(|(phi, draws)| {
                    draws
                        .iter()
                        .enumerate()
                        .map(|(k, d)| d.view(cfg, *phi, s, k))
                        .collect()
                })
                .collect()
        };
        let shared_at = |s: f64| {
            let v = views_at(s);
            let sets: Vec<&[Isometry3<f64>]> = v.iter().map(|x| x.as_slice()).collect();
            shared_fractions(&scene, &camera, &sets, &SharedConfig::default())
        };
        let (spread, shared) = solve_spread(cfg.overlap, shared_at);
        let views = views_at(spread);
        for (robot, views) in robots.iter_mut().zip(views) {
            let t_base_world = robot.t_world_base.inverse();
            let t_cam_ee = robot.t_ee_cam.inverse();
            robot.poses = views
                .iter()
                .enumerate()
                .map(|(k, t_world_cam)| {
                    Ok(PoseRecord {
                        frame: format!("{k:0width$}"),
                        pose: as_read_back_kuka(&(t_base_world * t_world_cam * t_cam_ee))?,
                        line: 0,
                    })
                })
                .collect::<Result<_>>()?;
        }
        Ok(SimCell {
            config: cfg.clone(),
            noise: cfg.noise_model(),
            scene,
            robots,
            view_spread: spread,
            shared,
        })
    }

    /// The true `T_base1_base2` (maps the second robot's base coordinates into the reference robot's base).
    pub fn t_base1_base2(&self) -> Isometry3<f64> {
        self.robots[0].t_world_base.inverse() * self.robots[1].t_world_base
    }

    /// `T_base1_world`: the table (world) frame in the reference robot's base.
    pub fn t_base1_world(&self) -> Isometry3<f64> {
        self.robots[0].t_world_base.inverse()
    }

    /// The seed of frame `k` of robot `robot` (noise and jitter).
    pub fn frame_seed(&self, robot: usize, k: usize) -> u64 {
        Rng::stream(self.config.seed, 1000 + ((robot as u64) << 32) + k as u64).next_u64()
    }

    /// Renders frame `k` of robot `robot` (depth after noise, and colour if the config asks for it).
    pub fn render(&self, robot: usize, k: usize) -> Result<RenderedFrame> {
        let r = &self.robots[robot];
        render_frame(
            &self.scene,
            &r.camera,
            &r.t_world_cam(k),
            &self.noise,
            self.frame_seed(robot, k),
            self.config.color,
        )
    }

    /// Renders every frame of a robot (in parallel).
    pub fn render_robot(&self, robot: usize) -> Result<Vec<RenderedFrame>> {
        (0..self.robots[robot].poses.len())
            .into_par_iter()
            .map(|k| self.render(robot, k))
            .collect()
    }

    /// The workspace box in the reference base frame (metres): the axis-aligned box, in that frame, around the
    /// region of the table holding the objects (workspace radius + 5 cm) from 2 cm below the table top to
    /// 5 cm above the tallest object, rounded outward to millimetres.
    pub fn workspace_base1(&self) -> CropBox {
        let r = self.config.scene.workspace_radius_m + 0.05;
        let top = self
            .scene
            .objects_bounds()
            .map(|(_, hi)| hi[2])
            .unwrap_or(0.1)
            + 0.05;
        let t = self.t_base1_world();
        let mut lo = [f64::MAX; 3];
        let mut hi = [f64::MIN; 3];
        for c in 0..8 {
            let p = Point3::new(
                if c & 1 == 0 { -r } else { r },
                if c & 2 == 0 { -r } else { r },
                if c & 4 == 0 { -0.02 } else { top },
            );
            let q = t * p;
            for k in 0..3 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        CropBox {
            min: lo.map(|v| (v * 1000.0).floor() / 1000.0),
            max: hi.map(|v| (v * 1000.0).ceil() / 1000.0),
        }
    }

    /// The `cell.toml` manifest: both robots with the conventional layout (KUKA `poses.csv`,
    /// `intrinsics.json`, inline hand-eye, `depth/{frame}.png`, `color/{frame}.png`) and a `[priors]` table:
    /// `bases_level`, `base_distance_m` (rounded to 0.1 m) and `workspace` (see [`SimCell::workspace_base1`]).
    pub fn manifest(&self) -> CellManifest {
        let mut m = CellManifest::new(&self.robots[0].name);
        for r in &self.robots {
            let mut e = RobotEntry::standard(&r.name, r.t_ee_cam);
            if self.config.color {
                e.color = Some(format!("{}/color/{FRAME_PLACEHOLDER}.png", r.name));
            }
            m.robots.push(e);
        }
        let mut priors = toml::Table::new();
        priors.insert("bases_level".into(), self.config.bases_level.into());
        let dist = self.t_base1_base2().translation.vector.norm();
        priors.insert(
            "base_distance_m".into(),
            ((dist * 10.0).round() / 10.0).into(),
        );
        let ws = self.workspace_base1();
        priors.insert(
            "workspace".into(),
            toml::Value::Array(
                ws.min
                    .iter()
                    .chain(ws.max.iter())
                    .map(|&v| toml::Value::Float(v))
                    .collect(),
            ),
        );
        m.extra.insert("priors".into(), toml::Value::Table(priors));
        if let Some(b) = &self.scene.board {
            m.extra.insert("board".into(), b.manifest_table());
        }
        if let Some(k) = &self.scene.markers {
            m.extra.insert("markers".into(), k.manifest_table());
        }
        m
    }

    /// The ground truth: `T_base1_base2`, and every other true transform and setting (see `docs/simulate.md`).
    pub fn ground_truth(&self) -> GroundTruth {
        use serde_json::{json, Value};
        let nested = |t: &Isometry3<f64>| serde_json::to_value(isometry_to_nested(t)).unwrap();
        let t_b1_w = self.t_base1_world();
        let robots: Vec<Value> = self
            .robots
            .iter()
            .map(|r| {
                json!({
                    "name": r.name,
                    "T_ee_cam": nested(&r.t_ee_cam),
                    "T_base1_base": nested(&(t_b1_w * r.t_world_base)),
                    "T_world_base": nested(&r.t_world_base),
                    "camera": r.camera,
                })
            })
            .collect();
        let objects: Vec<Value> = self
            .scene
            .objects
            .iter()
            .map(|o| {
                json!({
                    "shape": o.shape,
                    "T_base1_object": nested(&(t_b1_w * o.t_world_object)),
                    "T_world_object": nested(&o.t_world_object),
                })
            })
            .collect();
        let ws = self.workspace_base1();
        let mut extra = serde_json::Map::new();
        extra.insert("format".into(), json!("depthcal-sim/1"));
        extra.insert("reference".into(), json!(self.robots[0].name));
        extra.insert("other".into(), json!(self.robots[1].name));
        extra.insert("robots".into(), Value::Array(robots));
        extra.insert(
            "table".into(),
            json!({
                "T_base1_table": nested(&t_b1_w),
                "size_m": self.scene.table_size_m,
                "floor_below_m": self.scene.floor_below_m,
            }),
        );
        extra.insert("objects".into(), Value::Array(objects));
        extra.insert(
            "workspace_base1".into(),
            json!([ws.min[0], ws.min[1], ws.min[2], ws.max[0], ws.max[1], ws.max[2]]),
        );
        let mut shared: serde_json::Map<String, Value> = self
            .robots
            .iter()
            .zip(&self.shared)
            .map(|(r, f)| (r.name.clone(), json!(f)))
            .collect();
        shared.insert("view_spread".into(), json!(self.view_spread));
        extra.insert("shared_fraction".into(), Value::Object(shared));
        if let Some(b) = &self.scene.board {
            // The board pose in the world and in each robot's base (T_base_board = T_world_base⁻¹ · T_world_board).
            let in_bases: serde_json::Map<String, Value> = self
                .robots
                .iter()
                .map(|r| {
                    (
                        r.name.clone(),
                        nested(&(r.t_world_base.inverse() * b.t_world_board)),
                    )
                })
                .collect();
            // The board's own fields (`type`, then cols, rows, square_m or the ChArUco keys), then its poses.
            let mut entry = serde_json::to_value(b.board).unwrap_or_else(|_| json!({}));
            if let Some(o) = entry.as_object_mut() {
                o.insert("T_world_board".into(), json!(nested(&b.t_world_board)));
                o.insert(
                    "T_base1_board".into(),
                    json!(nested(&(t_b1_w * b.t_world_board))),
                );
                o.insert("T_base_board".into(), Value::Object(in_bases));
            }
            extra.insert("board".into(), entry);
        }
        if let Some(k) = &self.scene.markers {
            // Each marker's pose in the world, in base1 and in each robot's base.
            let list: Vec<Value> = k
                .markers
                .iter()
                .map(|m| {
                    let in_bases: serde_json::Map<String, Value> = self
                        .robots
                        .iter()
                        .map(|r| {
                            (
                                r.name.clone(),
                                nested(&(r.t_world_base.inverse() * m.t_world_marker)),
                            )
                        })
                        .collect();
                    json!({"id": m.id,
                           "T_world_marker": nested(&m.t_world_marker),
                           "T_base1_marker": nested(&(t_b1_w * m.t_world_marker)),
                           "T_base_marker": in_bases})
                })
                .collect();
            extra.insert(
                "markers".into(),
                json!({"dictionary": k.manifest_table().get("dictionary").and_then(|d| d.as_str()),
                       "size_m": k.config.size_m, "markers": list}),
            );
        }
        extra.insert("seed".into(), json!(self.config.seed));
        extra.insert("noise".into(), serde_json::to_value(&self.noise).unwrap());
        extra.insert(
            "settings".into(),
            serde_json::to_value(&self.config).unwrap(),
        );
        GroundTruth {
            t_base1_base2: Some(self.t_base1_base2()),
            extra,
        }
    }

    /// Writes the dataset into `dir` (created if missing; existing files of the same names are replaced, each
    /// atomically): per robot `poses.csv`, `intrinsics.json`, `depth/*.png` (and `color/*.png`), then
    /// `ground_truth.json` and last `cell.toml`. Frames are rendered in parallel; `progress` is called with the
    /// number of frames done after each one. The bytes depend only on the config, not on the thread count.
    pub fn write(
        &self,
        dir: impl AsRef<Path>,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<WriteStats> {
        let dir = dir.as_ref();
        let mkdir = |p: &Path| std::fs::create_dir_all(p).map_err(|e| Error::io(p, e));
        mkdir(dir)?;
        let manifest = self.manifest();
        let mut files = Vec::new();
        for (r, e) in self.robots.iter().zip(&manifest.robots) {
            mkdir(&dir.join(&r.name).join("depth"))?;
            if self.config.color {
                mkdir(&dir.join(&r.name).join("color"))?;
            }
            let p = dir.join(&e.poses);
            write_poses(&p, &r.poses, PoseFormat::Kuka)?;
            files.push(p);
            let p = dir.join(&e.intrinsics);
            r.camera.intrinsics.write_json_file(&p)?;
            files.push(p);
        }
        let jobs: Vec<(usize, usize)> = (0..self.robots.len())
            .flat_map(|i| (0..self.robots[i].poses.len()).map(move |k| (i, k)))
            .collect();
        let done = AtomicUsize::new(0);
        let written: Vec<Vec<std::path::PathBuf>> = jobs
            .par_iter()
            .map(|&(i, k)| -> Result<Vec<std::path::PathBuf>> {
                let f = self.render(i, k)?;
                let e = &manifest.robots[i];
                let id = &self.robots[i].poses[k].frame;
                let mut out = Vec::with_capacity(2);
                let p = crate::cell::frame_path(dir, &e.depth, id);
                write_depth_png(&p, &f.depth)?;
                out.push(p);
                if let (Some(c), Some(pat)) = (&f.color, &e.color) {
                    let p = crate::cell::frame_path(dir, pat, id);
                    write_rgb_png(&p, c)?;
                    out.push(p);
                }
                progress(done.fetch_add(1, Ordering::Relaxed) + 1);
                Ok(out)
            })
            .collect::<Result<_>>()?;
        files.extend(written.into_iter().flatten());
        self.ground_truth().write(dir)?;
        files.push(dir.join(crate::cell::GROUND_TRUTH_FILE));
        manifest.write(dir)?;
        files.push(dir.join(crate::cell::MANIFEST_FILE));
        let mut bytes = 0;
        for f in &files {
            bytes += std::fs::metadata(f).map_err(|e| Error::io(f, e))?.len();
        }
        Ok(WriteStats {
            files: files.len(),
            bytes,
            frames: jobs.len(),
        })
    }
}

/// Makes the cell of `cfg` and writes it into `dir` (see [`SimCell::write`]).
pub fn simulate_cell(
    cfg: &SimConfig,
    dir: impl AsRef<Path>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<(SimCell, WriteStats)> {
    let cell = SimCell::generate(cfg)?;
    let stats = cell.write(dir, progress)?;
    Ok((cell, stats))
}
