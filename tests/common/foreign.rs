//! An independent generator of two-robot depth cells ("foreign" cells), written without any of depthcal's
//! simulator or rendering code: its own scene of analytic primitives, its own pinhole ray caster, its own
//! RealSense-like noise, its own random numbers, and a `cell.toml` written by hand as text.
//!
//! Conventions (as in `../shared/design/ARCHITECTURE.md`): `T_a_b` maps `b` coordinates into `a`; the world
//! frame of the generator is robot 1's base (`base1`); the camera optical frame has `z` forward, `x` right,
//! `y` down; pixel centres sit at integer pixel coordinates (OpenCV / librealsense), so pixel `(u, v)`
//! looks along `((u - ppx) / fx, (v - ppy) / fy, 1)`; depth images hold the `z` coordinate (not the range)
//! in units of `depth_scale` metres, 0 = no data. KUKA poses are `x, y, z` mm and `A, B, C` degrees with
//! `R = Rz(A)·Ry(B)·Rx(C)` — converted here by this file's own code, not depthcal's.
//!
//! The cell: two robots facing each other across a table (robot 2 yawed about 180° relative to robot 1,
//! bases 1.0-1.6 m apart, a small height difference, optionally tilted), each with a camera on its flange
//! (`T_ee_cam` about 6 cm off the flange and turned ~90° about the flange `z`, plus a small random rotation),
//! taking views from a hemisphere above the table on its own side. Scenes ([`SceneKind`]): a table with
//! primitives, a cluttered shelf with boxes against a back wall, and a bare table larger than the views
//! (degenerate). Everything is deterministic per seed.
//!
//! [`generate`] writes `cell.toml`, `<robot>/poses.csv` (KUKA), `<robot>/intrinsics.json` (rs2 fields),
//! `<robot>/depth/NNNN.png` (16-bit) and `ground_truth.json` (`T_base1_base2` as 4 rows of 4, plus the
//! generator's own keys). [`Sabotage`] writes wrong inputs on purpose (the depth is always rendered with
//! the true values).
#![allow(dead_code)]

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

// ---------------------------------------------------------------------------------------------------------
// Random numbers (splitmix64 + Box-Muller), deterministic per seed.

/// A small deterministic random number generator (splitmix64).
#[derive(Clone, Debug)]
pub struct Rand(u64);

impl Rand {
    /// A generator for `seed`.
    pub fn new(seed: u64) -> Self {
        Rand(seed ^ 0x5851_f42d_4c95_7f2d)
    }
    /// A generator for a tuple of keys (seed, robot, view, row, ...).
    pub fn keyed(keys: &[u64]) -> Self {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        for &k in keys {
            h = (h ^ k).wrapping_mul(0x1000_0000_01b3);
            h = mix(h);
        }
        Rand(h)
    }
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        mix(self.0)
    }
    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    /// Uniform in `[a, b)`.
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.uniform()
    }
    /// A standard normal deviate (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
    /// A uniformly distributed unit vector.
    pub fn unit_vector(&mut self) -> Vector3<f64> {
        loop {
            let v = Vector3::new(self.normal(), self.normal(), self.normal());
            let n = v.norm();
            if n > 1e-9 {
                return v / n;
            }
        }
    }
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

// ---------------------------------------------------------------------------------------------------------
// KUKA XYZ-ABC, this file's own implementation of R = Rz(A)·Ry(B)·Rx(C).

/// `R = Rz(a)·Ry(b)·Rx(c)`, angles in radians, written out element by element.
pub fn kuka_rotation(a: f64, b: f64, c: f64) -> Matrix3<f64> {
    let (sa, ca) = a.sin_cos();
    let (sb, cb) = b.sin_cos();
    let (sc, cc) = c.sin_cos();
    Matrix3::new(
        ca * cb,
        ca * sb * sc - sa * cc,
        ca * sb * cc + sa * sc,
        sa * cb,
        sa * sb * sc + ca * cc,
        sa * sb * cc - ca * sc,
        -sb,
        cb * sc,
        cb * cc,
    )
}

/// Writes flange poses as a KUKA pose file (`frame,x_mm,…,c_deg`).
fn write_poses(path: &Path, ids: &[String], pose: impl Fn(usize) -> Isometry3<f64>) {
    super::write_kuka_pose_file(path, ids, None, |i| {
        let a = kuka_from_isometry(&pose(i));
        depthcal::geometry::pose::KukaPose {
            x_mm: a[0],
            y_mm: a[1],
            z_mm: a[2],
            a_deg: a[3],
            b_deg: a[4],
            c_deg: a[5],
        }
    })
}

/// `[x_mm, y_mm, z_mm, a_deg, b_deg, c_deg]` of a pose in metres.
pub fn kuka_from_isometry(t: &Isometry3<f64>) -> [f64; 6] {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let b = (-r[(2, 0)]).atan2((r[(0, 0)].powi(2) + r[(1, 0)].powi(2)).sqrt());
    let (a, c) = if b.cos() < 1e-9 {
        ((-r[(0, 1)]).atan2(r[(1, 1)]), 0.0)
    } else {
        (r[(1, 0)].atan2(r[(0, 0)]), r[(2, 1)].atan2(r[(2, 2)]))
    };
    let p = t.translation.vector * 1e3;
    [
        p.x,
        p.y,
        p.z,
        a.to_degrees(),
        b.to_degrees(),
        c.to_degrees(),
    ]
}

/// The pose (metres) of KUKA values `[x_mm, y_mm, z_mm, a_deg, b_deg, c_deg]`.
pub fn isometry_from_kuka(k: &[f64; 6]) -> Isometry3<f64> {
    let r = kuka_rotation(k[3].to_radians(), k[4].to_radians(), k[5].to_radians());
    Isometry3::from_parts(
        Translation3::new(k[0] * 1e-3, k[1] * 1e-3, k[2] * 1e-3),
        UnitQuaternion::from_matrix(&r),
    )
}

/// The 16 row-major entries of a pose's 4x4 matrix.
pub fn rows16(t: &Isometry3<f64>) -> [f64; 16] {
    let m = t.to_homogeneous();
    let mut out = [0.0; 16];
    for r in 0..4 {
        for c in 0..4 {
            out[r * 4 + c] = m[(r, c)];
        }
    }
    out
}

fn rows4(t: &Isometry3<f64>) -> serde_json::Value {
    let m = rows16(t);
    serde_json::json!([&m[0..4], &m[4..8], &m[8..12], &m[12..16]])
}

fn rot(axis: Vector3<f64>, angle: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle)
}

// ---------------------------------------------------------------------------------------------------------
// Scene: analytic primitives with closed-form ray intersections.

/// One analytic primitive (world = base1 coordinates, metres).
#[derive(Clone, Debug)]
pub enum Prim {
    /// The plane `n · x = k` (n unit), seen from both sides.
    Plane { n: Vector3<f64>, k: f64 },
    /// An oriented box: centre, world-from-local rotation, half extents.
    Cuboid {
        c: Vector3<f64>,
        r: Matrix3<f64>,
        h: Vector3<f64>,
    },
    /// A sphere.
    Sphere { c: Vector3<f64>, r: f64 },
    /// A vertical (world z) capped cylinder: bottom centre, radius, height.
    Cylinder { c: Vector3<f64>, r: f64, h: f64 },
}

const EPS: f64 = 1e-9;

impl Prim {
    /// An axis-aligned box resting on `z_base` with yaw `yaw` about z.
    fn resting_box(x: f64, y: f64, z_base: f64, h: Vector3<f64>, yaw: f64) -> Prim {
        Prim::Cuboid {
            c: Vector3::new(x, y, z_base + h.z),
            r: Rotation3::from_axis_angle(&Vector3::z_axis(), yaw).into_inner(),
            h,
        }
    }

    /// The nearest hit `t > 0` along `o + t·d` and the surface normal there (unit, any side).
    pub fn hit(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        match self {
            Prim::Plane { n, k } => {
                let nd = n.dot(d);
                if nd.abs() < EPS {
                    return None;
                }
                let t = (k - n.dot(o)) / nd;
                (t > EPS).then_some((t, *n))
            }
            Prim::Cuboid { c, r, h } => {
                let ol = r.tr_mul(&(o - c));
                let dl = r.tr_mul(d);
                let (mut tmin, mut tmax, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0usize);
                for i in 0..3 {
                    if dl[i].abs() < EPS {
                        if ol[i].abs() > h[i] {
                            return None;
                        }
                        continue;
                    }
                    let inv = 1.0 / dl[i];
                    let (mut t1, mut t2) = ((-h[i] - ol[i]) * inv, (h[i] - ol[i]) * inv);
                    if t1 > t2 {
                        std::mem::swap(&mut t1, &mut t2);
                    }
                    if t1 > tmin {
                        tmin = t1;
                        axis = i;
                    }
                    tmax = tmax.min(t2);
                    if tmin > tmax {
                        return None;
                    }
                }
                if tmin <= EPS {
                    return None; // behind or inside
                }
                let mut nl = Vector3::zeros();
                nl[axis] = -dl[axis].signum();
                Some((tmin, r * nl))
            }
            Prim::Sphere { c, r } => {
                let oc = o - c;
                let a = d.dot(d);
                let b = oc.dot(d);
                let cc = oc.dot(&oc) - r * r;
                let disc = b * b - a * cc;
                if disc < 0.0 {
                    return None;
                }
                let t = (-b - disc.sqrt()) / a;
                (t > EPS).then(|| (t, (o + d * t - c) / *r))
            }
            Prim::Cylinder { c, r, h } => {
                let mut best: Option<(f64, Vector3<f64>)> = None;
                let (ox, oy) = (o.x - c.x, o.y - c.y);
                let a = d.x * d.x + d.y * d.y;
                if a > EPS {
                    let b = ox * d.x + oy * d.y;
                    let cc = ox * ox + oy * oy - r * r;
                    let disc = b * b - a * cc;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / a;
                        let z = o.z + t * d.z;
                        if t > EPS && z >= c.z && z <= c.z + h {
                            best = Some((t, Vector3::new(ox + t * d.x, oy + t * d.y, 0.0) / *r));
                        }
                    }
                }
                if d.z.abs() > EPS {
                    for (zc, nz) in [(c.z + h, 1.0), (c.z, -1.0)] {
                        let t = (zc - o.z) / d.z;
                        let (px, py) = (ox + t * d.x, oy + t * d.y);
                        if t > EPS
                            && px * px + py * py <= r * r
                            && best.is_none_or(|(bt, _)| t < bt)
                        {
                            best = Some((t, Vector3::new(0.0, 0.0, nz)));
                        }
                    }
                }
                best
            }
        }
    }

    /// A bounding sphere (centre, radius); `None` for unbounded planes.
    fn bounds(&self) -> Option<(Vector3<f64>, f64)> {
        match self {
            Prim::Plane { .. } => None,
            Prim::Cuboid { c, h, .. } => Some((*c, h.norm())),
            Prim::Sphere { c, r } => Some((*c, *r)),
            Prim::Cylinder { c, r, h } => Some((
                c + Vector3::new(0.0, 0.0, h / 2.0),
                (r * r + h * h / 4.0).sqrt(),
            )),
        }
    }
}

/// The scene compositions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    /// A table with boxes (axis-aligned and turned), spheres and vertical cylinders on it, its legs and
    /// the floor.
    TablePrimitives,
    /// A shelf unit against a back wall on the table's far edge, boxes on its boards and clutter in front
    /// (one box leaning), a cylinder.
    ClutteredShelf,
    /// A table top larger than the views with nothing on it: rotation about its normal and in-plane
    /// translation are unconstrained (degenerate on purpose).
    BareTable,
}

impl SceneKind {
    /// A short name for tables and file names.
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::TablePrimitives => "table",
            SceneKind::ClutteredShelf => "shelf",
            SceneKind::BareTable => "bare",
        }
    }
}

/// Where robot 2 stands relative to robot 1 and the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// Across the table, yawed about 180° (the original cell).
    Facing,
    /// At 90° round the table: robot 2's base beside the table's long side, yawed about 90°.
    RightAngle,
    /// Both on the same side of the table, 0.8-1.2 m apart, the same yaw (± `yaw_jitter_deg`).
    SideBySide,
}

/// What is under and around the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ground {
    /// A table on legs and a floor 0.7-0.8 m below its top (the original cell).
    TableOnLegs,
    /// No table: the objects stand on a wide floor at the table's height.
    FloorOnly,
    /// The table on legs and nothing else in range (the original `floor: false`).
    Nothing,
}

/// The table top's outline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableShape {
    /// A rectangle (the original cell).
    Rectangle,
    /// A disc on one central column.
    Round,
    /// An L of two boxes (not symmetric under a half turn about the vertical).
    Irregular,
}

/// The objects on the table (the table scene only).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Objects {
    /// Boxes (axis-aligned and turned), spheres and vertical cylinders (the original cell).
    Asymmetric,
    /// Only spheres and vertical cylinders, each symmetric about the vertical; their arrangement is random.
    SymmetricOnly,
}

/// Where each robot's cameras look.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Aim {
    /// Near the table centre (the original cell).
    Shared,
    /// At points 0.25-0.35 m from the table centre toward the robot's own base, from a narrower and
    /// steeper arc (±35° azimuth, 60-80° elevation, 0.5-0.7 m away): about 50-70 % shared.
    OwnSide,
    /// Farther toward the own side (±25°, 68-83°, 0.4-0.55 m), the distance bisected on coarse renders
    /// until the robots share a drawn 17-28 % (the achieved figure is in `shared_fraction`).
    LowOverlap,
}

macro_rules! enum_names {
    ($t:ty { $($v:ident => $n:literal),* $(,)? }) => {
        impl $t {
            /// A short name for tables, file names and `ground_truth.json`.
            pub fn name(self) -> &'static str {
                match self { $(<$t>::$v => $n),* }
            }
        }
    };
}
enum_names!(Layout { Facing => "facing", RightAngle => "right_angle", SideBySide => "side_by_side" });
enum_names!(Ground { TableOnLegs => "table_on_legs", FloorOnly => "floor_only", Nothing => "nothing" });
enum_names!(TableShape { Rectangle => "rectangle", Round => "round", Irregular => "irregular" });
enum_names!(Objects { Asymmetric => "asymmetric", SymmetricOnly => "symmetric_only" });
enum_names!(Aim { Shared => "shared", OwnSide => "own_side", LowOverlap => "low_overlap" });

/// The table top's outline for placing objects on it (`None` in [`Placer`]: the placement box is on it).
#[derive(Clone, Copy, Debug)]
enum Top {
    /// A disc: centre, radius.
    Disc(f64, f64, f64),
    /// A union of two axis-aligned rectangles `(x0, x1, y0, y1)`.
    Rects([(f64, f64, f64, f64); 2]),
}

impl Top {
    /// Whether the footprint disc at `(x, y)` with radius `r` lies on the top.
    fn holds(&self, x: f64, y: f64, r: f64) -> bool {
        match *self {
            Top::Disc(cx, cy, rr) => (x - cx).hypot(y - cy) + r < rr - 0.01,
            Top::Rects(rs) => rs.iter().any(|&(x0, x1, y0, y1)| {
                x - r > x0 + 0.01 && x + r < x1 - 0.01 && y - r > y0 + 0.01 && y + r < y1 - 0.01
            }),
        }
    }
}

/// The options of [`build_scene`] beyond the scene kind (all default to the original cell).
#[derive(Clone, Copy, Debug)]
struct SceneOptions {
    back_wall: bool,
    ground: Ground,
    table_shape: TableShape,
    objects: Objects,
    /// Seed of the draws the new options need (the original draws stay as they were).
    seed: u64,
}

/// The primitives of a scene, split in always-tested ones and a cluster with a common bounding box.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Planes, the table, its legs: tested by every ray.
    pub big: Vec<Prim>,
    /// The objects: tested only by rays through `cluster_box`.
    pub objects: Vec<Prim>,
    spheres: Vec<(Vector3<f64>, f64)>,
    cluster_min: Vector3<f64>,
    cluster_max: Vector3<f64>,
    /// Table top height (world z).
    pub table_top: f64,
    /// Table centre (world xy).
    pub table_centre: Vector3<f64>,
    /// The back wall's plane `y = back_wall_y`, if any.
    pub back_wall_y: Option<f64>,
    /// The floor's height (world z), also when there is no floor (where it would be).
    pub floor_z: f64,
}

impl Scene {
    fn new(big: Vec<Prim>, objects: Vec<Prim>, table_top: f64, table_centre: Vector3<f64>) -> Self {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        let spheres: Vec<(Vector3<f64>, f64)> = objects
            .iter()
            .map(|p| p.bounds().expect("objects are bounded"))
            .collect();
        for &(c, r) in &spheres {
            lo = lo.inf(&(c - Vector3::repeat(r)));
            hi = hi.sup(&(c + Vector3::repeat(r)));
        }
        Scene {
            big,
            objects,
            spheres,
            cluster_min: lo,
            cluster_max: hi,
            table_top,
            table_centre,
            back_wall_y: None,
            floor_z: table_top - 0.75,
        }
    }

    fn ray_meets_cluster(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> bool {
        if self.objects.is_empty() {
            return false;
        }
        let (mut tmin, mut tmax) = (0.0f64, f64::INFINITY);
        for i in 0..3 {
            if d[i].abs() < EPS {
                if o[i] < self.cluster_min[i] || o[i] > self.cluster_max[i] {
                    return false;
                }
                continue;
            }
            let inv = 1.0 / d[i];
            let (mut t1, mut t2) = (
                (self.cluster_min[i] - o[i]) * inv,
                (self.cluster_max[i] - o[i]) * inv,
            );
            if t1 > t2 {
                std::mem::swap(&mut t1, &mut t2);
            }
            tmin = tmin.max(t1);
            tmax = tmax.min(t2);
        }
        tmin <= tmax
    }

    /// The nearest hit along the ray: `(t, unit normal)`.
    pub fn cast(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        let mut best: Option<(f64, Vector3<f64>)> = None;
        fn consider(
            best: &mut Option<(f64, Vector3<f64>)>,
            p: &Prim,
            o: &Vector3<f64>,
            d: &Vector3<f64>,
        ) {
            if let Some((t, n)) = p.hit(o, d) {
                if best.is_none_or(|(bt, _)| t < bt) {
                    *best = Some((t, n));
                }
            }
        }
        for p in &self.big {
            consider(&mut best, p, o, d);
        }
        if self.ray_meets_cluster(o, d) {
            let a = d.dot(d);
            for (p, (c, r)) in self.objects.iter().zip(&self.spheres) {
                // Bounding sphere first: skip a miss, or one wholly behind the nearest hit so far.
                let oc = o - c;
                let b = oc.dot(d);
                let disc = b * b - a * (oc.dot(&oc) - r * r);
                if disc < 0.0 || best.is_some_and(|(bt, _)| (-b - disc.sqrt()) / a > bt) {
                    continue;
                }
                consider(&mut best, p, o, d);
            }
        }
        best
    }
}

/// Places footprints (circles) on the table region without overlaps; `None` after many tries.
struct Placer {
    taken: Vec<(f64, f64, f64)>,
    x: (f64, f64),
    y: (f64, f64),
    /// The table top when it does not cover the whole placement box.
    top: Option<Top>,
}

impl Placer {
    fn place(&mut self, rng: &mut Rand, radius: f64) -> Option<(f64, f64)> {
        for _ in 0..200 {
            let x = rng.range(self.x.0 + radius, self.x.1 - radius);
            let y = rng.range(self.y.0 + radius, self.y.1 - radius);
            if self
                .taken
                .iter()
                .all(|&(tx, ty, tr)| (tx - x).hypot(ty - y) > tr + radius + 0.015)
                && self.top.is_none_or(|t| t.holds(x, y, radius))
            {
                self.taken.push((x, y, radius));
                return Some((x, y));
            }
        }
        None
    }
}

/// Builds the scene of `kind` for a table whose top's centre is `centre` (world), `length` along the line
/// between the bases (world x) and `width` across.
fn build_scene(
    kind: SceneKind,
    rng: &mut Rand,
    centre: Vector3<f64>,
    length: f64,
    width: f64,
    opt: SceneOptions,
) -> Scene {
    let top = centre.z;
    let thickness = 0.04;
    let floor = top - rng.range(0.70, 0.80);
    let (cx, cy) = (centre.x, centre.y);
    // The new options draw from their own generator so the original cells stay as they were.
    let mut xrng = Rand::keyed(&[opt.seed, 0x7ab1e]);
    let mut big = Vec::new();
    match opt.ground {
        Ground::TableOnLegs => big.push(Prim::Plane {
            n: Vector3::z(),
            k: floor,
        }),
        Ground::FloorOnly => big.push(Prim::Plane {
            n: Vector3::z(),
            k: top,
        }),
        Ground::Nothing => {}
    }
    let floor_z = if opt.ground == Ground::FloorOnly {
        top
    } else {
        floor
    };
    let mut objects = Vec::new();
    let slab = |x0: f64, x1: f64, y0: f64, y1: f64| Prim::Cuboid {
        c: Vector3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, top - thickness / 2.0),
        r: Matrix3::identity(),
        h: Vector3::new((x1 - x0) / 2.0, (y1 - y0) / 2.0, thickness / 2.0),
    };
    let table = |l: f64, w: f64| Prim::Cuboid {
        c: Vector3::new(cx, cy, top - thickness / 2.0),
        r: Matrix3::identity(),
        h: Vector3::new(l / 2.0, w / 2.0, thickness / 2.0),
    };
    let leg = |x: f64, y: f64| Prim::Cylinder {
        c: Vector3::new(x, y, floor),
        r: 0.025,
        h: top - thickness - floor,
    };
    if kind == SceneKind::BareTable {
        // Larger than any view: no edge, no floor in sight.
        big.push(table(5.0, 5.0));
        let mut scene = Scene::new(big, objects, top, centre);
        scene.floor_z = floor_z;
        return scene;
    }
    let mut top_outline = None;
    match (opt.ground, opt.table_shape) {
        (Ground::FloorOnly, _) => {}
        (_, TableShape::Rectangle) => {
            big.push(table(length, width));
            for (sx, sy) in [(-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)] {
                objects.push(leg(
                    cx + sx * (length / 2.0 - 0.06),
                    cy + sy * (width / 2.0 - 0.06),
                ));
            }
        }
        (_, TableShape::Round) => {
            let r = 0.5 * length.min(width) + xrng.range(0.0, 0.08);
            big.push(Prim::Cylinder {
                c: Vector3::new(cx, cy, top - thickness),
                r,
                h: thickness,
            });
            objects.push(Prim::Cylinder {
                c: Vector3::new(cx, cy, floor),
                r: 0.05,
                h: top - thickness - floor,
            });
            top_outline = Some(Top::Disc(cx, cy, r));
        }
        (_, TableShape::Irregular) => {
            // An L: the full length over part of the width on one side, and an extension over part of
            // the length on one end of the other side.
            let sx = if xrng.uniform() < 0.5 { -1.0 } else { 1.0 };
            let sy = if xrng.uniform() < 0.5 { -1.0 } else { 1.0 };
            let wa = width * xrng.range(0.55, 0.65);
            let la = length * xrng.range(0.45, 0.6);
            let (x0, x1) = (cx - length / 2.0, cx + length / 2.0);
            let y_edge = cy - sy * width / 2.0;
            let y_split = y_edge + sy * wa;
            let y_far = cy + sy * width / 2.0;
            let main = (x0, x1, y_edge.min(y_split), y_edge.max(y_split));
            let (e0, e1) = if sx > 0.0 {
                (x1 - la, x1)
            } else {
                (x0, x0 + la)
            };
            let ext = (e0, e1, y_split.min(y_far), y_split.max(y_far));
            for &(a0, a1, b0, b1) in &[main, ext] {
                big.push(slab(a0, a1, b0, b1));
                for (px, py) in [(a0, b0), (a0, b1), (a1, b0), (a1, b1)] {
                    objects.push(leg(
                        px + 0.06 * (a0 + a1 - 2.0 * px).signum(),
                        py + 0.06 * (b0 + b1 - 2.0 * py).signum(),
                    ));
                }
            }
            top_outline = Some(Top::Rects([main, ext]));
        }
    }
    let back = cy + width / 2.0; // the far edge (world +y)
    let mut wall = None;
    if opt.back_wall || kind == SceneKind::ClutteredShelf {
        big.push(Prim::Plane {
            n: Vector3::y(),
            k: back + 0.04,
        });
        wall = Some(back + 0.04);
    }
    let half_x = (length / 2.0 - 0.1).min(0.32);
    match kind {
        SceneKind::TablePrimitives => {
            let mut placer = Placer {
                taken: Vec::new(),
                x: (cx - half_x, cx + half_x),
                y: (cy - 0.3, cy + 0.3),
                top: top_outline,
            };
            for i in 0..4 {
                if opt.objects == Objects::SymmetricOnly {
                    // A sphere or a vertical cylinder in place of each box.
                    let r = rng.range(0.03, 0.065);
                    let h = rng.range(0.06, 0.25);
                    if let Some((x, y)) = placer.place(rng, r) {
                        objects.push(if i % 2 == 0 {
                            Prim::Sphere {
                                c: Vector3::new(x, y, top + r),
                                r,
                            }
                        } else {
                            Prim::Cylinder {
                                c: Vector3::new(x, y, top),
                                r,
                                h,
                            }
                        });
                    }
                    continue;
                }
                let h = Vector3::new(
                    rng.range(0.03, 0.09),
                    rng.range(0.03, 0.09),
                    rng.range(0.02, 0.09),
                );
                let yaw = if i < 2 { 0.0 } else { rng.range(0.2, 1.2) };
                if let Some((x, y)) = placer.place(rng, h.xy().norm()) {
                    objects.push(Prim::resting_box(x, y, top, h, yaw));
                }
            }
            for _ in 0..2 {
                let r = rng.range(0.035, 0.07);
                if let Some((x, y)) = placer.place(rng, r) {
                    objects.push(Prim::Sphere {
                        c: Vector3::new(x, y, top + r),
                        r,
                    });
                }
            }
            for _ in 0..2 {
                let r = rng.range(0.025, 0.055);
                let h = rng.range(0.06, 0.25);
                if let Some((x, y)) = placer.place(rng, r) {
                    objects.push(Prim::Cylinder {
                        c: Vector3::new(x, y, top),
                        r,
                        h,
                    });
                }
            }
        }
        SceneKind::ClutteredShelf => {
            // The shelf unit: two side boards, a middle and a top board, 0.6-0.7 m wide, 0.25 m deep.
            let w = rng.range(0.3, 0.36);
            let depth = 0.12;
            let height = rng.range(0.4, 0.5);
            let yc = back - depth;
            let sx = cx + rng.range(-0.05, 0.05);
            for s in [-1.0, 1.0] {
                objects.push(Prim::resting_box(
                    sx + s * (w - 0.01),
                    yc,
                    top,
                    Vector3::new(0.01, depth, height / 2.0),
                    0.0,
                ));
            }
            let mid = top + height * rng.range(0.45, 0.55);
            for z in [mid, top + height - 0.02] {
                objects.push(Prim::resting_box(
                    sx,
                    yc,
                    z,
                    Vector3::new(w - 0.02, depth, 0.01),
                    0.0,
                ));
            }
            // Boxes on the middle board and on the table under it.
            for (zb, n) in [(mid + 0.02, 2), (top, 2)] {
                let mut x = sx - w + 0.03;
                for _ in 0..n {
                    let h = Vector3::new(
                        rng.range(0.03, 0.07),
                        rng.range(0.03, 0.08),
                        rng.range(0.03, 0.08),
                    );
                    x += h.x;
                    objects.push(Prim::resting_box(
                        x,
                        yc - depth + h.y + rng.range(0.0, 0.03),
                        zb,
                        h,
                        rng.range(-0.2, 0.2),
                    ));
                    x += h.x + rng.range(0.03, 0.12);
                }
            }
            // Clutter in front of the shelf.
            let mut placer = Placer {
                taken: Vec::new(),
                x: (cx - half_x, cx + half_x),
                y: (cy - 0.3, yc - depth - 0.02),
                top: top_outline,
            };
            for i in 0..6 {
                let h = Vector3::new(
                    rng.range(0.025, 0.08),
                    rng.range(0.025, 0.08),
                    rng.range(0.02, 0.1),
                );
                let Some((x, y)) = placer.place(rng, h.xy().norm()) else {
                    continue;
                };
                if i == 0 {
                    // A box leaning over by ~20° about its x axis, resting on an edge.
                    let tilt = rng.range(0.3, 0.4);
                    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), rng.range(-1.0, 1.0))
                        * Rotation3::from_axis_angle(&Vector3::x_axis(), tilt);
                    let m = r.into_inner();
                    let lowest: f64 = (0..3).map(|j| m[(2, j)].abs() * h[j]).sum();
                    objects.push(Prim::Cuboid {
                        c: Vector3::new(x, y, top + lowest),
                        r: r.into_inner(),
                        h,
                    });
                } else {
                    objects.push(Prim::resting_box(x, y, top, h, rng.range(-0.8, 0.8)));
                }
            }
            let r = rng.range(0.03, 0.05);
            if let Some((x, y)) = placer.place(rng, r) {
                objects.push(Prim::Cylinder {
                    c: Vector3::new(x, y, top),
                    r,
                    h: rng.range(0.1, 0.2),
                });
            }
        }
        SceneKind::BareTable => unreachable!(),
    }
    let mut scene = Scene::new(big, objects, top, centre);
    scene.back_wall_y = wall;
    scene.floor_z = floor_z;
    scene
}

// ---------------------------------------------------------------------------------------------------------
// Camera, noise, rendering.

/// Pinhole intrinsics (no distortion).
#[derive(Clone, Copy, Debug)]
pub struct Pinhole {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub ppx: f64,
    pub ppy: f64,
}

/// RealSense-D435-like depth noise.
#[derive(Clone, Copy, Debug)]
pub struct Noise {
    /// Axial σ = `axial_a_m + axial_b_per_m · z²` (metres).
    pub axial_a_m: f64,
    /// See `axial_a_m`.
    pub axial_b_per_m: f64,
    /// Probability that a pixel has no data.
    pub dropout: f64,
    /// Pixels whose surface is seen at more than this incidence (degrees) have no data.
    pub max_incidence_deg: f64,
    /// Depth range with data, metres.
    pub min_z_m: f64,
    pub max_z_m: f64,
}

impl Default for Noise {
    fn default() -> Self {
        Noise {
            axial_a_m: 0.5e-3,
            axial_b_per_m: 1.5e-3,
            dropout: 0.01,
            max_incidence_deg: 82.0,
            min_z_m: 0.16,
            max_z_m: 4.0,
        }
    }
}

/// One rendered view: the noisy quantised depth and the noise-free `z` (0 = nothing).
pub struct View {
    pub t_base1_cam: Isometry3<f64>,
    pub depth: Vec<u16>,
    pub clean: Vec<f32>,
}

/// The depth artefacts beyond per-pixel noise and dropout.
#[derive(Clone, Copy, Debug, Default)]
struct Artefacts {
    flying_pixels: bool,
    holes: bool,
}

#[allow(clippy::too_many_arguments)]
fn render(
    scene: &Scene,
    k: &Pinhole,
    t_w_cam: &Isometry3<f64>,
    noise: &Noise,
    depth_scale: f64,
    keys: [u64; 3],
    artefacts: Artefacts,
) -> View {
    let (w, h) = (k.width as usize, k.height as usize);
    let mut depth = vec![0u16; w * h];
    let mut clean = vec![0f32; w * h];
    let rmat = t_w_cam.rotation.to_rotation_matrix().into_inner();
    let o = t_w_cam.translation.vector;
    let cos_max = noise.max_incidence_deg.to_radians().cos();
    depth
        .par_chunks_mut(w)
        .zip(clean.par_chunks_mut(w))
        .enumerate()
        .for_each(|(v, (drow, crow))| {
            let mut rng = Rand::keyed(&[keys[0], keys[1], keys[2], v as u64]);
            let y = (v as f64 - k.ppy) / k.fy;
            for u in 0..w {
                let x = (u as f64 - k.ppx) / k.fx;
                let d = rmat * Vector3::new(x, y, 1.0); // t along d is the camera z
                let Some((z, n)) = scene.cast(&o, &d) else {
                    continue;
                };
                crow[u] = z as f32;
                let noise_draw = rng.normal();
                let drop = rng.uniform() < noise.dropout;
                if drop || z < noise.min_z_m || z > noise.max_z_m {
                    continue;
                }
                if n.dot(&d).abs() / d.norm() < cos_max {
                    continue;
                }
                let sigma = noise.axial_a_m + noise.axial_b_per_m * z * z;
                let q = ((z + sigma * noise_draw) / depth_scale).round();
                if (1.0..=65535.0).contains(&q) {
                    drow[u] = q as u16;
                }
            }
        });
    if artefacts.flying_pixels {
        add_flying_pixels(&mut depth, &clean, w, h, noise, depth_scale, keys);
    }
    if artefacts.holes {
        add_holes(&mut depth, w, h, keys);
    }
    View {
        t_base1_cam: *t_w_cam,
        depth,
        clean,
    }
}

/// Whether the noise-free depth jumps within the 3x3 neighbourhood of `(u, v)`: `(near, far)` if so.
pub fn depth_edge(clean: &[f32], w: usize, h: usize, u: usize, v: usize) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for y in v.saturating_sub(1)..(v + 2).min(h) {
        for x in u.saturating_sub(1)..(u + 2).min(w) {
            let z = clean[y * w + x] as f64;
            if z > 0.0 {
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
    }
    (hi > 0.0 && hi - lo > 0.03 + 0.03 * lo).then_some((lo, hi))
}

/// RealSense-like edge artefacts: on the 1-2 pixel band along each depth discontinuity, about 60 % of the
/// pixels get a depth between the near and the far surface.
fn add_flying_pixels(
    depth: &mut [u16],
    clean: &[f32],
    w: usize,
    h: usize,
    noise: &Noise,
    depth_scale: f64,
    keys: [u64; 3],
) {
    let mut rng = Rand::keyed(&[keys[0], keys[1], keys[2], 0xf1f1]);
    for v in 0..h {
        for u in 0..w {
            if clean[v * w + u] <= 0.0 {
                continue;
            }
            let Some((lo, hi)) = depth_edge(clean, w, h, u, v) else {
                continue;
            };
            let (pick, f) = (rng.uniform(), rng.uniform());
            if pick > 0.6 {
                continue;
            }
            let z = lo + (hi - lo) * f;
            let q = (z / depth_scale).round();
            if z >= noise.min_z_m && z <= noise.max_z_m && (1.0..=65535.0).contains(&q) {
                depth[v * w + u] = q as u16;
            }
        }
    }
}

/// Dropout in blobs: ellipses of a few to tens of pixels (about one per 2500 pixels).
fn add_holes(depth: &mut [u16], w: usize, h: usize, keys: [u64; 3]) {
    let mut rng = Rand::keyed(&[keys[0], keys[1], keys[2], 0x401e]);
    let n = ((w * h) as f64 / 2500.0 * rng.range(0.5, 1.5)) as usize;
    for _ in 0..n {
        let (cu, cv) = (rng.range(0.0, w as f64), rng.range(0.0, h as f64));
        let (ru, rv) = (rng.range(1.0, 4.5), rng.range(1.0, 4.5));
        let (u0, u1) = (
            (cu - ru).floor().max(0.0) as usize,
            ((cu + ru).ceil() as usize).min(w),
        );
        let (v0, v1) = (
            (cv - rv).floor().max(0.0) as usize,
            ((cv + rv).ceil() as usize).min(h),
        );
        for v in v0..v1 {
            for u in u0..u1 {
                let (du, dv) = ((u as f64 - cu) / ru, (v as f64 - cv) / rv);
                if du * du + dv * dv <= 1.0 {
                    depth[v * w + u] = 0;
                }
            }
        }
    }
}

/// Writes a 16-bit greyscale PNG with the `png` crate.
pub fn write_png16(path: &Path, width: u32, height: u32, data: &[u16]) {
    let mut bytes = Vec::with_capacity(data.len() * 2);
    for d in data {
        bytes.extend_from_slice(&d.to_be_bytes());
    }
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = png::Encoder::new(f, width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    enc.set_compression(png::Compression::Fast);
    let mut wr = enc.write_header().unwrap();
    wr.write_image_data(&bytes).unwrap();
    wr.finish().unwrap();
}

/// Writes an 8-bit visualisation of a depth image (near = bright, no data = black) for eyeballing.
pub fn write_preview_png(path: &Path, width: u32, height: u32, data: &[u16]) {
    let valid: Vec<u16> = data.iter().copied().filter(|&d| d > 0).collect();
    let lo = valid.iter().copied().min().unwrap_or(0) as f64;
    let hi = valid.iter().copied().max().unwrap_or(1) as f64;
    let bytes: Vec<u8> = data
        .iter()
        .map(|&d| {
            if d == 0 {
                0
            } else {
                (255.0 - 230.0 * (d as f64 - lo) / (hi - lo).max(1.0)) as u8
            }
        })
        .collect();
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = png::Encoder::new(f, width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().unwrap();
    wr.write_image_data(&bytes).unwrap();
    wr.finish().unwrap();
}

/// Writes a contact sheet of depth images (8-bit, 4 thumbnails a row, one block of rows per image list,
/// thumbnails about 160 pixels wide, a grey line between blocks).
pub fn write_contact_sheet(path: &Path, width: u32, height: u32, blocks: &[Vec<&[u16]>]) {
    let step = width.div_ceil(160).max(1) as usize;
    let (tw, th) = (width as usize / step, height as usize / step);
    let cols = 4;
    let rows_per: Vec<usize> = blocks.iter().map(|b| b.len().div_ceil(cols)).collect();
    let sheet_w = cols * (tw + 2);
    let sheet_h: usize = rows_per.iter().map(|r| r * (th + 2) + 4).sum();
    let mut img = vec![0u8; sheet_w * sheet_h];
    let mut y0 = 0;
    for (b, block) in blocks.iter().enumerate() {
        for (i, data) in block.iter().enumerate() {
            let lo = data.iter().copied().filter(|&d| d > 0).min().unwrap_or(0) as f64;
            let hi = data.iter().copied().max().unwrap_or(1) as f64;
            let (ox, oy) = ((i % cols) * (tw + 2), y0 + (i / cols) * (th + 2));
            for y in 0..th {
                for x in 0..tw {
                    // Depth (near = bright) plus relief shading from the depth gradient.
                    let at =
                        |xx: usize, yy: usize| data[yy * step * width as usize + xx * step] as f64;
                    let d = at(x, y);
                    img[(oy + y) * sheet_w + ox + x] = if d == 0.0 {
                        0
                    } else {
                        let (x1, y1) = ((x + 1).min(tw - 1), (y + 1).min(th - 1));
                        let (dx, dy) = (at(x1, y), at(x, y1));
                        let g = if dx > 0.0 && dy > 0.0 {
                            ((dx - d) + (dy - d)) / d
                        } else {
                            0.0
                        };
                        (200.0 - 120.0 * (d - lo) / (hi - lo).max(1.0) - 2000.0 * g)
                            .clamp(1.0, 255.0) as u8
                    };
                }
            }
        }
        y0 += rows_per[b] * (th + 2) + 4;
        for x in 0..sheet_w {
            img[(y0 - 2) * sheet_w + x] = 128;
        }
    }
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut enc = png::Encoder::new(f, sheet_w as u32, sheet_h as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let mut wr = enc.write_header().unwrap();
    wr.write_image_data(&img).unwrap();
    wr.finish().unwrap();
}

// ---------------------------------------------------------------------------------------------------------
// The cell.

/// Wrong inputs written on purpose (the depth is rendered with the true values).
#[derive(Clone, Debug, Default)]
pub struct Sabotage {
    /// `(robot index 0|1, factor)`: the intrinsics file says `fy · factor`.
    pub fy_scale: Option<(usize, f64)>,
    /// `(robot, mm, deg)`: the hand-eye in `cell.toml` is off by `mm` along a random direction and `deg`
    /// about a random axis.
    pub hand_eye: Option<(usize, f64, f64)>,
    /// `(robot, frame index, mm, deg)`: that row of the pose file is off by `mm` along a random direction
    /// and `deg` about a random axis.
    pub pose_row: Option<(usize, usize, f64, f64)>,
    /// The priors table is spelled `[prior]` (a typo) instead of `[priors]`; implies writing priors.
    pub priors_typo: bool,
}

impl Sabotage {
    /// True when nothing is sabotaged.
    pub fn is_none(&self) -> bool {
        self.fy_scale.is_none()
            && self.hand_eye.is_none()
            && self.pose_row.is_none()
            && !self.priors_typo
    }
}

/// What to generate.
#[derive(Clone, Debug)]
pub struct ForeignConfig {
    /// Seed of everything random.
    pub seed: u64,
    /// Views (frames) per robot.
    pub views: usize,
    /// Image size (intrinsics scale with the width).
    pub width: u32,
    pub height: u32,
    /// The scene composition.
    pub scene: SceneKind,
    /// Write `[priors] bases_level = true` and a rough `base_distance_m` (default: no priors table).
    pub with_priors: bool,
    /// Distance between the base origins in xy, metres (`None`: random in 1.0-1.6).
    pub base_separation_m: Option<f64>,
    /// Height of base 2 above base 1, metres (`None`: random in ±0.05).
    pub height_difference_m: Option<f64>,
    /// Tilt of robot 2's base about a random horizontal axis, degrees (0 = upright).
    pub tilt_deg: f64,
    /// Yaw of robot 2 relative to robot 1 is 180° plus a random offset within ± this, degrees.
    pub yaw_jitter_deg: f64,
    /// Put a back wall behind the table (always there in the shelf scene).
    pub back_wall: bool,
    /// A floor 0.7-0.8 m below the table top (default true; without it the views see nothing beyond the
    /// table's edges).
    pub floor: bool,
    /// Metres per depth unit written in the intrinsics (0.001 or 0.0001).
    pub depth_scale: f64,
    /// Depth noise.
    pub noise: Noise,
    /// Robot names (reference first).
    pub names: [String; 2],
    /// Also write `preview/<robot>_<frame>.png` 8-bit visualisations.
    pub previews: bool,
    /// Wrong inputs on purpose.
    pub sabotage: Sabotage,
    /// Where robot 2 stands (default: facing robot 1 across the table).
    pub layout: Layout,
    /// What is under and around the table (default: a table on legs and a floor; with `floor: false` a
    /// `TableOnLegs` ground means `Nothing`, as the field meant before this one existed).
    pub ground: Ground,
    /// The table top's outline (default: a rectangle).
    pub table_shape: TableShape,
    /// The table is as wide as it is long (default: 0.8-1.1 m wide).
    pub square_table: bool,
    /// The objects on the table (default: boxes, spheres and cylinders).
    pub objects: Objects,
    /// The idle robot stands in candle pose (straight up) at its base while the other robot captures:
    /// each robot's depth shows the other robot's arm, which is no part of the static scene.
    pub other_robot_in_view: bool,
    /// A 0.36 m x 0.36 m box under each robot's base from the floor up to the base (static scene).
    pub pedestal: bool,
    /// Where the cameras look (default: near the table centre).
    pub aim: Aim,
    /// More robots beside the table's long sides (at most 2: the third at its -y side, the fourth at its +y
    /// side, each facing the table, upright, yaw ± `yaw_jitter_deg`), named `arm_c`, `arm_d`; only with the
    /// `Facing` layout. Each robot's views then show every other robot's arm when `other_robot_in_view`.
    pub extra_robots: usize,
    /// RealSense-like flying pixels on 1-2 pixel bands along depth discontinuities.
    pub flying_pixels: bool,
    /// Dropout in blobs of a few to tens of pixels (besides the single-pixel dropout).
    pub holes: bool,
    /// The poses written to `poses.csv` are off by this many mm (1-σ per axis) and this x 0.05 degrees
    /// (1-σ per axis); the depth is rendered with the true poses. 0 = exact poses.
    pub pose_noise_mm: f64,
}

impl ForeignConfig {
    /// The ground in effect (`floor: false` turns the default `TableOnLegs` into `Nothing`).
    pub fn effective_ground(&self) -> Ground {
        if !self.floor && self.ground == Ground::TableOnLegs {
            Ground::Nothing
        } else {
            self.ground
        }
    }
}

impl Default for ForeignConfig {
    fn default() -> Self {
        ForeignConfig {
            seed: 1,
            views: 12,
            width: 640,
            height: 480,
            scene: SceneKind::TablePrimitives,
            with_priors: false,
            base_separation_m: None,
            height_difference_m: None,
            tilt_deg: 0.0,
            yaw_jitter_deg: 10.0,
            back_wall: false,
            floor: true,
            depth_scale: 0.001,
            noise: Noise::default(),
            names: ["arm_a".into(), "arm_b".into()],
            previews: false,
            sabotage: Sabotage::default(),
            layout: Layout::Facing,
            ground: Ground::TableOnLegs,
            table_shape: TableShape::Rectangle,
            square_table: false,
            objects: Objects::Asymmetric,
            other_robot_in_view: false,
            pedestal: false,
            aim: Aim::Shared,
            extra_robots: 0,
            flying_pixels: false,
            holes: false,
            pose_noise_mm: 0.0,
        }
    }
}

/// What [`generate`] wrote and measured.
#[derive(Clone, Debug)]
pub struct ForeignCell {
    /// The cell directory.
    pub dir: PathBuf,
    /// The true `T_base1_base2`.
    pub truth: Isometry3<f64>,
    /// Every robot's true `T_base1_base` (the reference's is the identity), in robot order.
    pub truths: Vec<Isometry3<f64>>,
    /// The robots' names, in order.
    pub names: Vec<String>,
    /// The true hand-eyes `T_ee_cam` of every robot.
    pub t_ee_cam: Vec<Isometry3<f64>>,
    /// The true flange poses `T_base_ee` of every robot, per frame.
    pub t_base_ee: Vec<Vec<Isometry3<f64>>>,
    /// Per robot: the fraction of its valid pixels (sampled) that some view of another robot also saw.
    pub shared_fraction: Vec<f64>,
    /// Per robot: the fraction of pixels with data.
    pub valid_fraction: Vec<f64>,
    /// Table top height and table centre in base1 (metres).
    pub table_top: f64,
    pub table_centre: Vector3<f64>,
    /// Seconds spent ray casting all views.
    pub render_s: f64,
    /// Seconds for the whole generation (incl. PNG writing and the shared-fraction measurement).
    pub total_s: f64,
    /// The configuration it was generated from.
    pub config: ForeignConfig,
}

/// A camera at `eye` looking at `target`, image `y` down towards world `-z`, rolled by `roll` about its axis.
fn look_at(eye: Vector3<f64>, target: Vector3<f64>, roll: f64) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let down = -Vector3::z();
    let y = (down - z * down.dot(&z)).normalize();
    let x = y.cross(&z);
    let r = Matrix3::from_columns(&[x, y, z]);
    let q =
        UnitQuaternion::from_matrix(&r) * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll);
    Isometry3::from_parts(Translation3::from(eye), q)
}

/// Camera poses in world (base1) for the robot whose base sits at `base_xy`: a hemisphere above the table
/// on that robot's side, every view looking at a point near the table centre.
/// The shape of a robot's camera arc: the target's shift off the table centre (world), the azimuth half
/// range and the elevation range (degrees).
#[derive(Clone, Copy, Debug)]
struct Arc {
    shift: Vector3<f64>,
    az_half_deg: f64,
    el_min_deg: f64,
    el_span_deg: f64,
    dist_m: (f64, f64),
}

impl Arc {
    /// The original arc: at the table centre, ±65° azimuth, 48-72° elevation.
    const SHARED: Arc = Arc {
        shift: Vector3::new(0.0, 0.0, 0.0),
        az_half_deg: 65.0,
        el_min_deg: 48.0,
        el_span_deg: 24.0,
        dist_m: (0.55, 0.8),
    };
}

fn camera_arc(
    rng: &mut Rand,
    views: usize,
    scene: &Scene,
    base_xy: Vector3<f64>,
    arc: Arc,
) -> Vec<Isometry3<f64>> {
    let shift = arc.shift;
    let c = scene.table_centre;
    let toward_base = (base_xy - c).xy();
    let az0 = toward_base.y.atan2(toward_base.x);
    (0..views)
        .map(|i| {
            let f = if views > 1 {
                i as f64 / (views - 1) as f64
            } else {
                0.5
            };
            let az = az0
                + (-arc.az_half_deg + 2.0 * arc.az_half_deg * f + rng.range(-6.0, 6.0))
                    .to_radians();
            let el = (arc.el_min_deg
                + arc.el_span_deg * ((i as f64 * 0.618_034) % 1.0)
                + rng.range(-3.0, 3.0))
            .to_radians();
            let dist = rng.range(arc.dist_m.0, arc.dist_m.1);
            let target = Vector3::new(
                c.x + rng.range(-0.12, 0.12),
                c.y + rng.range(-0.12, 0.12),
                scene.table_top + rng.range(0.0, 0.08),
            ) + shift;
            let mut eye =
                target + dist * Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
            if let Some(wall) = scene.back_wall_y {
                if eye.y > wall - 0.3 {
                    // Behind or against the back wall: mirror to the open front side.
                    eye.y = 2.0 * target.y - eye.y;
                }
            }
            look_at(eye, target, rng.range(-15.0, 15.0).to_radians())
        })
        .collect()
}

/// The primitives of an iiwa-like arm in candle pose (straight up) standing at `base` (world): a base
/// drum, links of 0.07-0.1 m radius with ball joints, a flange at 1.2-1.3 m.
fn candle_arm(base: Vector3<f64>, rng: &mut Rand) -> Vec<Prim> {
    let s = rng.range(1.2, 1.3) / 1.26;
    let r = rng.range(0.07, 0.1);
    let at = |z: f64| base + Vector3::new(0.0, 0.0, z * s);
    vec![
        Prim::Cylinder {
            c: at(0.0),
            r: r + 0.02,
            h: 0.16 * s,
        },
        Prim::Cylinder {
            c: at(0.16),
            r,
            h: 0.2 * s,
        },
        Prim::Sphere {
            c: at(0.36),
            r: r + 0.01,
        },
        Prim::Cylinder {
            c: at(0.36),
            r: r * 0.95,
            h: 0.42 * s,
        },
        Prim::Sphere { c: at(0.78), r },
        Prim::Cylinder {
            c: at(0.78),
            r: r * 0.85,
            h: 0.4 * s,
        },
        Prim::Sphere {
            c: at(1.18),
            r: r * 0.8,
        },
        Prim::Cylinder {
            c: at(1.18),
            r: 0.045,
            h: 0.08 * s,
        },
    ]
}

fn perturbed(t: &Isometry3<f64>, rng: &mut Rand, mm: f64, deg: f64) -> Isometry3<f64> {
    let dt = rng.unit_vector() * mm * 1e-3;
    let dr = rot(rng.unit_vector(), deg.to_radians());
    Isometry3::from_parts(
        Translation3::from(t.translation.vector + dt),
        dr * t.rotation,
    )
}

fn fmt_f(v: f64) -> String {
    // Debug formatting always has a decimal point or an exponent: a valid TOML float.
    format!("{v:?}")
}

/// Generates a cell into `dir` (created; an existing cell there is overwritten).
pub fn generate(dir: &Path, cfg: &ForeignConfig) -> ForeignCell {
    let start = std::time::Instant::now();
    let mut rng = Rand::keyed(&[cfg.seed, 0xce11]);
    // The new options draw from their own generator so the original cells stay as they were.
    let mut lrng = Rand::keyed(&[cfg.seed, 0x1a7e]);
    // Robot 2's base in base1.
    let sep = cfg.base_separation_m.unwrap_or_else(|| rng.range(1.0, 1.6));
    let lateral = rng.range(-0.1, 0.1);
    let dz = cfg
        .height_difference_m
        .unwrap_or_else(|| rng.range(-0.05, 0.05));
    let jitter = rng
        .range(-cfg.yaw_jitter_deg, cfg.yaw_jitter_deg)
        .to_radians();
    let tilt_axis_angle = rng.range(0.0, std::f64::consts::TAU);
    let tilt = rot(
        Vector3::new(tilt_axis_angle.cos(), tilt_axis_angle.sin(), 0.0),
        cfg.tilt_deg.to_radians(),
    );
    // The table: `length` along world x, `width` along world y.
    let top = rng.range(-0.08, 0.03);
    let width = rng.range(0.8, 1.1);
    let (base2, yaw, centre, length, width) = match cfg.layout {
        Layout::Facing => (
            Vector3::new(sep, lateral, dz),
            std::f64::consts::PI + jitter,
            Vector3::new(sep / 2.0, lateral / 2.0, top),
            (sep - 0.25).max(0.8),
            width,
        ),
        Layout::RightAngle => {
            // Robot 1 at the table's -x end as when facing, robot 2 beside its -y side looking along +y.
            let length = (sep - 0.25).max(0.8);
            let centre = Vector3::new(sep / 2.0, lateral / 2.0, top);
            let base2 = Vector3::new(
                centre.x + lrng.range(-0.1, 0.1),
                centre.y - width / 2.0 - lrng.range(0.12, 0.25),
                dz,
            );
            (
                base2,
                std::f64::consts::FRAC_PI_2 + jitter,
                centre,
                length,
                width,
            )
        }
        Layout::SideBySide => {
            // Both at the table's -x side, robot 2 0.8-1.2 m along +y, the same yaw.
            let spacing = lrng.range(0.8, 1.2);
            let depth = lrng.range(0.8, 1.0);
            let base2 = Vector3::new(lateral, spacing, dz);
            let centre = Vector3::new(depth / 2.0 + lrng.range(0.1, 0.15), spacing / 2.0, top);
            (base2, jitter, centre, depth, spacing + lrng.range(0.3, 0.5))
        }
    };
    let width = if cfg.square_table { length } else { width };
    let truth = Isometry3::from_parts(
        Translation3::from(base2),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw) * tilt,
    );
    let mut scene = build_scene(
        cfg.scene,
        &mut rng,
        centre,
        length,
        width,
        SceneOptions {
            back_wall: cfg.back_wall,
            ground: cfg.effective_ground(),
            table_shape: cfg.table_shape,
            objects: cfg.objects,
            seed: cfg.seed,
        },
    );
    // More robots beside the long sides, from their own generator (the two-robot cells stay as they were).
    assert!(
        cfg.extra_robots <= 2 && (cfg.extra_robots == 0 || cfg.layout == Layout::Facing),
        "extra robots: at most 2, with the facing layout"
    );
    let mut truths = vec![Isometry3::identity(), truth];
    let mut yaws = vec![0.0, yaw];
    let mut names: Vec<String> = cfg.names.to_vec();
    let mut xrng = Rand::keyed(&[cfg.seed, 0x3b0b]);
    for e in 0..cfg.extra_robots {
        let side = if e == 0 { -1.0 } else { 1.0 };
        let pos = Vector3::new(
            centre.x + xrng.range(-0.1, 0.1),
            centre.y + side * (width / 2.0 + xrng.range(0.12, 0.25)),
            xrng.range(-0.05, 0.05),
        );
        let y = -side * std::f64::consts::FRAC_PI_2
            + xrng
                .range(-cfg.yaw_jitter_deg, cfg.yaw_jitter_deg)
                .to_radians();
        truths.push(Isometry3::from_parts(
            Translation3::from(pos),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), y),
        ));
        yaws.push(y);
        names.push(format!("arm_{}", (b'c' + e as u8) as char));
    }
    let n_robots = truths.len();
    let bases: Vec<Vector3<f64>> = truths.iter().map(|t| t.translation.vector).collect();
    if cfg.pedestal {
        // A box under each base, its table-side face 0.08 m in front of the base.
        for (k, b) in bases.iter().enumerate() {
            let height = b.z - scene.floor_z;
            if height < 0.02 {
                continue;
            }
            let to_table = (scene.table_centre - b).xy().normalize();
            let c = b.xy() - to_table * 0.1;
            let facing = yaws[k];
            scene.big.push(Prim::resting_box(
                c.x,
                c.y,
                scene.floor_z,
                Vector3::new(0.18, 0.18, height / 2.0),
                facing,
            ));
        }
    }
    // Per robot: the static scene, plus the other robots' arms in candle pose when they are in view.
    let scenes: Vec<Scene> = (0..n_robots)
        .map(|k| {
            let mut s = scene.clone();
            if cfg.other_robot_in_view {
                for j in (0..n_robots).filter(|&j| j != k) {
                    let mut arng = Rand::keyed(&[cfg.seed, 0xa4a, j as u64]);
                    s.big.extend(candle_arm(bases[j], &mut arng));
                }
            }
            s
        })
        .collect();
    // Cameras and hand-eyes.
    let to_base: Vec<Isometry3<f64>> = truths.iter().map(|t| t.inverse()).collect(); // T_base_k_base1
    let mut intr = Vec::new();
    let mut hand_eye = Vec::new();
    let mut cams = Vec::new();
    let mut arcs = Vec::new();
    for (k, &base) in bases.iter().enumerate() {
        let w = cfg.width as f64;
        let fx = w * 0.6 * (1.0 + rng.range(-0.01, 0.01));
        intr.push(Pinhole {
            width: cfg.width,
            height: cfg.height,
            fx,
            fy: fx * (1.0 + rng.range(-0.003, 0.003)),
            ppx: (w - 1.0) / 2.0 + rng.range(-4.0, 4.0) * w / 640.0,
            ppy: (cfg.height as f64 - 1.0) / 2.0 + rng.range(-3.0, 3.0) * w / 640.0,
        });
        let extra = rot(rng.unit_vector(), rng.range(0.5, 3.0).to_radians());
        let q = UnitQuaternion::from_axis_angle(
            &Vector3::z_axis(),
            (90.0 + rng.range(-4.0, 4.0)).to_radians(),
        ) * extra;
        hand_eye.push(Isometry3::from_parts(
            Translation3::new(
                rng.range(0.05, 0.075),
                rng.range(-0.015, 0.015),
                rng.range(0.03, 0.06),
            ),
            q,
        ));
        // Aim off the table centre toward the own base (an own generator per robot for the distance).
        let mut arng = Rand::keyed(&[cfg.seed, 0xa1e, k as u64]);
        let toward = (base - scene.table_centre).xy().normalize();
        let toward = Vector3::new(toward.x, toward.y, 0.0);
        let arc = match cfg.aim {
            Aim::Shared => Arc::SHARED,
            Aim::OwnSide => Arc {
                shift: toward * arng.range(0.25, 0.35),
                az_half_deg: 35.0,
                el_min_deg: 60.0,
                el_span_deg: 20.0,
                dist_m: (0.5, 0.7),
            },
            // The distance is scaled below to reach the intended overlap.
            Aim::LowOverlap => Arc {
                shift: toward * arng.range(0.9, 1.1),
                az_half_deg: 25.0,
                el_min_deg: 68.0,
                el_span_deg: 15.0,
                dist_m: (0.4, 0.55),
            },
        };
        arcs.push((rng.clone(), base, arc));
        cams.push(camera_arc(&mut rng, cfg.views, &scene, base, arc));
    }
    if cfg.aim == Aim::LowOverlap {
        // Bisect the aim's distance from the table centre on coarse renders (1/8 of the size, no artefacts)
        // until the robots share a drawn 17-28 %: the overlap depends on the table and the objects too.
        let mut orng = Rand::keyed(&[cfg.seed, 0x10e7]);
        let target = orng.range(0.17, 0.28);
        let cams_at = |scale: f64| -> Vec<Vec<Isometry3<f64>>> {
            arcs.iter()
                .map(|(r, base, arc)| {
                    let arc = Arc {
                        shift: arc.shift * scale,
                        ..*arc
                    };
                    camera_arc(&mut r.clone(), cfg.views, &scene, *base, arc)
                })
                .collect()
        };
        let coarse: Vec<Pinhole> = intr
            .iter()
            .map(|k| Pinhole {
                width: (k.width / 8).max(8),
                height: (k.height / 8).max(6),
                fx: k.fx / 8.0,
                fy: k.fy / 8.0,
                ppx: (k.ppx + 0.5) / 8.0 - 0.5,
                ppy: (k.ppy + 0.5) / 8.0 - 0.5,
            })
            .collect();
        let clean_noise = Noise {
            dropout: 0.0,
            ..cfg.noise
        };
        let overlap_at = |scale: f64| -> f64 {
            let cs = cams_at(scale);
            let views: Vec<Vec<View>> = (0..n_robots)
                .map(|k| {
                    cs[k]
                        .iter()
                        .map(|t| {
                            render(
                                &scenes[k],
                                &coarse[k],
                                t,
                                &clean_noise,
                                cfg.depth_scale,
                                [cfg.seed, k as u64, 0],
                                Artefacts::default(),
                            )
                        })
                        .collect()
                })
                .collect();
            let (shared, _) = shared_and_valid(&views, &coarse, 1);
            shared.iter().sum::<f64>() / shared.len() as f64
        };
        let (mut lo, mut hi) = (0.2, 1.2);
        for _ in 0..7 {
            let mid = (lo + hi) / 2.0;
            if overlap_at(mid) > target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        cams = cams_at((lo + hi) / 2.0);
    }
    // Render.
    let t_render = std::time::Instant::now();
    let views: Vec<Vec<View>> = (0..n_robots)
        .map(|k| {
            cams[k]
                .iter()
                .enumerate()
                .map(|(i, t)| {
                    render(
                        &scenes[k],
                        &intr[k],
                        t,
                        &cfg.noise,
                        cfg.depth_scale,
                        [cfg.seed, k as u64, i as u64],
                        Artefacts {
                            flying_pixels: cfg.flying_pixels,
                            holes: cfg.holes,
                        },
                    )
                })
                .collect()
        })
        .collect();
    let render_s = t_render.elapsed().as_secs_f64();
    // Shared fraction and valid fraction.
    let (shared_fraction, valid_fraction) = shared_and_valid(&views, &intr, 6);
    // Files.
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let mut srng = Rand::keyed(&[cfg.seed, 0x5ab0]);
    let ids: Vec<String> = (0..cfg.views).map(|i| format!("{i:04}")).collect();
    let mut toml = String::new();
    writeln!(
        toml,
        "# Written by hand by the foreign cell generator (tests/common/foreign.rs)."
    )
    .unwrap();
    writeln!(toml, "format = \"depthcal-cell/1\"").unwrap();
    writeln!(toml, "reference = \"{}\"", cfg.names[0]).unwrap();
    let mut t_base_ee_all: Vec<Vec<Isometry3<f64>>> = vec![Vec::new(); n_robots];
    for k in 0..n_robots {
        let name = &names[k];
        std::fs::create_dir_all(dir.join(name).join("depth")).unwrap();
        if cfg.previews {
            std::fs::create_dir_all(dir.join("preview")).unwrap();
        }
        let kk = &intr[k];
        let mut fy_written = kk.fy;
        if let Some((r, f)) = cfg.sabotage.fy_scale {
            if r == k {
                fy_written *= f;
            }
        }
        let intr_json = serde_json::json!({
            "width": kk.width, "height": kk.height,
            "ppx": kk.ppx, "ppy": kk.ppy, "fx": kk.fx, "fy": fy_written,
            "model": "brown_conrady", "coeffs": [0.0, 0.0, 0.0, 0.0, 0.0],
            "depth_scale": cfg.depth_scale,
        });
        std::fs::write(
            dir.join(name).join("intrinsics.json"),
            serde_json::to_string_pretty(&intr_json).unwrap(),
        )
        .unwrap();
        // Flange poses: T_base_ee = T_base_cam · T_ee_cam⁻¹.
        let he_inv = hand_eye[k].inverse();
        let poses: Vec<Isometry3<f64>> = views[k]
            .iter()
            .map(|v| to_base[k] * v.t_base1_cam * he_inv)
            .collect();
        let mut written = poses.clone();
        if cfg.pose_noise_mm > 0.0 {
            let mut prng = Rand::keyed(&[cfg.seed, 0x905e, k as u64]);
            let (mm, deg) = (cfg.pose_noise_mm, cfg.pose_noise_mm * 0.05);
            for p in &mut written {
                let dt = Vector3::new(prng.normal(), prng.normal(), prng.normal()) * mm * 1e-3;
                let dr =
                    Vector3::new(prng.normal(), prng.normal(), prng.normal()) * deg.to_radians();
                *p = Isometry3::from_parts(
                    Translation3::from(p.translation.vector + dt),
                    UnitQuaternion::from_scaled_axis(dr) * p.rotation,
                );
            }
        }
        if cfg.pose_noise_mm > 0.0 {
            // For studies of the pose scatter: the true poses, and the true poses all moved by the mean of
            // the noise put in (left increments in the base frame), which is what a perfect per-frame
            // correction with a zero-mean gauge would leave.
            let incs: Vec<(Vector3<f64>, Vector3<f64>)> = written
                .iter()
                .zip(&poses)
                .map(|(w, p)| {
                    let e = w * p.inverse();
                    (e.rotation.scaled_axis(), e.translation.vector)
                })
                .collect();
            let m = incs.len().max(1) as f64;
            let mean = Isometry3::from_parts(
                Translation3::from(incs.iter().map(|i| i.1).sum::<Vector3<f64>>() / m),
                UnitQuaternion::from_scaled_axis(
                    incs.iter().map(|i| i.0).sum::<Vector3<f64>>() / m,
                ),
            );
            for (file, moved) in [
                ("poses_true.csv", None),
                ("poses_mean_noise.csv", Some(mean)),
            ] {
                write_poses(&dir.join(name).join(file), &ids, |i| {
                    moved.map_or(poses[i], |e| e * poses[i])
                });
            }
        }
        if let Some((r, frame, mm, deg)) = cfg.sabotage.pose_row {
            if r == k {
                written[frame] = perturbed(&written[frame], &mut srng, mm, deg);
            }
        }
        write_poses(&dir.join(name).join("poses.csv"), &ids, |i| written[i]);
        t_base_ee_all[k] = poses;
        for (i, v) in views[k].iter().enumerate() {
            write_png16(
                &dir.join(name).join("depth").join(format!("{}.png", ids[i])),
                kk.width,
                kk.height,
                &v.depth,
            );
            if cfg.previews {
                write_preview_png(
                    &dir.join("preview").join(format!("{name}_{}.png", ids[i])),
                    kk.width,
                    kk.height,
                    &v.depth,
                );
            }
        }
        let mut he = hand_eye[k];
        if let Some((r, mm, deg)) = cfg.sabotage.hand_eye {
            if r == k {
                he = perturbed(&he, &mut srng, mm, deg);
            }
        }
        let nums: Vec<String> = rows16(&he).iter().map(|&v| fmt_f(v)).collect();
        writeln!(toml).unwrap();
        writeln!(toml, "[[robot]]").unwrap();
        writeln!(toml, "name = \"{name}\"").unwrap();
        writeln!(toml, "poses = \"{name}/poses.csv\"").unwrap();
        writeln!(toml, "pose_format = \"kuka\"").unwrap();
        writeln!(toml, "intrinsics = \"{name}/intrinsics.json\"").unwrap();
        writeln!(toml, "hand_eye = [{}]", nums.join(", ")).unwrap();
        writeln!(toml, "depth = \"{name}/depth/{{frame}}.png\"").unwrap();
    }
    if cfg.previews {
        let blocks: Vec<Vec<&[u16]>> = views
            .iter()
            .map(|vs| vs.iter().map(|v| v.depth.as_slice()).collect())
            .collect();
        write_contact_sheet(
            &dir.join("preview").join("sheet.png"),
            cfg.width,
            cfg.height,
            &blocks,
        );
    }
    if cfg.with_priors || cfg.sabotage.priors_typo {
        let table = if cfg.sabotage.priors_typo {
            "prior"
        } else {
            "priors"
        };
        writeln!(toml).unwrap();
        writeln!(toml, "[{table}]").unwrap();
        writeln!(toml, "bases_level = true").unwrap();
        writeln!(
            toml,
            "base_distance_m = {:.1}",
            truth.translation.vector.norm()
        )
        .unwrap();
    }
    std::fs::write(dir.join("cell.toml"), toml).unwrap();
    let mut gt = serde_json::json!({
        "T_base1_base2": rows4(&truth),
        "generator": "depthcal-tests-foreign/1",
        "seed": cfg.seed,
        "scene": cfg.scene.name(),
        "views_per_robot": cfg.views,
        "size": [cfg.width, cfg.height],
        "tilt_deg": cfg.tilt_deg,
        "shared_fraction": shared_fraction,
        "valid_fraction": valid_fraction,
        "true_hand_eye": names.iter().zip(&hand_eye).map(|(n, h)| (n.clone(), serde_json::json!(rows4(h)))).collect::<serde_json::Map<_, _>>(),
        "true_fy": intr.iter().map(|k| k.fy).collect::<Vec<_>>(),
        "sabotage": format!("{:?}", cfg.sabotage),
        "layout": cfg.layout.name(),
        "ground": cfg.effective_ground().name(),
        "floor": cfg.floor,
        "table_shape": cfg.table_shape.name(),
        "square_table": cfg.square_table,
        "objects": cfg.objects.name(),
        "other_robot_in_view": cfg.other_robot_in_view,
        "pedestal": cfg.pedestal,
        "aim": cfg.aim.name(),
        "flying_pixels": cfg.flying_pixels,
        "holes": cfg.holes,
        "pose_noise_mm": cfg.pose_noise_mm,
        "pose_noise_deg": cfg.pose_noise_mm * 0.05,
        "depth_scale": cfg.depth_scale,
        "table_top_m": scene.table_top,
        "table_centre_m": [scene.table_centre.x, scene.table_centre.y, scene.table_centre.z],
    });
    if n_robots > 2 {
        // Every robot's base, in the simulator's vocabulary (`calibrate` reads it).
        gt["robots"] = names
            .iter()
            .zip(&truths)
            .map(|(n, t)| serde_json::json!({"name": n, "T_base1_base": rows4(t)}))
            .collect();
    }
    std::fs::write(
        dir.join("ground_truth.json"),
        serde_json::to_string_pretty(&gt).unwrap(),
    )
    .unwrap();
    ForeignCell {
        dir: dir.to_path_buf(),
        truth,
        truths,
        names,
        t_ee_cam: hand_eye,
        t_base_ee: t_base_ee_all,
        shared_fraction,
        valid_fraction,
        table_top: scene.table_top,
        table_centre: scene.table_centre,
        render_s,
        total_s: start.elapsed().as_secs_f64(),
        config: cfg.clone(),
    }
}

/// Per robot: the fraction of its valid pixels (every `step`-th row and column) that some view of another
/// robot also saw, and the fraction of all its pixels with data.
fn shared_and_valid(views: &[Vec<View>], intr: &[Pinhole], step: usize) -> (Vec<f64>, Vec<f64>) {
    let n = views.len();
    let mut shared_fraction = vec![0.0; n];
    let mut valid_fraction = vec![0.0; n];
    for k in 0..n {
        let (mut seen, mut shared, mut valid, mut total) = (0usize, 0usize, 0usize, 0usize);
        let kk = &intr[k];
        for view in &views[k] {
            total += view.depth.len();
            valid += view.depth.iter().filter(|&&d| d > 0).count();
            for v in (0..kk.height as usize).step_by(step) {
                for u in (0..kk.width as usize).step_by(step) {
                    let z = view.clean[v * kk.width as usize + u] as f64;
                    if z <= 0.0 || view.depth[v * kk.width as usize + u] == 0 {
                        continue;
                    }
                    seen += 1;
                    let p_cam = Vector3::new(
                        (u as f64 - kk.ppx) / kk.fx * z,
                        (v as f64 - kk.ppy) / kk.fy * z,
                        z,
                    );
                    let p_w = view.t_base1_cam * Point3::from(p_cam);
                    let by_another = (0..n)
                        .filter(|&j| j != k)
                        .any(|j| views[j].iter().any(|ov| sees(&intr[j], ov, &p_w)));
                    if by_another {
                        shared += 1;
                    }
                }
            }
        }
        shared_fraction[k] = shared as f64 / seen.max(1) as f64;
        valid_fraction[k] = valid as f64 / total.max(1) as f64;
    }
    (shared_fraction, valid_fraction)
}

/// Whether the (other robot's) view `ov` saw the world point `p` (in its image, not occluded).
fn sees(k: &Pinhole, ov: &View, p: &Point3<f64>) -> bool {
    let q = ov.t_base1_cam.inverse_transform_point(p);
    if q.z <= 0.05 {
        return false;
    }
    let u = (q.x / q.z * k.fx + k.ppx).round();
    let v = (q.y / q.z * k.fy + k.ppy).round();
    if u < 0.0 || v < 0.0 || u >= k.width as f64 || v >= k.height as f64 {
        return false;
    }
    let i = v as usize * k.width as usize + u as usize;
    let z = ov.clean[i] as f64;
    ov.depth[i] > 0 && (z - q.z).abs() < 0.01 + 0.01 * q.z
}
