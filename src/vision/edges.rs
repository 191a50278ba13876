//! Sub-pixel marker corners from the four edges of the black square: each edge is located across its
//! length on the image gradient and fitted with a line, and the corners are the intersections of adjacent
//! lines (the idea of AprilTag's `refine_edges`, for any detector's quadrilateral).
//!
//! Unlike `cornerSubPix`, which needs a symmetric neighbourhood and is biased on the blurred L-shaped
//! corner of a marker (0.2 px on the unit tests' synthetic markers), the edge fit uses only the straight
//! parts of the outline.

use super::image::GreyImage;
use nalgebra::{Matrix2, Point2, Vector2};

/// Bilinear grey value at `p`, or `None` outside the image.
fn sample(img: &GreyImage, p: Point2<f64>) -> Option<f64> {
    let (w, h) = (img.width as f64, img.height as f64);
    if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= w - 1.0 && p.y <= h - 1.0) {
        return None;
    }
    let (x0, y0) = (p.x.floor(), p.y.floor());
    let (fx, fy) = (p.x - x0, p.y - y0);
    let (x0, y0) = (x0 as u32, y0 as u32);
    let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
    let g = |u, v| img.at(u, v) as f64;
    Some(
        (1.0 - fy) * ((1.0 - fx) * g(x0, y0) + fx * g(x1, y0))
            + fy * ((1.0 - fx) * g(x0, y1) + fx * g(x1, y1)),
    )
}

/// A line `n·x = d` with unit normal `n`.
#[derive(Clone, Copy, Debug)]
struct Line {
    n: Vector2<f64>,
    d: f64,
}

fn intersect(a: Line, b: Line) -> Option<Point2<f64>> {
    // Nearly parallel edges (under ~6°) give no usable corner.
    if (a.n.x * b.n.y - a.n.y * b.n.x).abs() < 0.1 {
        return None;
    }
    let m = Matrix2::new(a.n.x, a.n.y, b.n.x, b.n.y);
    Some(Point2::from(m.try_inverse()? * Vector2::new(a.d, b.d)))
}

/// The edge from `a` to `b` located on the image: `samples` points along it (the middle 80%), each
/// moved across the edge to the gradient-weighted centre of the dark-to-light step within `range` px,
/// then a total-least-squares line. `out` is the unit normal pointing out of the marker (towards white).
fn fit_edge(
    img: &GreyImage,
    a: Point2<f64>,
    b: Point2<f64>,
    out: Vector2<f64>,
    range: f64,
) -> Option<Line> {
    let len = (b - a).norm();
    let samples = ((len / 2.0).round() as usize).clamp(6, 64);
    let step = 0.25;
    let steps = (range / step).round() as i64;
    let mut pts: Vec<(Point2<f64>, f64)> = Vec::with_capacity(samples);
    for s in 0..samples {
        let t = 0.1 + 0.8 * (s as f64 + 0.5) / samples as f64;
        let p = a + (b - a) * t;
        let (mut m, mut wsum) = (0.0, 0.0);
        for k in -steps..=steps {
            let o = k as f64 * step;
            // Derivative along the outward normal: central difference over ±0.5 px.
            let (Some(hi), Some(lo)) = (
                sample(img, p + out * (o + 0.5)),
                sample(img, p + out * (o - 0.5)),
            ) else {
                continue;
            };
            let g = hi - lo;
            if g > 0.0 {
                m += g * o;
                wsum += g;
            }
        }
        if wsum > 0.0 {
            pts.push((p + out * (m / wsum), wsum));
        }
    }
    if pts.len() < samples / 2 || pts.len() < 4 {
        return None;
    }
    let wt: f64 = pts.iter().map(|q| q.1).sum();
    let c = pts
        .iter()
        .fold(Vector2::zeros(), |acc, q| acc + q.0.coords * q.1)
        / wt;
    let mut cov = Matrix2::zeros();
    for (p, w) in &pts {
        let d = p.coords - c;
        cov += d * d.transpose() * *w;
    }
    let e = cov.symmetric_eigen();
    // The normal is the direction of least spread.
    let k = if e.eigenvalues[0] < e.eigenvalues[1] {
        0
    } else {
        1
    };
    let n: Vector2<f64> = e.eigenvectors.column(k).into_owned();
    let n = if n.dot(&out) < 0.0 { -n } else { n };
    Some(Line { n, d: n.dot(&c) })
}

/// Refines the quadrilateral `c` (corners in order around the marker, either sense) of a marker with
/// `cells` cells per side (border included), `passes` times (each pass starts from the last one's
/// corners); corners that cannot be refined, or would end more than `max_move_px` from where they
/// started, are kept.
pub(crate) fn refine_quad(
    img: &GreyImage,
    c: &mut [Point2<f64>; 4],
    cells: u32,
    passes: u32,
    max_move_px: f64,
) {
    let start = *c;
    for _ in 0..passes {
        let mut next = *c;
        refine_once(img, &mut next, cells);
        *c = next;
    }
    for k in 0..4 {
        let moved = (c[k] - start[k]).norm();
        if moved.is_nan() || moved > max_move_px {
            c[k] = start[k];
        }
    }
}

fn refine_once(img: &GreyImage, c: &mut [Point2<f64>; 4], cells: u32) {
    let centre = Point2::from(c.iter().fold(Vector2::zeros(), |a, p| a + p.coords) / 4.0);
    let shortest = (0..4)
        .map(|k| (c[(k + 1) % 4] - c[k]).norm())
        .fold(f64::MAX, f64::min);
    // Stay within the one-cell black border so that the edge between the border and a white data cell is
    // never taken for the outline.
    let cell = shortest / cells as f64;
    let range = (0.45 * cell).clamp(0.75, 3.0);
    let lines: Vec<Option<Line>> = (0..4)
        .map(|k| {
            let (a, b) = (c[k], c[(k + 1) % 4]);
            let d = (b - a).normalize();
            let mut out = Vector2::new(-d.y, d.x);
            if out.dot(&(Point2::from((a.coords + b.coords) / 2.0) - centre)) < 0.0 {
                out = -out;
            }
            fit_edge(img, a, b, out, range)
        })
        .collect();
    for k in 0..4 {
        // Corner k joins edge k−1 (into it) and edge k (out of it).
        let (Some(l0), Some(l1)) = (lines[(k + 3) % 4], lines[k]) else {
            continue;
        };
        if let Some(p) = intersect(l0, l1) {
            c[k] = p;
        }
    }
}
