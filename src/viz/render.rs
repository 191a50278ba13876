//! The software renderer of the PNG snapshots: an orthographic point splatter with a depth buffer, lines
//! drawn over the points, and bitmap-font labels. The page's viewer projects, shades and colours points the
//! same way ([`Projector`], [`shade`], [`colormap`]), so that a snapshot shows what the page opens on.

use super::font::{text_pixels, text_width};
use super::scene::{Camera, Scene, Shape};
use crate::camera::RgbImage;
use nalgebra::{Point3, Vector3};

/// Background colour of the views.
pub const BACKGROUND: [u8; 3] = [24, 26, 30];
/// Colour of points without a counterpart on the other surface (residual NaN).
pub const UNMATCHED: [u8; 3] = [90, 90, 96];
/// Colour of the points that carry no residual in the residual colouring (the reference surface).
pub const REFERENCE_GREY: [u8; 3] = [150, 150, 150];
/// The residual colour scale from 0 to its maximum: dark blue, blue, cyan, green, orange, red, dark red.
pub const COLORMAP: [[u8; 3]; 7] = [
    [48, 18, 59],
    [70, 134, 251],
    [26, 228, 182],
    [164, 252, 60],
    [251, 185, 56],
    [228, 70, 16],
    [122, 4, 3],
];
/// How far behind (a fraction of the camera's depth radius) the points without residuals are drawn in the residual
/// colouring, so that the coloured surface shows where both surfaces coincide.
pub const DEPTH_BIAS: f64 = 0.01;
/// The fraction of the image's smaller side the camera's sphere spans.
pub const FILL: f64 = 0.95;

/// The colour of `t` in [0, 1] (clamped) on [`COLORMAP`], linear between its stops.
pub fn colormap(t: f64) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (COLORMAP.len() - 1) as f64;
    let k = (x.floor() as usize).min(COLORMAP.len() - 2);
    let f = x - k as f64;
    let (a, b) = (COLORMAP[k], COLORMAP[k + 1]);
    std::array::from_fn(|i| (a[i] as f64 + (b[i] as f64 - a[i] as f64) * f).round() as u8)
}

/// Depth cueing: `rgb` darkened with the distance from the viewer, from full brightness at the front of the
/// scene to 45% at its back (`depth` along the view direction, positive toward the viewer, over the camera's
/// depth radius).
pub fn shade(rgb: [u8; 3], depth: f64, radius: f64) -> [u8; 3] {
    let f = (0.45 + 0.55 * (depth / radius + 1.0) / 2.0).clamp(0.3, 1.0);
    rgb.map(|c| (c as f64 * f).round() as u8)
}

/// A splat size that about covers the image for `points` points (1 to 4 pixels).
pub fn point_size(points: usize, width: u32, height: u32) -> u32 {
    let area = width as f64 * height as f64;
    ((area / points.max(1) as f64).sqrt().round() as u32).clamp(1, 4)
}

/// Maps scene points to image pixels for a [`Camera`].
#[derive(Clone, Copy, Debug)]
pub struct Projector {
    basis: [Vector3<f64>; 3],
    center: Vector3<f64>,
    scale: f64,
    half: (f64, f64),
}

impl Projector {
    /// The projection of `camera` into a `width` x `height` image.
    pub fn new(camera: &Camera, width: u32, height: u32) -> Self {
        Projector {
            basis: camera.basis(),
            center: Vector3::from(camera.center),
            scale: FILL * width.min(height) as f64 / (2.0 * camera.radius),
            half: (width as f64 / 2.0, height as f64 / 2.0),
        }
    }

    /// Pixel column, row and depth (scene units, positive toward the viewer) of a scene point.
    pub fn project(&self, p: &Vector3<f64>) -> (f64, f64, f64) {
        let d = p - self.center;
        let [r, u, e] = &self.basis;
        (
            self.half.0 + self.scale * r.dot(&d),
            self.half.1 - self.scale * u.dot(&d),
            e.dot(&d),
        )
    }
}

/// How points are coloured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Colouring {
    /// Each item in its own colour.
    ByItem,
    /// Points with residuals on the residual colour scale, the others grey.
    Residual,
}

/// An image being drawn: colours and the depth of what each pixel shows.
pub struct Canvas {
    /// The picture.
    pub image: RgbImage,
    depth: Vec<f32>,
}

impl Canvas {
    /// A `width` x `height` canvas filled with [`BACKGROUND`].
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Canvas {
            image: RgbImage {
                width,
                height,
                data: BACKGROUND.iter().copied().cycle().take(3 * n).collect(),
            },
            depth: vec![f32::NEG_INFINITY; n],
        }
    }

    fn put(&mut self, x: i64, y: i64, rgb: [u8; 3]) {
        let (w, h) = (self.image.width as i64, self.image.height as i64);
        if x >= 0 && y >= 0 && x < w && y < h {
            let k = (y * w + x) as usize;
            self.image.data[3 * k..3 * k + 3].copy_from_slice(&rgb);
        }
    }

    /// A square splat of `size` pixels centred at `(x, y)`, where nothing nearer was drawn.
    fn splat(&mut self, x: f64, y: f64, depth: f32, size: u32, rgb: [u8; 3]) {
        let (w, h) = (self.image.width as i64, self.image.height as i64);
        let s = size as i64;
        let (x0, y0) = (
            (x - s as f64 / 2.0).round() as i64,
            (y - s as f64 / 2.0).round() as i64,
        );
        for yy in y0.max(0)..(y0 + s).min(h) {
            for xx in x0.max(0)..(x0 + s).min(w) {
                let k = (yy * w + xx) as usize;
                if depth > self.depth[k] {
                    self.depth[k] = depth;
                    self.image.data[3 * k..3 * k + 3].copy_from_slice(&rgb);
                }
            }
        }
    }

    /// A 2-pixel line from `a` to `b` (pixels), over everything drawn.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), rgb: [u8; 3]) {
        let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).clamp(1, 20_000);
        for k in 0..=n {
            let f = k as f64 / n as f64;
            let (x, y) = (a.0 + (b.0 - a.0) * f, a.1 + (b.1 - a.1) * f);
            let (x, y) = (x.round() as i64, y.round() as i64);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                self.put(x + dx, y + dy, rgb);
            }
        }
    }

    /// `text` at `(x, y)` (top left) in font pixels of `scale`.
    pub fn text(&mut self, text: &str, x: i64, y: i64, scale: u32, rgb: [u8; 3]) {
        let mut px = Vec::new();
        text_pixels(text, x, y, scale, |a, b| px.push((a, b)));
        for (a, b) in px {
            self.put(a, b, rgb);
        }
    }

    /// A filled rectangle.
    pub fn rect(&mut self, x: i64, y: i64, w: i64, h: i64, rgb: [u8; 3]) {
        for yy in y..y + h {
            for xx in x..x + w {
                self.put(xx, yy, rgb);
            }
        }
    }

    /// The residual colour scale at `(x, y)` (top left), `w` x `h` pixels, labelled `0` and `max unit`, with
    /// a grey swatch for points without a counterpart.
    pub fn colour_bar(&mut self, x: i64, y: i64, w: i64, h: i64, max: f64, unit: &str) {
        let fg = [230, 230, 230];
        self.text("RESIDUAL (POINT TO PLANE)", x, y - 22, 2, fg);
        for k in 0..w {
            let c = colormap(k as f64 / (w - 1).max(1) as f64);
            self.rect(x + k, y, 1, h, c);
        }
        self.text("0", x, y + h + 6, 2, fg);
        let label = format!("{} {unit}", format_scale(max));
        let lw = text_width(&label, 2) as i64;
        self.text(&label, x + w - lw, y + h + 6, 2, fg);
        self.rect(x, y + h + 28, h, h, UNMATCHED);
        self.text(
            "NO COUNTERPART",
            x + h + 8,
            y + h + 28 + (h - 14) / 2,
            2,
            fg,
        );
    }
}

/// A scale maximum as short text (`5`, `0.5`, `0.02`).
pub fn format_scale(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// Draws the items of `scene` that belong to `view` into `canvas`; returns the number of points that fell
/// inside the image.
pub fn draw_scene(canvas: &mut Canvas, scene: &Scene, view: &str, colouring: Colouring) -> usize {
    let (w, h) = (canvas.image.width, canvas.image.height);
    let pr = Projector::new(&scene.camera, w, h);
    let items: Vec<_> = scene
        .items
        .iter()
        .filter(|i| i.views.contains(&view))
        .collect();
    let total: usize = items
        .iter()
        .map(|i| match &i.shape {
            Shape::Points { set, .. } => scene.sets[*set].points.len(),
            Shape::Lines(_) => 0,
        })
        .sum();
    let size = point_size(total, w, h);
    let mut drawn = 0;
    for it in &items {
        let Shape::Points { set, residual } = &it.shape else {
            continue;
        };
        let res = residual.map(|r| &scene.residuals[r].values);
        for (k, p) in scene.sets[*set].points.iter().enumerate() {
            let q = (it.transform * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)).coords;
            let (x, y, d) = pr.project(&q);
            if !(x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
                continue;
            }
            drawn += 1;
            let base = match (colouring, res) {
                (Colouring::ByItem, _) => it.rgb,
                (Colouring::Residual, None) => REFERENCE_GREY,
                (Colouring::Residual, Some(r)) => match r.get(k) {
                    Some(v) if !v.is_nan() => colormap(*v as f64 / scene.residual_max),
                    _ => UNMATCHED,
                },
            };
            // In residual colours the reference surface yields where the two coincide.
            let bias = if colouring == Colouring::Residual && res.is_none() {
                DEPTH_BIAS * scene.camera.depth_radius
            } else {
                0.0
            };
            canvas.splat(
                x,
                y,
                (d - bias) as f32,
                size,
                shade(base, d, scene.camera.depth_radius),
            );
        }
    }
    for it in &items {
        let Shape::Lines(segments) = &it.shape else {
            continue;
        };
        for s in segments {
            let p = |v: [f32; 3]| {
                let q = (it.transform * Point3::new(v[0] as f64, v[1] as f64, v[2] as f64)).coords;
                let (x, y, _) = pr.project(&q);
                (x, y)
            };
            canvas.line(p(s.a), p(s.b), s.rgb);
        }
    }
    drawn
}

#[cfg(test)]
mod tests {
    use super::super::scene::{Item, PointSet, PALETTE};
    use super::*;
    use nalgebra::Isometry3;

    #[test]
    fn colormap_ends_and_shading() {
        assert_eq!(colormap(0.0), COLORMAP[0]);
        assert_eq!(colormap(1.0), COLORMAP[6]);
        assert_eq!(colormap(7.0), COLORMAP[6]);
        assert_eq!(colormap(0.5), COLORMAP[3]);
        assert_eq!(shade([200, 100, 0], 1.0, 1.0), [200, 100, 0]);
        assert_eq!(shade([200, 100, 0], -1.0, 1.0), [90, 45, 0]);
        assert_eq!(format_scale(5.0), "5");
        assert_eq!(format_scale(0.02), "0.02");
    }

    #[test]
    fn a_point_lands_where_the_projection_says_and_nearer_points_win() {
        let mut sc = Scene::new("mm");
        let set = sc.add_set(PointSet::subsampled(
            "a",
            &[
                [0.0, 0.0, 0.0],
                [0.0, 0.0, 0.5],
                [1.0, 1.0, 1.0],
                [-1.0, -1.0, -1.0],
            ],
            10,
        ));
        sc.items.push(Item {
            name: "a".into(),
            shape: Shape::Points {
                set,
                residual: None,
            },
            transform: Isometry3::identity(),
            rgb: PALETTE[1],
            visible: true,
            views: vec!["refined"],
        });
        // Looking straight down: the two points on the z axis meet at the centre, the upper one wins.
        sc.camera.elevation_deg = 90.0;
        sc.fit_camera();
        let mut c = Canvas::new(64, 48);
        assert_eq!(draw_scene(&mut c, &sc, "refined", Colouring::ByItem), 4);
        let k = (24 * 64 + 32) * 3;
        let centre = &c.image.data[k..k + 3];
        let pr = Projector::new(&sc.camera, 64, 48);
        let (_, _, d) = pr.project(&Vector3::new(0.0, 0.0, 0.5));
        assert_eq!(centre, shade(PALETTE[1], d, sc.camera.depth_radius));
        assert_eq!(draw_scene(&mut c, &sc, "initial", Colouring::ByItem), 0);
    }
}
