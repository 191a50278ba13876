//! The simulated scene: a table with fiducial objects of distinct geometry (boxes, cylinders, spheres, cones,
//! triangle meshes), an optional floor, and ray casting against it (parry3d).
//!
//! Frames: the scene's `world` frame is the table frame: origin at the centre of the table top, `z` up, the
//! table top is the plane `z = 0` and the table occupies `z ∈ [-thickness, 0]`. Each object has an object
//! frame whose origin is the centre of its bounding box and whose `z` axis is the shape's axis (cylinders,
//! cones, meshes' "up"); `T_world_object` maps it into the world.

use super::board::{SimBoard, SimBoardConfig};
use super::convert::{to_pose, to_vec};
use super::marker::{SimMarkers, SimMarkersConfig};
use super::mesh::{builtin_mesh, read_ply_mesh, MeshData, BUILTIN_MESHES};
use crate::error::{Error, Result};
use crate::geometry::Rng;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::math::{Pose, Vector};
use parry3d_f64::query::{Ray, RayCast, RayIntersection};
use parry3d_f64::shape::{Ball, Cone, Cuboid, Cylinder, TriMesh};
use serde::{Deserialize, Serialize};
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::PathBuf;

/// The kinds of fiducial objects.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    /// A box (cuboid).
    Box,
    /// A cylinder, standing or lying on its side.
    Cylinder,
    /// A sphere.
    Sphere,
    /// An upright cone (apex up).
    Cone,
    /// A triangle mesh (built-in or from a PLY file).
    Mesh,
}

/// The geometry of one object, in its object frame (origin at the bounding-box centre, `z` the axis). Metres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ObjectShape {
    /// A box with full edge lengths `size_m = [x, y, z]`.
    Box {
        /// Edge lengths along the object's x, y, z, metres.
        size_m: [f64; 3],
    },
    /// A cylinder about the object's z axis.
    Cylinder {
        /// Radius, metres.
        radius_m: f64,
        /// Length along z, metres.
        height_m: f64,
    },
    /// A sphere.
    Sphere {
        /// Radius, metres.
        radius_m: f64,
    },
    /// A cone about the object's z axis, base at `z = -height/2`, apex at `z = +height/2`.
    Cone {
        /// Base radius, metres.
        radius_m: f64,
        /// Height, metres.
        height_m: f64,
    },
    /// A triangle mesh: a built-in one (see [`BUILTIN_MESHES`]) or a PLY file, scaled by `scale` and centred
    /// on its bounding box.
    Mesh {
        /// The built-in name, or the file stem for a PLY file.
        name: String,
        /// The PLY file, when not built in.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        path: Option<PathBuf>,
        /// Scale applied to the mesh's coordinates.
        scale: f64,
        /// Bounding-box size after scaling `[x, y, z]`, metres (informative).
        size_m: [f64; 3],
    },
}

impl ObjectShape {
    /// The object's kind.
    pub fn kind(&self) -> ObjectKind {
        match self {
            ObjectShape::Box { .. } => ObjectKind::Box,
            ObjectShape::Cylinder { .. } => ObjectKind::Cylinder,
            ObjectShape::Sphere { .. } => ObjectKind::Sphere,
            ObjectShape::Cone { .. } => ObjectKind::Cone,
            ObjectShape::Mesh { .. } => ObjectKind::Mesh,
        }
    }
}

/// How a surface looks in the grey/colour image: a 3-D checker of two albedos in object coordinates,
/// modulated by value noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Appearance {
    /// The two albedos (linear RGB in `[0, 1]`).
    pub albedo: [[f32; 3]; 2],
    /// Checker cell edge, metres.
    pub checker_m: f64,
    /// Seed of the value-noise pattern.
    pub pattern_seed: u64,
    /// A distinctive multi-scale texture of the two albedos instead of the checks (for 2D features).
    #[serde(default)]
    pub texture: bool,
}

/// One object of the scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneObject {
    /// Its geometry.
    pub shape: ObjectShape,
    /// Pose of the object frame in the world (table) frame, metres.
    pub t_world_object: Isometry3<f64>,
    /// Its look in the colour image.
    pub appearance: Appearance,
}

/// Settings of the random scene ([`Scene::random`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// Number of objects on the table (default 8).
    pub objects: usize,
    /// The kinds to use, assigned in turn from a random start (default all five kinds).
    pub kinds: Vec<ObjectKind>,
    /// PLY meshes to use for `mesh` objects (default none: the built-in meshes).
    pub mesh_files: Vec<PathBuf>,
    /// Range of the largest extent of a mesh object, metres (default `[0.09, 0.16]`).
    pub mesh_size_m: [f64; 2],
    /// Objects are placed (centres and footprints) within this radius of the table centre, metres (default
    /// 0.28).
    pub workspace_radius_m: f64,
    /// Smallest gap between the footprints of two objects, metres (default 0.02).
    pub min_gap_m: f64,
    /// Table top size `[x, y]` and thickness, metres (default `[1.0, 0.8, 0.04]`).
    pub table_size_m: [f64; 3],
    /// A floor this far below the table top, metres (default none: no floor, nothing below the table).
    pub floor_below_m: Option<f64>,
    /// Allow cylinders to lie on their side (default true; about a third of them do).
    pub lying_cylinders: bool,
    /// A printed checkerboard on the table top, kept clear of objects (default none; see
    /// [`crate::sim::board`]).
    pub board: Option<SimBoardConfig>,
    /// Square fiducial markers on the table top, kept clear of the board and of objects (default none;
    /// see [`crate::sim::marker`]).
    pub markers: Option<SimMarkersConfig>,
    /// Give the objects and the table a distinctive multi-scale texture (default false: two-colour
    /// checks with a faint value noise), for the 2D-feature method.
    pub textured: bool,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            objects: 8,
            kinds: vec![
                ObjectKind::Box,
                ObjectKind::Cylinder,
                ObjectKind::Sphere,
                ObjectKind::Cone,
                ObjectKind::Mesh,
            ],
            mesh_files: Vec::new(),
            mesh_size_m: [0.09, 0.16],
            workspace_radius_m: 0.28,
            min_gap_m: 0.02,
            table_size_m: [1.0, 0.8, 0.04],
            floor_below_m: None,
            lying_cylinders: true,
            board: None,
            markers: None,
            textured: false,
        }
    }
}

impl SceneConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("scene.{field}"),
                msg,
            })
        };
        if self.objects > 0 && self.kinds.is_empty() {
            return bad("kinds", "must name at least one kind".into());
        }
        if !(self.mesh_size_m[0] > 0.0 && self.mesh_size_m[1] >= self.mesh_size_m[0]) {
            return bad(
                "mesh_size_m",
                format!(
                    "must be [lo, hi] with 0 < lo ≤ hi, found {:?}",
                    self.mesh_size_m
                ),
            );
        }
        if !(self.workspace_radius_m > 0.05 && self.workspace_radius_m.is_finite()) {
            return bad(
                "workspace_radius_m",
                format!("must be above 0.05 m, found {}", self.workspace_radius_m),
            );
        }
        if !(self.min_gap_m >= 0.0 && self.min_gap_m.is_finite()) {
            return bad(
                "min_gap_m",
                format!("must be ≥ 0, found {}", self.min_gap_m),
            );
        }
        if self
            .table_size_m
            .iter()
            .any(|v| !(v.is_finite() && *v > 0.0))
        {
            return bad(
                "table_size_m",
                format!("must be positive, found {:?}", self.table_size_m),
            );
        }
        if let Some(b) = &self.board {
            b.validate()?;
        }
        if let Some(m) = &self.markers {
            m.validate()?;
        }
        if let Some(f) = self.floor_below_m {
            if !(f.is_finite() && f > self.table_size_m[2]) {
                return bad(
                    "floor_below_m",
                    format!("must exceed the table thickness, found {f}"),
                );
            }
        }
        Ok(())
    }
}

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Surface {
    /// The table.
    Table,
    /// The floor.
    Floor,
    /// Object `i` of [`Scene::objects`].
    Object(usize),
}

/// A ray hit in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit: distance along the ray in units of the direction's length.
    pub t: f64,
    /// The hit point, metres, world frame.
    pub point: Point3<f64>,
    /// Unit surface normal at the hit, world frame, facing the ray origin.
    pub normal: Vector3<f64>,
    /// The surface hit.
    pub surface: Surface,
}

/// A parry shape of the scene.
#[derive(Clone)]
pub(crate) enum Geom {
    Cuboid(Cuboid),
    Ball(Ball),
    Cylinder(Cylinder),
    Cone(Cone),
    Mesh(Box<TriMesh>),
}

impl Geom {
    /// parry's ray cast (GJK for cylinders and cones), in world coordinates with the shape at `pose`.
    fn cast_parry(&self, pose: &Pose, ray: &Ray, max_t: f64) -> Option<RayIntersection> {
        match self {
            Geom::Cuboid(s) => s.cast_ray_and_get_normal(pose, ray, max_t, true),
            Geom::Ball(s) => s.cast_ray_and_get_normal(pose, ray, max_t, true),
            Geom::Cylinder(s) => s.cast_ray_and_get_normal(pose, ray, max_t, true),
            Geom::Cone(s) => s.cast_ray_and_get_normal(pose, ray, max_t, true),
            Geom::Mesh(s) => s.cast_ray_and_get_normal(pose, ray, max_t, true),
        }
    }

    /// Closed-form ray cast in the *object* frame (axis z): `(t, outward normal)` of the first entry with
    /// `0 < t ≤ max_t`. Meshes go through parry's BVH.
    #[inline]
    fn cast_local(&self, o: Vector, d: Vector, max_t: f64) -> Option<(f64, Vector)> {
        match self {
            Geom::Cuboid(c) => ray_box(o, d, c.half_extents, max_t),
            Geom::Ball(b) => ray_sphere(o, d, b.radius, max_t),
            Geom::Cylinder(c) => ray_cylinder(o, d, c.radius, c.half_height, max_t),
            Geom::Cone(c) => ray_cone(o, d, c.radius, c.half_height, max_t),
            Geom::Mesh(m) => m
                .cast_local_ray_and_get_normal(&Ray::new(o, d), max_t, true)
                .map(|h| (h.time_of_impact, h.normal)),
        }
    }

    fn aabb(&self, pose: &Pose) -> Aabb {
        match self {
            Geom::Cuboid(s) => s.aabb(pose),
            Geom::Ball(s) => s.aabb(pose),
            Geom::Cylinder(s) => s.aabb(pose),
            Geom::Cone(s) => s.aabb(pose),
            Geom::Mesh(s) => s.aabb(pose),
        }
    }
}

/// The roots `(t1 ≤ t2)` of `a t² + 2 b t + c = 0`, or `None` when there are none.
#[inline]
fn quadric_roots(a: f64, b: f64, c: f64) -> Option<(f64, f64)> {
    if a.abs() < 1e-300 {
        if b.abs() < 1e-300 {
            return None;
        }
        let t = -c / (2.0 * b);
        return Some((t, t));
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    // The numerically stable pair: q = −(b + sign(b)·√disc), roots q/a and c/q.
    let q = -(b + if b >= 0.0 { sq } else { -sq });
    if q == 0.0 {
        return Some((0.0, 0.0));
    }
    let (t1, t2) = (q / a, c / q);
    Some((t1.min(t2), t1.max(t2)))
}

#[inline]
fn ray_box(o: Vector, d: Vector, h: Vector, max_t: f64) -> Option<(f64, Vector)> {
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis = 0;
    for k in 0..3 {
        let (ok, dk, hk) = (o[k], d[k], h[k]);
        if dk.abs() < 1e-300 {
            if ok.abs() > hk {
                return None;
            }
            continue;
        }
        let inv = 1.0 / dk;
        let (mut t1, mut t2) = ((-hk - ok) * inv, (hk - ok) * inv);
        if t1 > t2 {
            std::mem::swap(&mut t1, &mut t2);
        }
        if t1 > t_near {
            t_near = t1;
            axis = k;
        }
        t_far = t_far.min(t2);
        if t_near > t_far {
            return None;
        }
    }
    if t_near <= 0.0 || t_near > max_t {
        return None;
    }
    let mut n = Vector::ZERO;
    n[axis] = -d[axis].signum();
    Some((t_near, n))
}

#[inline]
fn ray_sphere(o: Vector, d: Vector, r: f64, max_t: f64) -> Option<(f64, Vector)> {
    let (t1, _) = quadric_roots(d.dot(d), o.dot(d), o.dot(o) - r * r)?;
    if t1 <= 0.0 || t1 > max_t {
        return None;
    }
    Some((t1, (o + d * t1) / r))
}

#[inline]
fn ray_cylinder(o: Vector, d: Vector, r: f64, hh: f64, max_t: f64) -> Option<(f64, Vector)> {
    let mut best: Option<(f64, Vector)> = None;
    let mut limit = max_t;
    if let Some((t1, t2)) = quadric_roots(
        d.x * d.x + d.y * d.y,
        o.x * d.x + o.y * d.y,
        o.x * o.x + o.y * o.y - r * r,
    ) {
        for t in [t1, t2] {
            if t > 0.0 && t <= limit {
                let p = o + d * t;
                if p.z.abs() <= hh {
                    best = Some((t, Vector::new(p.x / r, p.y / r, 0.0)));
                    limit = t;
                    break;
                }
            }
        }
    }
    if d.z.abs() > 1e-300 {
        for zc in [-hh, hh] {
            let t = (zc - o.z) / d.z;
            if t > 0.0 && t <= limit {
                let p = o + d * t;
                if p.x * p.x + p.y * p.y <= r * r {
                    best = Some((t, Vector::new(0.0, 0.0, zc.signum())));
                    limit = t;
                }
            }
        }
    }
    best
}

#[inline]
fn ray_cone(o: Vector, d: Vector, r: f64, hh: f64, max_t: f64) -> Option<(f64, Vector)> {
    // Side: x² + y² = k²·(hh − z)² with z ∈ [−hh, hh]; base disc at z = −hh.
    let k = r / (2.0 * hh);
    let k2 = k * k;
    let e = hh - o.z;
    let mut best: Option<(f64, Vector)> = None;
    let mut limit = max_t;
    if let Some((t1, t2)) = quadric_roots(
        d.x * d.x + d.y * d.y - k2 * d.z * d.z,
        o.x * d.x + o.y * d.y + k2 * e * d.z,
        o.x * o.x + o.y * o.y - k2 * e * e,
    ) {
        for t in [t1, t2] {
            if t > 0.0 && t <= limit {
                let p = o + d * t;
                if p.z >= -hh && p.z <= hh {
                    let n = Vector::new(p.x, p.y, k2 * (hh - p.z)).normalize_or_zero();
                    best = Some((t, n));
                    limit = t;
                    break;
                }
            }
        }
    }
    if d.z.abs() > 1e-300 {
        let t = (-hh - o.z) / d.z;
        if t > 0.0 && t <= limit {
            let p = o + d * t;
            if p.x * p.x + p.y * p.y <= r * r {
                best = Some((t, Vector::NEG_Z));
            }
        }
    }
    best
}

/// A shape placed in the world, ready for ray casting.
#[derive(Clone)]
pub(crate) struct Body {
    pub geom: Geom,
    /// Pose of the parry shape's own frame in the world (its y axis is the axis of cylinders and cones).
    pub parry_pose: Pose,
    /// `T_world_object` (z axis = axis).
    pub object_pose: Pose,
    /// Its inverse (world → object frame).
    pub inv_object: Pose,
    /// World-space bounds.
    pub aabb: Aabb,
    pub surface: Surface,
}

/// A scene ready for ray casting: the table, an optional floor and the objects.
#[derive(Clone)]
pub struct Scene {
    /// Table top size `[x, y]` and thickness, metres.
    pub table_size_m: [f64; 3],
    /// Height of the floor below the table top, metres (none: no floor).
    pub floor_below_m: Option<f64>,
    /// The objects.
    pub objects: Vec<SceneObject>,
    /// The table's look in the colour image.
    pub table_appearance: Appearance,
    /// The checkerboard on the table, if any (colour image only).
    pub board: Option<SimBoard>,
    /// The fiducial markers on the table, if any (colour image only).
    pub markers: Option<SimMarkers>,
    /// Bodies: the table first, then the objects in order.
    pub(crate) bodies: Vec<Body>,
    /// Cast with parry's own ray casts (GJK for cylinders and cones) instead of the closed forms (tests).
    pub(crate) use_parry: bool,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("table_size_m", &self.table_size_m)
            .field("floor_below_m", &self.floor_below_m)
            .field("objects", &self.objects)
            .finish()
    }
}

/// parry's cylinders and cones have their axis along y; the object frame has it along z.
fn y_to_z() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2),
    )
}

fn load_mesh(name: &str, path: &Option<PathBuf>) -> Result<MeshData> {
    match path {
        Some(p) => read_ply_mesh(p),
        None => builtin_mesh(name).ok_or_else(|| {
            Error::InvalidInput(format!(
                "unknown built-in mesh {name:?} (built-in: {BUILTIN_MESHES:?})"
            ))
        }),
    }
}

/// The mesh of a `Mesh` shape in its object frame (scaled, centred on its bounding box).
fn mesh_in_object_frame(name: &str, path: &Option<PathBuf>, scale: f64) -> Result<MeshData> {
    let m = load_mesh(name, path)?.normalised(scale);
    // `normalised` puts the bottom at z = 0; centre the box in z too.
    let (lo, hi) = m.bounds().expect("validated mesh");
    let dz = (lo[2] + hi[2]) / 2.0;
    let mut m = m;
    for v in &mut m.vertices {
        v[2] -= dz;
    }
    Ok(m)
}

fn geom_of(shape: &ObjectShape) -> Result<(Geom, Isometry3<f64>)> {
    let id = Isometry3::identity();
    Ok(match shape {
        ObjectShape::Box { size_m } => (
            Geom::Cuboid(Cuboid::new(Vector::new(
                size_m[0] / 2.0,
                size_m[1] / 2.0,
                size_m[2] / 2.0,
            ))),
            id,
        ),
        ObjectShape::Sphere { radius_m } => (Geom::Ball(Ball::new(*radius_m)), id),
        ObjectShape::Cylinder { radius_m, height_m } => (
            Geom::Cylinder(Cylinder::new(height_m / 2.0, *radius_m)),
            y_to_z(),
        ),
        ObjectShape::Cone { radius_m, height_m } => {
            (Geom::Cone(Cone::new(height_m / 2.0, *radius_m)), y_to_z())
        }
        ObjectShape::Mesh {
            name, path, scale, ..
        } => {
            let m = mesh_in_object_frame(name, path, *scale)?;
            let verts = m
                .vertices
                .iter()
                .map(|v| Vector::new(v[0], v[1], v[2]))
                .collect();
            let tm = TriMesh::new(verts, m.triangles).map_err(|e| {
                Error::InvalidInput(format!("mesh {name:?}: cannot build a triangle mesh: {e}"))
            })?;
            (Geom::Mesh(Box::new(tm)), id)
        }
    })
}

fn random_appearance(rng: &mut Rng, textured: bool) -> Appearance {
    // A saturated colour and a light or dark partner of a nearby hue.
    let hue = rng.uniform(0.0, 1.0);
    let c1 = hsv(hue, rng.uniform(0.45, 0.9), rng.uniform(0.55, 0.95));
    let c2 = hsv(
        (hue + rng.uniform(-0.15, 0.15)).rem_euclid(1.0),
        rng.uniform(0.1, 0.6),
        rng.uniform(0.15, 0.45),
    );
    Appearance {
        albedo: [c1, c2],
        checker_m: rng.uniform(0.012, 0.03),
        pattern_seed: rng.next_u64(),
        texture: textured,
    }
}

fn hsv(h: f64, s: f64, v: f64) -> [f32; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i64 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [r as f32, g as f32, b as f32]
}

/// Footprint radius of a shape on the table (xy bounding circle of its rotated shape), metres.
fn footprint(shape: &ObjectShape, lying: bool) -> f64 {
    match shape {
        ObjectShape::Box { size_m } => size_m[0].hypot(size_m[1]) / 2.0,
        ObjectShape::Sphere { radius_m } => *radius_m,
        ObjectShape::Cylinder { radius_m, height_m } => {
            if lying {
                radius_m.hypot(height_m / 2.0)
            } else {
                *radius_m
            }
        }
        ObjectShape::Cone { radius_m, .. } => *radius_m,
        ObjectShape::Mesh { size_m, .. } => size_m[0].hypot(size_m[1]) / 2.0,
    }
}

impl Scene {
    /// Builds a scene from explicit objects (poses in the table frame). Mesh objects are loaded (built-in or
    /// from their PLY file).
    pub fn new(
        table_size_m: [f64; 3],
        floor_below_m: Option<f64>,
        objects: Vec<SceneObject>,
        table_appearance: Appearance,
    ) -> Result<Self> {
        let mut bodies = Vec::with_capacity(objects.len() + 1);
        let [tx, ty, tz] = table_size_m;
        let table_pose = to_pose(&Isometry3::translation(0.0, 0.0, -tz / 2.0));
        let table = Geom::Cuboid(Cuboid::new(Vector::new(tx / 2.0, ty / 2.0, tz / 2.0)));
        bodies.push(Body {
            aabb: table.aabb(&table_pose),
            geom: table,
            parry_pose: table_pose,
            object_pose: table_pose,
            inv_object: table_pose.inverse(),
            surface: Surface::Table,
        });
        for (i, o) in objects.iter().enumerate() {
            let (geom, local) = geom_of(&o.shape)?;
            let parry_pose = to_pose(&(o.t_world_object * local));
            bodies.push(Body {
                aabb: geom.aabb(&parry_pose),
                geom,
                parry_pose,
                object_pose: to_pose(&o.t_world_object),
                inv_object: to_pose(&o.t_world_object.inverse()),
                surface: Surface::Object(i),
            });
        }
        Ok(Scene {
            table_size_m,
            floor_below_m,
            objects,
            table_appearance,
            board: None,
            markers: None,
            bodies,
            use_parry: false,
        })
    }

    /// A random scene: `cfg.objects` objects of the configured kinds with random sizes and yaw, resting on the
    /// table without touching each other, within `cfg.workspace_radius_m` of the table centre. Same seed, same
    /// scene.
    pub fn random(cfg: &SceneConfig, seed: u64) -> Result<Self> {
        cfg.validate()?;
        let mut rng = Rng::stream(seed, 0x5CE7E);
        let meshes: Vec<(String, Option<PathBuf>)> = if cfg.mesh_files.is_empty() {
            BUILTIN_MESHES
                .iter()
                .map(|n| (n.to_string(), None))
                .collect()
        } else {
            cfg.mesh_files
                .iter()
                .map(|p| {
                    let stem = p
                        .file_stem()
                        .map(|s| s.to_string_lossy().into_owned())
                        .unwrap_or_else(|| "mesh".into());
                    (stem, Some(p.clone()))
                })
                .collect()
        };
        // Raw mesh extents, to scale each to a chosen size.
        let mut mesh_raw = Vec::with_capacity(meshes.len());
        for (name, path) in &meshes {
            let m = load_mesh(name, path)?;
            let (lo, hi) = m.bounds().expect("validated mesh");
            mesh_raw.push([hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]]);
        }
        let table_appearance = Appearance {
            albedo: [[0.62, 0.55, 0.45], [0.35, 0.3, 0.25]],
            checker_m: 0.05,
            pattern_seed: rng.next_u64(),
            texture: cfg.textured,
        };
        let start = if cfg.kinds.is_empty() {
            0
        } else {
            rng.below(cfg.kinds.len())
        };
        let mut mesh_next = rng.below(meshes.len().max(1));
        let mut placed: Vec<([f64; 2], f64)> = Vec::new();
        // Its own stream, so that scenes without a board are as before.
        let board = match &cfg.board {
            Some(b) => Some(SimBoard::place(b, &mut Rng::stream(seed, 0xB0A4D))?),
            None => None,
        };
        let markers = match &cfg.markers {
            Some(m) => Some(SimMarkers::place(
                m,
                &mut Rng::stream(seed, 0x3A4E5),
                &|c, r| board.as_ref().is_some_and(|b| b.overlaps_disc(c, r)),
            )?),
            None => None,
        };
        let mut objects = Vec::with_capacity(cfg.objects);
        let r_ws = cfg.workspace_radius_m;
        for i in 0..cfg.objects {
            let kind = cfg.kinds[(start + i) % cfg.kinds.len()];
            let mut done = false;
            for _attempt in 0..400 {
                let lying =
                    kind == ObjectKind::Cylinder && cfg.lying_cylinders && rng.below(3) == 0;
                let shape = match kind {
                    ObjectKind::Box => ObjectShape::Box {
                        size_m: [
                            rng.uniform(0.04, 0.15),
                            rng.uniform(0.04, 0.12),
                            rng.uniform(0.03, 0.14),
                        ],
                    },
                    ObjectKind::Cylinder => ObjectShape::Cylinder {
                        radius_m: rng.uniform(0.025, 0.055),
                        height_m: if lying {
                            rng.uniform(0.08, 0.16)
                        } else {
                            rng.uniform(0.06, 0.2)
                        },
                    },
                    ObjectKind::Sphere => ObjectShape::Sphere {
                        radius_m: rng.uniform(0.03, 0.065),
                    },
                    ObjectKind::Cone => ObjectShape::Cone {
                        radius_m: rng.uniform(0.035, 0.07),
                        height_m: rng.uniform(0.08, 0.18),
                    },
                    ObjectKind::Mesh => {
                        let k = mesh_next % meshes.len();
                        let raw = mesh_raw[k];
                        let largest = raw[0].max(raw[1]).max(raw[2]).max(1e-9);
                        let scale = rng.uniform(cfg.mesh_size_m[0], cfg.mesh_size_m[1]) / largest;
                        ObjectShape::Mesh {
                            name: meshes[k].0.clone(),
                            path: meshes[k].1.clone(),
                            scale,
                            size_m: raw.map(|v| v * scale),
                        }
                    }
                };
                let fp = footprint(&shape, lying);
                if fp + 0.01 > r_ws {
                    continue;
                }
                // Uniform in the disc of radius r_ws − fp.
                let rr = (r_ws - fp) * rng.next_f64().sqrt();
                let th = rng.uniform(0.0, 2.0 * PI);
                let c = [rr * th.cos(), rr * th.sin()];
                let yaw = rng.uniform(-PI, PI);
                if placed
                    .iter()
                    .any(|(p, f)| (p[0] - c[0]).hypot(p[1] - c[1]) < f + fp + cfg.min_gap_m)
                    || board
                        .as_ref()
                        .is_some_and(|b| b.overlaps_disc(c, fp + cfg.min_gap_m))
                    || markers
                        .as_ref()
                        .is_some_and(|m| m.overlaps_disc(c, fp + cfg.min_gap_m))
                {
                    continue;
                }
                // Height of the object-frame origin (bounding-box centre) above the table top.
                let (z, tilt) = match &shape {
                    ObjectShape::Box { size_m } => (size_m[2] / 2.0, None),
                    ObjectShape::Sphere { radius_m } => (*radius_m, None),
                    ObjectShape::Cylinder { radius_m, height_m } => {
                        if lying {
                            (*radius_m, Some(FRAC_PI_2))
                        } else {
                            (height_m / 2.0, None)
                        }
                    }
                    ObjectShape::Cone { height_m, .. } => (height_m / 2.0, None),
                    ObjectShape::Mesh { size_m, .. } => (size_m[2] / 2.0, None),
                };
                let mut rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
                if let Some(a) = tilt {
                    rot *= UnitQuaternion::from_axis_angle(&Vector3::x_axis(), a);
                }
                let t_world_object = Isometry3::from_parts(Translation3::new(c[0], c[1], z), rot);
                if kind == ObjectKind::Mesh {
                    mesh_next += 1;
                }
                placed.push((c, fp));
                objects.push(SceneObject {
                    shape,
                    t_world_object,
                    appearance: random_appearance(&mut rng, cfg.textured),
                });
                done = true;
                break;
            }
            if !done {
                log::warn!(
                    "scene: no room for object {i} ({kind:?}) within {r_ws} m of the table centre; it is left out \
                     ({} of the objects before it placed)",
                    objects.len()
                );
            }
        }
        let mut scene = Scene::new(
            cfg.table_size_m,
            cfg.floor_below_m,
            objects,
            table_appearance,
        )?;
        scene.board = board;
        scene.markers = markers;
        Ok(scene)
    }

    /// The first hit of the ray `origin + t·dir` (`t ∈ (0, max_t]`), world frame, metres. `dir` need not be
    /// normalised; `t` is in units of its length.
    pub fn cast_ray(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<Hit> {
        let ray = Ray::new(to_vec(&origin.coords), to_vec(dir));
        let h = self.cast_bodies(&ray, 0..self.bodies.len(), max_t)?;
        let p = ray.origin + ray.dir * h.t;
        Some(Hit {
            t: h.t,
            point: Point3::new(p.x, p.y, p.z),
            normal: Vector3::new(h.normal.x, h.normal.y, h.normal.z),
            surface: h.surface,
        })
    }

    /// Nearest hit among the bodies `ids` and the floor.
    #[inline]
    pub(crate) fn cast_bodies(
        &self,
        ray: &Ray,
        ids: impl IntoIterator<Item = usize>,
        max_t: f64,
    ) -> Option<RawHit> {
        let mut best: Option<RawHit> = None;
        let mut limit = max_t;
        for i in ids {
            let b = &self.bodies[i];
            let hit = if self.use_parry {
                b.geom
                    .cast_parry(&b.parry_pose, ray, limit)
                    .map(|h| (h.time_of_impact, h.normal))
            } else {
                let o = b.inv_object.transform_point(ray.origin);
                let d = b.inv_object.rotation * ray.dir;
                b.geom
                    .cast_local(o, d, limit)
                    .map(|(t, n)| (t, b.object_pose.rotation * n))
            };
            if let Some((t, normal)) = hit {
                if t > 0.0 && t <= limit {
                    limit = t;
                    best = Some(RawHit {
                        t,
                        normal,
                        surface: b.surface,
                        body: i,
                    });
                }
            }
        }
        if let Some(fb) = self.floor_below_m {
            // The plane z = -fb, seen from above.
            if ray.dir.z < 0.0 {
                let t = (-fb - ray.origin.z) / ray.dir.z;
                if t > 0.0 && t <= limit {
                    best = Some(RawHit {
                        t,
                        normal: Vector::Z,
                        surface: Surface::Floor,
                        body: usize::MAX,
                    });
                }
            }
        }
        best.map(|mut h| {
            let n = h.normal.normalize_or_zero();
            h.normal = if n.dot(ray.dir) > 0.0 { -n } else { n };
            h
        })
    }

    /// Number of bodies (the table and the objects).
    pub(crate) fn body_count(&self) -> usize {
        self.bodies.len()
    }

    /// The appearance and world→object transform of a surface (for texturing).
    pub(crate) fn surface_look(&self, s: Surface) -> (&Appearance, Pose) {
        match s {
            Surface::Table | Surface::Floor => (&self.table_appearance, Pose::IDENTITY),
            Surface::Object(i) => (&self.objects[i].appearance, self.bodies[i + 1].inv_object),
        }
    }

    /// The world-space bounds `(min, max)` of the table top's objects (all objects), metres; `None` without
    /// objects.
    pub fn objects_bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let mut it = self.bodies.iter().skip(1);
        let first = it.next()?.aabb;
        let (mut lo, mut hi) = (first.mins, first.maxs);
        for b in it {
            lo = lo.min(b.aabb.mins);
            hi = hi.max(b.aabb.maxs);
        }
        Some(([lo.x, lo.y, lo.z], [hi.x, hi.y, hi.z]))
    }

    /// The world-space bounds of body `i` (0 = table).
    pub(crate) fn body_aabb(&self, i: usize) -> &Aabb {
        &self.bodies[i].aabb
    }
}

/// A hit in parry's types.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RawHit {
    pub t: f64,
    pub normal: Vector,
    pub surface: Surface,
    #[allow(dead_code)]
    pub body: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed-form casts agree with parry's own (GJK for cylinders and cones) on random rays.
    #[test]
    fn closed_forms_match_parry() {
        let mut scene = Scene::random(&SceneConfig::default(), 11).unwrap();
        let mut rng = Rng::new(5);
        let (mut hits, mut worst_t, mut worst_n) = (0, 0.0f64, 0.0f64);
        for _ in 0..20_000 {
            let o = Point3::new(
                rng.uniform(-0.8, 0.8),
                rng.uniform(-0.8, 0.8),
                rng.uniform(0.2, 0.9),
            );
            let target = Point3::new(
                rng.uniform(-0.3, 0.3),
                rng.uniform(-0.3, 0.3),
                rng.uniform(-0.05, 0.2),
            );
            let d = (target - o).normalize();
            scene.use_parry = false;
            let a = scene.cast_ray(&o, &d, 10.0);
            scene.use_parry = true;
            let b = scene.cast_ray(&o, &d, 10.0);
            match (a, b) {
                (Some(a), Some(b)) => {
                    // Rays that graze an edge may see different faces; compare where both agree on the surface.
                    if a.surface == b.surface && (a.t - b.t).abs() < 1e-3 {
                        hits += 1;
                        worst_t = worst_t.max((a.t - b.t).abs());
                        worst_n = worst_n.max((a.normal - b.normal).norm());
                    }
                }
                (None, None) => {}
                (a, b) => {
                    // Only at silhouettes, where GJK's tolerance decides.
                    let t = a.or(b).unwrap().t;
                    let _ = t;
                }
            }
        }
        assert!(hits > 10_000, "{hits}");
        assert!(worst_t < 1e-6, "worst |Δt| = {worst_t}");
        assert!(worst_n < 1e-3, "worst |Δn| = {worst_n}");
    }
}
