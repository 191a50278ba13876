//! An analytic indoor-like scene sampler (floor, two walls, boxes, spheres, cylinders) and a partial-overlap
//! splitter, used by the tests, the benches and to make the sample clouds in `clouds/`.

use crate::geometry::{PointCloud, Rng};

/// A synthetic indoor-like scene with exact geometry (metres, about 3 m across): a floor, two walls, and
/// boxes, spheres and cylinders of varied sizes, sampled with about `n` points.
pub fn demo_scene(seed: u64, n: usize) -> PointCloud {
    let mut rng = Rng::new(seed);
    let mut pts = Vec::with_capacity(n);
    let area_pick = |rng: &mut Rng| rng.next_f64();
    // Object list: (kind, centre, size)
    let objects: Vec<(u8, [f64; 3], f64)> = (0..9)
        .map(|k| {
            (
                (k % 3) as u8,
                [rng.uniform(0.4, 2.6), rng.uniform(0.4, 2.6), 0.0],
                rng.uniform(0.15, 0.4),
            )
        })
        .collect();
    while pts.len() < n {
        let u = area_pick(&mut rng);
        let (a, b) = (rng.uniform(0.0, 3.0), rng.uniform(0.0, 3.0));
        let p: [f64; 3] = if u < 0.3 {
            [a, b, 0.0] // floor
        } else if u < 0.45 {
            [a, 0.0, b * 0.8] // wall y = 0
        } else if u < 0.6 {
            [0.0, a, b * 0.8] // wall x = 0
        } else {
            let (kind, c, s) = objects[rng.below(objects.len())];
            match kind {
                0 => {
                    // box of half-size (s, 0.7 s, s) standing on the floor: 5 faces
                    let (hx, hy, hz) = (s, 0.7 * s, s);
                    let (x, y) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
                    match rng.below(5) {
                        0 => [c[0] + x * hx, c[1] + y * hy, 2.0 * hz],
                        1 => [c[0] + hx, c[1] + x * hy, hz + y * hz],
                        2 => [c[0] - hx, c[1] + x * hy, hz + y * hz],
                        3 => [c[0] + x * hx, c[1] + hy, hz + y * hz],
                        _ => [c[0] + x * hx, c[1] - hy, hz + y * hz],
                    }
                }
                1 => {
                    // sphere resting on the floor
                    let d = nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal())
                        .normalize();
                    [c[0] + s * d.x, c[1] + s * d.y, s + s * d.z]
                }
                _ => {
                    // upright cylinder of radius 0.5 s, height 2.5 s, with a top cap
                    let th = rng.uniform(0.0, std::f64::consts::TAU);
                    if rng.next_f64() < 0.8 {
                        [
                            c[0] + 0.5 * s * th.cos(),
                            c[1] + 0.5 * s * th.sin(),
                            rng.uniform(0.0, 2.5 * s),
                        ]
                    } else {
                        let r = 0.5 * s * rng.next_f64().sqrt();
                        [c[0] + r * th.cos(), c[1] + r * th.sin(), 2.5 * s]
                    }
                }
            }
        };
        pts.push([p[0] as f32, p[1] as f32, p[2] as f32]);
    }
    PointCloud::from_points(pts)
}

/// Splits a cloud into two overlapping parts along a random horizontal direction, each keeping a random
/// half of its points and independent Gaussian noise of `noise` (cloud units). Returns (source, target,
/// overlap fraction of the source).
pub fn split_overlapping(
    cloud: &PointCloud,
    seed: u64,
    overlap: f64,
    noise: f64,
) -> (PointCloud, PointCloud, f64) {
    let mut rng = Rng::new(seed);
    let th = rng.uniform(0.0, std::f64::consts::TAU);
    let dir = [th.cos(), th.sin()];
    let proj: Vec<f64> = cloud
        .points
        .iter()
        .map(|p| p[0] as f64 * dir[0] + p[1] as f64 * dir[1])
        .collect();
    let mut sorted = proj.clone();
    sorted.sort_by(|a, b| a.total_cmp(b));
    let q = |f: f64| sorted[((sorted.len() - 1) as f64 * f) as usize];
    // source: [0, s_hi], target: [t_lo, 1] in quantiles, with the shared band holding `overlap` of the source.
    let s_hi = 0.5 + overlap / 2.0 * 0.6;
    let t_lo = s_hi - overlap * s_hi;
    let (a, b) = (q(s_hi), q(t_lo));
    let mut src = Vec::new();
    let mut tgt = Vec::new();
    let mut shared = 0usize;
    let jitter = |rng: &mut Rng, p: &[f32; 3]| p.map(|c| (c as f64 + noise * rng.normal()) as f32);
    for (p, &x) in cloud.points.iter().zip(&proj) {
        if x <= a && rng.next_f64() < 0.5 {
            src.push(jitter(&mut rng, p));
            if x >= b {
                shared += 1;
            }
        }
        if x >= b && rng.next_f64() < 0.5 {
            tgt.push(jitter(&mut rng, p));
        }
    }
    let frac = shared as f64 / src.len() as f64;
    (
        PointCloud::from_points(src),
        PointCloud::from_points(tgt),
        frac,
    )
}
