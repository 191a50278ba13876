//! The 3-D scene of a report: point sets in their own frames, the items that place and colour them (a cloud
//! under a transform, line sets for base triads and camera frusta), and the fixed camera both the page's
//! viewer and the PNG snapshots start from.
//!
//! Coordinates are the clouds' own (metres for cells, cloud units for `register`); every transform maps an
//! item's own frame into the scene frame (the reference base, or the target's frame): `p_scene = T · p`.

use crate::camera::Intrinsics;
use nalgebra::{Isometry3, Point3, Vector3};
use serde::Serialize;

/// Most points a report's viewer and snapshots hold over all point sets (a deterministic stride subsample
/// of each cloud beyond its share).
pub const MAX_POINTS: usize = 200_000;

/// Colours of the clouds: the reference robot (or the registration target), the other robot (or the moved
/// source), then further placements (`compare`'s other methods, initial estimates).
pub const PALETTE: [[u8; 3]; 6] = [
    [230, 120, 30],
    [40, 110, 230],
    [175, 80, 210],
    [40, 175, 95],
    [220, 200, 40],
    [30, 190, 200],
];

/// Colour of a frame the robot's own consistency check flagged.
pub const FLAGGED: [u8; 3] = [240, 40, 40];

/// A set of points in its own frame.
#[derive(Clone, Debug, Default)]
pub struct PointSet {
    /// What the set is (e.g. `right fused cloud`).
    pub name: String,
    /// The points (finite only).
    pub points: Vec<[f32; 3]>,
    /// How many points the cloud had before subsampling.
    pub original: usize,
}

impl PointSet {
    /// The finite points of `points`, every `k`-th of them when there are more than `max` (`k` the smallest
    /// stride that keeps at most `max`; deterministic).
    pub fn subsampled(name: &str, points: &[[f32; 3]], max: usize) -> Self {
        let finite: Vec<[f32; 3]> = points
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .copied()
            .collect();
        let step = finite.len().div_ceil(max.max(1)).max(1);
        PointSet {
            name: name.to_string(),
            points: finite.iter().step_by(step).copied().collect(),
            original: points.len(),
        }
    }
}

/// A line segment with its colour, in its item's own frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// One end.
    pub a: [f32; 3],
    /// The other end.
    pub b: [f32; 3],
    /// Colour.
    pub rgb: [u8; 3],
}

/// What an item draws.
#[derive(Clone, Debug)]
pub enum Shape {
    /// A point set ([`Scene::sets`] index), with a residual per point ([`Scene::residuals`] index) when
    /// the residual colouring applies to it.
    Points {
        /// The point set.
        set: usize,
        /// The residuals of its points, if any.
        residual: Option<usize>,
    },
    /// Line segments.
    Lines(Vec<Segment>),
}

/// One thing the viewer can show or hide.
#[derive(Clone, Debug)]
pub struct Item {
    /// The toggle's label.
    pub name: String,
    /// What it draws.
    pub shape: Shape,
    /// Maps the item's own frame into the scene frame.
    pub transform: Isometry3<f64>,
    /// Colour of its points (lines carry their own).
    pub rgb: [u8; 3],
    /// Shown when the page opens.
    pub visible: bool,
    /// Which snapshots show it ([`View`] names: `refined`, `initial`).
    pub views: Vec<&'static str>,
}

/// The fixed starting camera: orthographic, looking at `center` from azimuth / elevation (degrees, z up),
/// scaled so that a sphere of `radius` about `center` fits the image.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Camera {
    /// The point looked at (scene frame).
    pub center: [f64; 3],
    /// Radius of the sphere that fits the image (scene units).
    pub radius: f64,
    /// Angle about z of the direction toward the viewer, from +x, degrees.
    pub azimuth_deg: f64,
    /// Angle of that direction above the xy plane, degrees.
    pub elevation_deg: f64,
    /// Half the depth the scene spans along the view direction (scene units): the range of the depth cue.
    pub depth_radius: f64,
}

impl Camera {
    /// The view basis: rows `right`, `up`, `toward the viewer` (scene frame).
    pub fn basis(&self) -> [Vector3<f64>; 3] {
        let (az, el) = (
            self.azimuth_deg.to_radians(),
            self.elevation_deg.to_radians(),
        );
        let eye = Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
        let right = Vector3::new(-az.sin(), az.cos(), 0.0);
        let up = eye.cross(&right);
        [right, up, eye]
    }
}

/// Residuals of one point set's points (display units, NaN: no counterpart).
#[derive(Clone, Debug, Default)]
pub struct Residuals {
    /// What the residuals are of (e.g. `right, refined`).
    pub name: String,
    /// Per point of the set, display units; NaN where the other surface has no point within reach.
    pub values: Vec<f32>,
}

/// The whole scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The point sets.
    pub sets: Vec<PointSet>,
    /// The residual arrays.
    pub residuals: Vec<Residuals>,
    /// The items, in drawing and toggle order.
    pub items: Vec<Item>,
    /// The starting camera ([`Scene::fit_camera`]).
    pub camera: Camera,
    /// The largest residual of the colour scale (display units).
    pub residual_max: f64,
    /// The residuals' unit (`mm`, or `cloud units`).
    pub residual_unit: String,
}

impl Scene {
    /// An empty scene.
    pub fn new(residual_unit: &str) -> Self {
        Scene {
            sets: Vec::new(),
            residuals: Vec::new(),
            items: Vec::new(),
            camera: Camera {
                center: [0.0; 3],
                radius: 1.0,
                azimuth_deg: -60.0,
                elevation_deg: 30.0,
                depth_radius: 1.0,
            },
            residual_max: 1.0,
            residual_unit: residual_unit.to_string(),
        }
    }

    /// Adds a point set; returns its index.
    pub fn add_set(&mut self, set: PointSet) -> usize {
        self.sets.push(set);
        self.sets.len() - 1
    }

    /// Points of the visible point items, in the scene frame, with the item they belong to.
    fn visible_points(&self) -> impl Iterator<Item = Vector3<f64>> + '_ {
        self.items.iter().filter(|i| i.visible).flat_map(move |i| {
            let pts: Vec<[f32; 3]> = match &i.shape {
                Shape::Points { set, .. } => self.sets[*set].points.clone(),
                Shape::Lines(s) => s.iter().flat_map(|s| [s.a, s.b]).collect(),
            };
            pts.into_iter().map(move |p| {
                (i.transform * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).coords
            })
        })
    }

    /// Points drawn when the page opens: those of the visible point items.
    pub fn visible_point_count(&self) -> usize {
        self.items
            .iter()
            .filter(|i| i.visible)
            .map(|i| match &i.shape {
                Shape::Points { set, .. } => self.sets[*set].points.len(),
                Shape::Lines(_) => 0,
            })
            .sum()
    }

    /// Frames everything visible from the camera's direction: centres the camera on the box the visible
    /// points and lines span in the image plane and sets its radius to the larger half side of that box, so
    /// that each of them lies inside a landscape image; the depth radius is the half depth of the box.
    pub fn fit_camera(&mut self) {
        let [r, u, e] = self.camera.basis();
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for p in self.visible_points() {
            let v = Vector3::new(r.dot(&p), u.dot(&p), e.dot(&p));
            lo = lo.inf(&v);
            hi = hi.sup(&v);
        }
        if !(lo.x.is_finite() && hi.x.is_finite()) {
            return;
        }
        let m = (lo + hi) / 2.0;
        let c = r * m.x + u * m.y + e * m.z;
        let half = (hi - lo) / 2.0;
        let radius = half.x.max(half.y);
        self.camera.center = [c.x, c.y, c.z];
        self.camera.radius = if radius > 0.0 { radius } else { 1.0 };
        self.camera.depth_radius = if half.z > 0.0 {
            half.z
        } else {
            self.camera.radius
        };
    }
}

/// The axes of a frame as three segments (x red, y green, z blue) of `length`.
pub fn triad(length: f64) -> Vec<Segment> {
    let l = length as f32;
    [
        ([l, 0.0, 0.0], [230, 50, 50]),
        ([0.0, l, 0.0], [60, 200, 60]),
        ([0.0, 0.0, l], [70, 110, 255]),
    ]
    .into_iter()
    .map(|(b, rgb)| Segment {
        a: [0.0; 3],
        b,
        rgb,
    })
    .collect()
}

/// A camera's frustum as eight segments: its centre to the four corners of its image at `depth` in front
/// of it, and the image outline; `t_frame_cam` places the camera in the item's frame.
pub fn frustum(
    t_frame_cam: &Isometry3<f64>,
    intrinsics: &Intrinsics,
    depth: f64,
    rgb: [u8; 3],
) -> Vec<Segment> {
    let (w, h) = (intrinsics.width as f64, intrinsics.height as f64);
    let corner = |u: f64, v: f64| {
        let x = (u - intrinsics.ppx) / intrinsics.fx * depth;
        let y = (v - intrinsics.ppy) / intrinsics.fy * depth;
        let p = t_frame_cam * Point3::new(x, y, depth);
        [p.x as f32, p.y as f32, p.z as f32]
    };
    let o = t_frame_cam.translation.vector;
    let o = [o.x as f32, o.y as f32, o.z as f32];
    let c = [
        corner(0.0, 0.0),
        corner(w, 0.0),
        corner(w, h),
        corner(0.0, h),
    ];
    let mut s = Vec::with_capacity(8);
    for k in 0..4 {
        s.push(Segment { a: o, b: c[k], rgb });
        s.push(Segment {
            a: c[k],
            b: c[(k + 1) % 4],
            rgb,
        });
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn subsample_keeps_at_most_max_and_drops_non_finite() {
        let pts: Vec<[f32; 3]> = (0..1001)
            .map(|i| {
                if i == 5 {
                    [f32::NAN, 0.0, 0.0]
                } else {
                    [i as f32, 0.0, 0.0]
                }
            })
            .collect();
        let s = PointSet::subsampled("x", &pts, 100);
        assert!(
            s.points.len() <= 100 && s.points.len() >= 90,
            "{}",
            s.points.len()
        );
        assert_eq!(s.original, 1001);
        assert!(s.points.iter().all(|p| p[0].is_finite()));
        assert_eq!(PointSet::subsampled("x", &pts, 5000).points.len(), 1000);
    }

    #[test]
    fn the_fitted_camera_holds_every_visible_point() {
        let mut sc = Scene::new("mm");
        let set = sc.add_set(PointSet::subsampled(
            "a",
            &[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 4.0, 1.0]],
            10,
        ));
        sc.items.push(Item {
            name: "a".into(),
            shape: Shape::Points {
                set,
                residual: None,
            },
            transform: Isometry3::translation(10.0, 0.0, 0.0),
            rgb: PALETTE[0],
            visible: true,
            views: vec!["refined"],
        });
        sc.fit_camera();
        // Every point projects inside the sphere's square, and the extreme ones touch its sides.
        let [r, u, e] = sc.camera.basis();
        let c = Vector3::from(sc.camera.center);
        let mut max = 0f64;
        for p in [[10.0, 0.0, 0.0], [12.0, 0.0, 0.0], [10.0, 4.0, 1.0]] {
            let d = Vector3::from(p) - c;
            let (x, y) = (r.dot(&d), u.dot(&d));
            assert!(x.abs() <= sc.camera.radius + 1e-12 && y.abs() <= sc.camera.radius + 1e-12);
            max = max.max(x.abs()).max(y.abs());
            assert!(e.dot(&d).abs() <= sc.camera.depth_radius + 1e-12);
        }
        assert!((max - sc.camera.radius).abs() < 1e-12);
        let [right, up, eye] = sc.camera.basis();
        assert!(right.dot(&up).abs() < 1e-12 && up.dot(&eye).abs() < 1e-12);
        assert!((right.cross(&up) - eye).norm() < 1e-12, "right-handed");
        assert_eq!(sc.visible_point_count(), 3);
    }
}
