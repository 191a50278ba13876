//! Rendering a view of a [`Scene`]: ray-cast depth (every pixel, rayon over rows), the noise model of
//! [`NoiseConfig`], and a shaded, textured colour image of the same view.
//!
//! Each body's world bounds are projected into the image once per frame; a pixel's ray is tested only
//! against the bodies whose projected rectangle holds it. Every random draw comes from a stream seeded by the
//! frame seed and the pixel index, so a frame is bit-identical at any thread count.

use super::board::TablePrint;
use super::camera::SimCamera;
use super::convert::to_pose;
use super::noise::NoiseConfig;
use super::scene::{Appearance, RawHit, Scene, Surface};
use crate::camera::DepthImage;
use crate::error::{Error, Result};
use crate::geometry::Rng;
use nalgebra::Isometry3;
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::math::{Pose, Vector};
use parry3d_f64::query::Ray;
use rayon::prelude::*;

pub use crate::camera::{write_rgb_png, RgbImage};

/// A rendered view.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    /// The depth image (raw units of the camera's `depth_scale`, 0 = no data), after the noise model.
    pub depth: DepthImage,
    /// The ideal depth along the optical axis of each pixel's (jittered) ray, metres, before noise, range
    /// limits and quantisation; 0 where the ray hits nothing.
    pub ideal_z_m: Vec<f32>,
    /// The colour image (aligned with the depth image: same intrinsics and pose), if asked for.
    pub color: Option<RgbImage>,
}

/// Inverse of the standard normal CDF (Acklam's rational approximation, relative error < 1.2e-9).
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// A table of the inverse normal CDF at the centres of 16384 equal-probability bins: a standard normal
/// sample costs one uniform draw and a lookup (tails are cut at ±4.0 σ, a 1-in-16384 bin).
struct NormalTable(Vec<f64>);

impl NormalTable {
    const N: usize = 16384;
    fn get() -> &'static NormalTable {
        static TABLE: std::sync::OnceLock<NormalTable> = std::sync::OnceLock::new();
        TABLE.get_or_init(|| {
            NormalTable(
                (0..Self::N)
                    .map(|i| inverse_normal_cdf((i as f64 + 0.5) / Self::N as f64))
                    .collect(),
            )
        })
    }
    /// A standard normal sample (piecewise-constant inverse CDF with linear interpolation inside a bin).
    #[inline]
    fn sample(&self, rng: &mut Rng) -> f64 {
        let x = rng.next_f64() * Self::N as f64 - 0.5;
        let i = (x.floor().max(0.0) as usize).min(Self::N - 2);
        let f = (x - i as f64).clamp(0.0, 1.0);
        self.0[i] + f * (self.0[i + 1] - self.0[i])
    }
}

/// sRGB-like encoding (γ = 2.2) of a linear intensity in [0, 1] through a table.
struct Gamma(Vec<u8>);

impl Gamma {
    const N: usize = 4096;
    fn new() -> Self {
        Gamma(
            (0..=Self::N)
                .map(|i| ((i as f64 / Self::N as f64).powf(1.0 / 2.2) * 255.0).round() as u8)
                .collect(),
        )
    }
    #[inline]
    fn encode(&self, x: f64) -> u8 {
        self.0[(x.clamp(0.0, 1.0) * Self::N as f64).round() as usize]
    }
}

/// Pixel rectangle `[u0, u1] × [v0, v1]` (inclusive) of a body, or `None` when it cannot be seen.
type Rect = Option<[i32; 4]>;

/// Projects world bounds into a camera; conservative (a margin of 2 px, full image when a corner is behind
/// the camera).
fn project_rect(aabb: &Aabb, cam: &SimCamera, t_cam_world: &Pose, margin: i32) -> Rect {
    let intr = &cam.intrinsics;
    let (w, h) = (intr.width as i32, intr.height as i32);
    let full = Some([0, w - 1, 0, h - 1]);
    let distorted = intr.coeffs.iter().any(|&c| c != 0.0);
    let corners = aabb.vertices();
    // With distortion the silhouette of a box's edges bulges: sample the 12 edges.
    let mut samples: Vec<Vector> = Vec::with_capacity(if distorted { 8 + 12 * 7 } else { 8 });
    samples.extend_from_slice(&corners);
    if distorted {
        for a in 0..8usize {
            for bit in [1usize, 2, 4] {
                let b = a | bit;
                if b != a {
                    for k in 1..8 {
                        let s = k as f64 / 8.0;
                        samples.push(corners[a] * (1.0 - s) + corners[b] * s);
                    }
                }
            }
        }
    }
    let mut behind = 0;
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in &samples {
        let q = t_cam_world.transform_point(*p);
        if q.z < 1e-3 {
            behind += 1;
            continue;
        }
        let [u, v] = intr.project([q.x, q.y, q.z]);
        u0 = u0.min(u);
        u1 = u1.max(u);
        v0 = v0.min(v);
        v1 = v1.max(v);
    }
    if behind == samples.len() {
        return None;
    }
    if behind > 0 || distorted && (u1 - u0 > 4.0 * w as f64) {
        return full;
    }
    let r = [
        (u0.floor() as i32 - margin).max(0),
        (u1.ceil() as i32 + margin).min(w - 1),
        (v0.floor() as i32 - margin).max(0),
        (v1.ceil() as i32 + margin).min(h - 1),
    ];
    (r[0] <= r[1] && r[2] <= r[3]).then_some(r)
}

/// Rectangles of every body for a camera at `t_world_cam`.
fn body_rects(scene: &Scene, cam: &SimCamera, t_world_cam: &Pose) -> Vec<(usize, [i32; 4])> {
    let t_cam_world = t_world_cam.inverse();
    (0..scene.body_count())
        .filter_map(|i| project_rect(scene.body_aabb(i), cam, &t_cam_world, 2).map(|r| (i, r)))
        .collect()
}

#[inline]
fn in_rect(r: &[i32; 4], u: i32, v: i32) -> bool {
    u >= r[0] && u <= r[1] && v >= r[2] && v <= r[3]
}

/// What the first pass stores per pixel.
#[derive(Clone, Copy, Default)]
struct PixelHit {
    /// Ideal depth along the optical axis, metres (0 = no hit).
    z: f64,
    /// |cos| of the incidence angle.
    cos: f32,
    /// Not seen by the second imager.
    shadow: bool,
    rgb: [u8; 3],
}

fn hash3(seed: u64, x: i64, y: i64, z: i64) -> f64 {
    let mut h = seed
        ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth 3-D value noise in [0, 1).
fn value_noise(seed: u64, p: Vector) -> f64 {
    let (fx, fy, fz) = (p.x.floor(), p.y.floor(), p.z.floor());
    let (tx, ty, tz) = (p.x - fx, p.y - fy, p.z - fz);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy, sz) = (s(tx), s(ty), s(tz));
    let (ix, iy, iz) = (fx as i64, fy as i64, fz as i64);
    let mut acc = 0.0;
    for c in 0..8 {
        let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let wgt = (if dx == 1 { sx } else { 1.0 - sx })
            * (if dy == 1 { sy } else { 1.0 - sy })
            * (if dz == 1 { sz } else { 1.0 - sz });
        acc += wgt * hash3(seed, ix + dx as i64, iy + dy as i64, iz + dz as i64);
    }
    acc
}

/// Albedo of a surface point given in object coordinates.
fn albedo(a: &Appearance, p: Vector) -> [f64; 3] {
    if a.texture {
        return textured_albedo(a, p);
    }
    let c = a.checker_m;
    let q = p / c;
    let parity = (q.x.floor() as i64 + q.y.floor() as i64 + q.z.floor() as i64).rem_euclid(2);
    let base = a.albedo[parity as usize];
    let n = value_noise(a.pattern_seed, q * 2.3);
    let f = 0.6 + 0.7 * n;
    [base[0] as f64 * f, base[1] as f64 * f, base[2] as f64 * f]
}

/// The distinctive texture: value noise at 25, 11 and 5 mm, contrast-stretched between the two albedos
/// (blobs of every size, no repetition: what keypoint detectors and descriptors need).
fn textured_albedo(a: &Appearance, p: Vector) -> [f64; 3] {
    let s = a.pattern_seed;
    let n = 0.5 * value_noise(s, p / 0.025)
        + 0.3 * value_noise(s ^ 0x7E37, p / 0.011)
        + 0.2 * value_noise(s ^ 0x5A5A, p / 0.005);
    let t = ((n - 0.32) / 0.36).clamp(0.0, 1.0);
    let t = t * t * (3.0 - 2.0 * t);
    let [c1, c2] = a.albedo;
    [0, 1, 2].map(|k| c2[k] as f64 + t * (c1[k] as f64 - c2[k] as f64))
}

/// Shading of a hit; `grey` replaces the surface's albedo (the board's pixel coverage).
fn shade(
    scene: &Scene,
    gamma: &Gamma,
    hit: &RawHit,
    p_world: Vector,
    dir: Vector,
    grey: Option<f64>,
) -> [u8; 3] {
    let (look, inv) = scene.surface_look(hit.surface);
    let p_obj = match hit.surface {
        Surface::Floor => p_world * 0.5,
        _ => inv.transform_point(p_world),
    };
    let a = grey.map_or_else(|| albedo(look, p_obj), |g| [g; 3]);
    let key = Vector::new(0.3, -0.4, 1.0).normalize();
    let n = hit.normal;
    let light = 0.18 + 0.55 * n.dot(key).max(0.0) + 0.35 * n.dot(-dir).max(0.0);
    [
        gamma.encode(a[0] * light),
        gamma.encode(a[1] * light),
        gamma.encode(a[2] * light),
    ]
}

/// Renders the view of a camera at `t_world_cam` (world = table frame, metres): ray-cast depth with the
/// noise model `noise`, seeded by `seed`, and optionally the colour image. Parallel over rows; the result is
/// bit-identical at any thread count.
pub fn render_frame(
    scene: &Scene,
    cam: &SimCamera,
    t_world_cam: &Isometry3<f64>,
    noise: &NoiseConfig,
    seed: u64,
    with_color: bool,
) -> Result<RenderedFrame> {
    noise.validate()?;
    let intr = &cam.intrinsics;
    intr.validate()
        .map_err(|m| Error::InvalidInput(format!("simulated camera intrinsics: {m}")))?;
    let (w, h) = (intr.width as usize, intr.height as usize);
    let pose = to_pose(t_world_cam);
    let rects = body_rects(scene, cam, &pose);
    // The second imager, for stereo shadows.
    let pose2 = pose * Pose::from_translation(Vector::new(cam.baseline_m, 0.0, 0.0));
    let inv2 = pose2.inverse();
    let rects2 = if noise.stereo_shadow {
        body_rects(scene, cam, &pose2)
    } else {
        Vec::new()
    };
    let origin = pose.translation;
    let origin2 = pose2.translation;
    let jitter = noise.lateral_sigma_px;
    let max_t = cam.max_depth_m * 4.0;
    let gamma = Gamma::new();
    let normals = NormalTable::get();
    // Without distortion coefficients the ray is the pinhole ray whatever the model.
    let pinhole = intr.coeffs.iter().all(|&c| c == 0.0);
    let (fx, fy, ppx, ppy) = (intr.fx, intr.fy, intr.ppx, intr.ppy);

    let mut pass1 = vec![PixelHit::default(); w * h];
    pass1.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut ids: Vec<usize> = Vec::with_capacity(rects.len());
        for (u, px) in row.iter_mut().enumerate() {
            let idx = (v * w + u) as u64;
            let (mut du, mut dv) = (0.0, 0.0);
            if jitter > 0.0 {
                let mut rng = Rng::stream(seed, idx);
                du = (jitter * normals.sample(&mut rng)).clamp(-1.0, 1.0);
                dv = (jitter * normals.sample(&mut rng)).clamp(-1.0, 1.0);
            }
            let (pu, pv) = (u as f64 + du, v as f64 + dv);
            let [x, y] = if pinhole {
                [(pu - ppx) / fx, (pv - ppy) / fy]
            } else {
                intr.pixel_ray([pu, pv])
            };
            let d_cam = Vector::new(x, y, 1.0).normalize();
            let dir = pose.rotation * d_cam;
            let ray = Ray::new(origin, dir);
            ids.clear();
            ids.extend(
                rects
                    .iter()
                    .filter(|(_, r)| in_rect(r, u as i32, v as i32))
                    .map(|(i, _)| *i),
            );
            let Some(hit) = scene.cast_bodies(&ray, ids.iter().copied(), max_t) else {
                if with_color {
                    px.rgb = [18, 18, 22];
                }
                continue;
            };
            let p = origin + dir * hit.t;
            px.z = hit.t * d_cam.z;
            px.cos = hit.normal.dot(-dir).abs() as f32;
            if noise.stereo_shadow {
                px.shadow = shadowed(scene, cam, &inv2, origin2, &rects2, p);
            }
            if with_color {
                // Prints on the table top (the board, the markers): pixel coverage from the pixel centre's
                // footprint.
                let on_top = hit.surface == Surface::Table && hit.normal.z > 0.5;
                let table = |x: f64, y: f64| {
                    let a = albedo(&scene.table_appearance, Vector::new(x, y, 0.0));
                    0.299 * a[0] + 0.587 * a[1] + 0.114 * a[2]
                };
                let (uf, vf) = (u as f64, v as f64);
                let grey = if on_top {
                    scene
                        .board
                        .as_ref()
                        .and_then(|b| b.pixel_albedo(intr, t_world_cam, uf, vf, &table))
                        .or_else(|| {
                            scene
                                .markers
                                .as_ref()
                                .and_then(|m| m.pixel_albedo(intr, t_world_cam, uf, vf, &table))
                        })
                } else {
                    None
                };
                px.rgb = shade(scene, &gamma, &hit, p, dir, grey);
            }
        }
    });

    // Pass 2: the noise model.
    let mut depth = DepthImage::zeros(intr.width, intr.height);
    let mut ideal = vec![0f32; w * h];
    let scale = intr.depth_scale;
    let ideal_noise = noise.is_ideal();
    let noise_seed = seed ^ 0xD1F7_5EED_0000_0001;
    depth
        .data
        .par_chunks_mut(w)
        .zip(ideal.par_chunks_mut(w))
        .enumerate()
        .for_each(|(v, (drow, irow))| {
            for u in 0..w {
                let px = &pass1[v * w + u];
                irow[u] = px.z as f32;
                if px.z <= 0.0 {
                    continue;
                }
                let mut z = px.z;
                if !ideal_noise {
                    if px.shadow {
                        continue;
                    }
                    let mut rng = Rng::stream(noise_seed, (v * w + u) as u64);
                    let (r_graze, r_drop, r_fly, r_mix) = (
                        rng.next_f64(),
                        rng.next_f64(),
                        rng.next_f64(),
                        rng.next_f64(),
                    );
                    if r_graze < noise.grazing_drop_prob(px.cos as f64)
                        || r_drop < noise.dropout_prob
                    {
                        continue;
                    }
                    if noise.flying_prob > 0.0 && r_fly < noise.flying_prob {
                        let (mut lo, mut hi) = (z, z);
                        for vv in v.saturating_sub(1)..=(v + 1).min(h - 1) {
                            for uu in u.saturating_sub(1)..=(u + 1).min(w - 1) {
                                let q = pass1[vv * w + uu].z;
                                if q > 0.0 {
                                    lo = lo.min(q);
                                    hi = hi.max(q);
                                }
                            }
                        }
                        if hi - lo > noise.flying_jump * z {
                            z = r_mix * lo + (1.0 - r_mix) * hi;
                        }
                    }
                    z += noise.axial_sigma(z) * normals.sample(&mut rng);
                }
                if z < cam.min_depth_m || z > cam.max_depth_m {
                    continue;
                }
                let raw = (z / scale).round();
                if raw >= 1.0 && raw <= u16::MAX as f64 {
                    drow[u] = raw as u16;
                }
            }
        });

    let color = with_color.then(|| {
        let mut data = vec![0u8; w * h * 3];
        let color_seed = seed ^ 0xC010_0125_EED0_0002;
        let grain = if ideal_noise { 0.0 } else { 1.5 };
        // Optics blur, in scenes with prints (the others render as before).
        let sigma = scene
            .board
            .as_ref()
            .map(|b| b.config.blur_sigma_px)
            .into_iter()
            .chain(scene.markers.as_ref().map(|m| m.config.blur_sigma_px))
            .fold(0.0, f64::max);
        let blurred = (sigma > 0.0).then(|| {
            let rgb: Vec<u8> = pass1.iter().flat_map(|p| p.rgb).collect();
            super::board::gaussian_blur(&rgb, w, h, 3, sigma)
        });
        data.par_chunks_mut(w * 3).enumerate().for_each(|(v, row)| {
            for u in 0..w {
                let px = &pass1[v * w + u];
                let value = |k: usize| match &blurred {
                    Some(b) => b[(v * w + u) * 3 + k] as f64,
                    None => px.rgb[k] as f64,
                };
                if grain > 0.0 {
                    // Sensor grain: one small offset per pixel, the same on the three channels.
                    let mut rng = Rng::stream(color_seed, (v * w + u) as u64);
                    let g = grain * normals.sample(&mut rng);
                    for k in 0..3 {
                        row[u * 3 + k] = (value(k) + g).round().clamp(0.0, 255.0) as u8;
                    }
                } else if blurred.is_some() {
                    for k in 0..3 {
                        row[u * 3 + k] = value(k).round().clamp(0.0, 255.0) as u8;
                    }
                } else {
                    row[u * 3..u * 3 + 3].copy_from_slice(&px.rgb);
                }
            }
        });
        RgbImage {
            width: intr.width,
            height: intr.height,
            data,
        }
    });

    Ok(RenderedFrame {
        depth,
        ideal_z_m: ideal,
        color,
    })
}

/// True when the world point `p` (on a surface) is hidden from the second imager or outside its image.
fn shadowed(
    scene: &Scene,
    cam: &SimCamera,
    inv2: &Pose,
    origin2: Vector,
    rects2: &[(usize, [i32; 4])],
    p: Vector,
) -> bool {
    let q = inv2.transform_point(p);
    if q.z <= 1e-3 {
        return true;
    }
    let intr = &cam.intrinsics;
    let [u2, v2] = intr.project([q.x, q.y, q.z]);
    if u2 < -0.5 || v2 < -0.5 || u2 > intr.width as f64 - 0.5 || v2 > intr.height as f64 - 0.5 {
        return true;
    }
    let (ui, vi) = (u2.round() as i32, v2.round() as i32);
    let dir = p - origin2;
    let ray = Ray::new(origin2, dir);
    let len = dir.length();
    // Stop 0.5 mm short of the point so that its own surface does not count.
    let max_t = 1.0 - 5e-4 / len;
    let ids = rects2
        .iter()
        .filter(|(_, r)| in_rect(r, ui, vi))
        .map(|(i, _)| *i);
    scene.cast_bodies(&ray, ids, max_t).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::camera::Resolution;
    use crate::sim::scene::SceneConfig;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn looking_down(h: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.0, 0.0, h),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
        )
    }

    #[test]
    fn stereo_shadow_band_is_the_disparity_wide() {
        let scene = Scene::random(
            &SceneConfig {
                objects: 0,
                ..Default::default()
            },
            1,
        )
        .unwrap();
        let cam = SimCamera::d435(Resolution::Vga);
        let noise = NoiseConfig {
            stereo_shadow: true,
            ..NoiseConfig::none()
        };
        let f = render_frame(&scene, &cam, &looking_down(0.5), &noise, 1, false).unwrap();
        // The band of pixels the second imager cannot see: f·b/z = 382.6 · 0.05 / 0.5 ≈ 38 px.
        let row = &f.depth.data[240 * 640..241 * 640];
        let first = row.iter().position(|&d| d != 0).unwrap();
        assert!((37..=40).contains(&first), "{first}");
        assert!(row[first..].iter().all(|&d| d == 500));
    }

    #[test]
    fn normal_table_is_standard() {
        let t = NormalTable::get();
        let mut rng = Rng::new(9);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| t.sample(&mut rng)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.02,
            "{mean} {var}"
        );
        assert!((inverse_normal_cdf(0.975) - 1.959964).abs() < 1e-6);
    }
}
