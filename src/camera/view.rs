//! A frame's depth at low resolution with the camera's pose: what a camera saw, kept small enough to test
//! many points against many frames (visibility, free space).

use crate::camera::{DepthImage, Intrinsics};
use nalgebra::{Isometry3, Point3};

/// Per block of `block × block` pixels, the nearest and farthest valid depth (metres; 0 where the block has
/// no data) and which of its pixels have data, with the camera's intrinsics and `T_cam_base`.
#[derive(Clone, Debug)]
pub struct DepthView {
    /// Maps base-frame points into the camera frame.
    pub t_cam_base: Isometry3<f64>,
    /// The full-resolution intrinsics.
    pub intrinsics: Intrinsics,
    /// Block edge, pixels.
    pub block: u32,
    /// Blocks per row and per column.
    pub size: [u32; 2],
    /// Nearest valid depth of each block (metres, 0 = none), row-major.
    pub near: Vec<f32>,
    /// Farthest valid depth of each block (metres, 0 = none), row-major.
    pub far: Vec<f32>,
    /// Per block, one bit per pixel with data (bit `row · block + column` within the block), row-major;
    /// empty when blocks hold more than 64 pixels (then a block with data counts as data in every pixel).
    /// A point that falls on a pixel without depth is [`Seen::Unknown`]: no depth is not free space (a
    /// dark or steep surface, a thin edge, a hole).
    pub valid: Vec<u64>,
}

/// Blocks of at most this edge keep a per-pixel validity mask ([`DepthView::valid`]).
pub const MAX_MASKED_BLOCK: u32 = 8;

/// Where a point falls in a view.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(u8)]
pub enum Seen {
    /// Outside the image, behind the camera, or on a block without depth: the view says nothing.
    Unknown,
    /// In front of everything the camera saw along that line of sight by more than the margin: the camera
    /// looked through it, so nothing can be there.
    FreeSpace,
    /// Within the margin of the depths the block saw.
    Surface,
    /// Behind what the camera saw: hidden from it.
    Occluded,
}

impl DepthView {
    /// Reduces `depth` (whose size must match `intrinsics`) to blocks of `block` pixels.
    pub fn new(
        depth: &DepthImage,
        intrinsics: &Intrinsics,
        t_base_cam: &Isometry3<f64>,
        block: u32,
    ) -> Self {
        let block = block.max(1);
        let (w, h) = (depth.width, depth.height);
        let size = [w.div_ceil(block), h.div_ceil(block)];
        let n = (size[0] * size[1]) as usize;
        let mut near = vec![f32::INFINITY; n];
        let mut far = vec![0f32; n];
        let masked = block <= MAX_MASKED_BLOCK;
        let mut valid = vec![0u64; if masked { n } else { 0 }];
        let scale = intrinsics.depth_scale as f32;
        // Row by row, `block` pixels at a time: no integer division per pixel.
        let rows = depth.data.chunks_exact(w.max(1) as usize).take(h as usize);
        for (v, row) in rows.enumerate().filter(|_| w > 0) {
            let first = (v as u32 / block * size[0]) as usize;
            let row_bit = (v as u32 % block) * block;
            for (bu, run) in row.chunks(block as usize).enumerate() {
                let k = first + bu;
                let mut bits = 0u64;
                for (j, &d) in run.iter().enumerate() {
                    if d == 0 {
                        continue;
                    }
                    let z = d as f32 * scale;
                    near[k] = near[k].min(z);
                    far[k] = far[k].max(z);
                    bits |= 1 << j;
                }
                if masked {
                    valid[k] |= bits << row_bit;
                }
            }
        }
        for z in &mut near {
            if !z.is_finite() {
                *z = 0.0;
            }
        }
        DepthView {
            t_cam_base: t_base_cam.inverse(),
            intrinsics: intrinsics.clone(),
            block,
            size,
            near,
            far,
            valid,
        }
    }

    /// Classifies a base-frame point with a depth margin `margin` (metres): against its block's nearest
    /// and farthest depth, and [`Seen::Unknown`] when its own pixel has no depth.
    pub fn classify(&self, p_base: &Point3<f64>, margin: f64) -> Seen {
        let p = self.t_cam_base * p_base;
        if p.z <= 1e-3 {
            return Seen::Unknown;
        }
        let [u, v] = self.intrinsics.project([p.x, p.y, p.z]);
        let (w, h) = (self.intrinsics.width as f64, self.intrinsics.height as f64);
        if !(u >= -0.5 && v >= -0.5 && u < w - 0.5 && v < h - 0.5) {
            return Seen::Unknown;
        }
        let (pu, pv) = ((u + 0.5) as u32, (v + 0.5) as u32);
        let (bu, bv) = (
            (pu / self.block).min(self.size[0] - 1),
            (pv / self.block).min(self.size[1] - 1),
        );
        let k = (bv * self.size[0] + bu) as usize;
        let (near, far) = (self.near[k] as f64, self.far[k] as f64);
        if near <= 0.0 {
            return Seen::Unknown;
        }
        if let Some(bits) = self.valid.get(k) {
            let bit = (pv - bv * self.block) * self.block + (pu - bu * self.block);
            if bit < 64 && bits & (1 << bit) == 0 {
                return Seen::Unknown;
            }
        }
        if p.z < near - margin {
            Seen::FreeSpace
        } else if p.z <= far + margin {
            Seen::Surface
        } else {
            Seen::Occluded
        }
    }

    /// [`Self::classify`] of each base-frame point `(x[i], y[i], z[i])` into `out[i]`, bit for bit (test
    /// `classify_many_is_classify`): the same arithmetic without branches, many points at once, in the
    /// widest vector instructions the CPU has, where the view allows (no lens distortion, a power-of-two
    /// block, blocks that match the image); else point by point. The slices must be as long as `out`.
    pub fn classify_many(&self, x: &[f64], y: &[f64], z: &[f64], margin: f64, out: &mut [Seen]) {
        let n = out.len();
        assert!(
            x.len() == n && y.len() == n && z.len() == n,
            "classify_many: coordinate slices of {}, {}, {} for {n} results",
            x.len(),
            y.len(),
            z.len()
        );
        match BlockLookup::of(self) {
            Some(lut) if lut.masked => classify_masked(self, &lut, [x, y, z], margin, out),
            Some(lut) => classify_unmasked(self, &lut, [x, y, z], margin, out),
            None => {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = self.classify(&Point3::new(x[i], y[i], z[i]), margin);
                }
            }
        }
    }
}

/// What [`DepthView::classify_many`]'s vector path needs of a view, checked: the block's size as a shift,
/// the blocks per row and column (at least one each, their product the length of `near`, `far` and, when
/// masked, `valid`), and whether pixels are masked.
struct BlockLookup {
    shift: u32,
    cols: u32,
    rows: u32,
    masked: bool,
}

impl BlockLookup {
    /// `None` where the vector path would not be [`DepthView::classify`] (a lens distortion, a block size
    /// that is not a power of two) or could read outside the tables (sizes that do not match).
    fn of(view: &DepthView) -> Option<Self> {
        let [cols, rows] = view.size;
        let blocks = (cols as usize).checked_mul(rows as usize)?;
        let masked = !view.valid.is_empty();
        let fits = blocks > 0
            && view.near.len() == blocks
            && view.far.len() == blocks
            && (!masked || view.valid.len() == blocks);
        let plain = crate::camera::distortion::undistort_is_identity(
            view.intrinsics.model,
            &view.intrinsics.coeffs,
        );
        (fits && plain && view.block.is_power_of_two()).then_some(BlockLookup {
            shift: view.block.trailing_zeros(),
            cols,
            rows,
            masked,
        })
    }
}

crate::simd::dispatch_simd! {
    /// [`classify_many_generic`] with a per-pixel mask.
    fn classify_masked(view: &DepthView, lut: &BlockLookup, xyz: [&[f64]; 3], margin: f64, out: &mut [Seen])
        = classify_many_generic::<true>;
}

crate::simd::dispatch_simd! {
    /// [`classify_many_generic`] without a per-pixel mask.
    fn classify_unmasked(view: &DepthView, lut: &BlockLookup, xyz: [&[f64]; 3], margin: f64, out: &mut [Seen])
        = classify_many_generic::<false>;
}

/// The body of [`DepthView::classify_many`]'s vector path: [`DepthView::classify`]'s steps for every point,
/// each choice a select. The rotation is nalgebra's `UnitQuaternion × Point3` written out (`t = 2 (u × p)`,
/// `t·w + u × t + p`), then the translation; projection as [`Intrinsics::project`] without distortion.
/// Points that fall outside the image look up block 0 and are then called unknown.
#[inline(always)]
fn classify_many_generic<const MASKED: bool>(
    view: &DepthView,
    lut: &BlockLookup,
    [x, y, z]: [&[f64]; 3],
    margin: f64,
    out: &mut [Seen],
) {
    let q = view.t_cam_base.rotation.quaternion();
    let (ux, uy, uz, w) = (q.i, q.j, q.k, q.w);
    let tr = view.t_cam_base.translation.vector;
    let intr = &view.intrinsics;
    let (fx, fy, ppx, ppy) = (intr.fx, intr.fy, intr.ppx, intr.ppy);
    let (wl, hl) = (intr.width as f64 - 0.5, intr.height as f64 - 0.5);
    let (shift, cols, rows, block) = (lut.shift, lut.cols, lut.rows, view.block);
    let (near, far, valid) = (&view.near[..], &view.far[..], &view.valid[..]);
    let n = out.len();
    let (x, y, z) = (&x[..n], &y[..n], &z[..n]);
    for i in 0..n {
        let (px, py, pz) = (x[i], y[i], z[i]);
        let tx = (uy * pz - uz * py) * 2.0;
        let ty = (uz * px - ux * pz) * 2.0;
        let tz = (ux * py - uy * px) * 2.0;
        let cx = uy * tz - uz * ty;
        let cy = uz * tx - ux * tz;
        let cz = ux * ty - uy * tx;
        let rx = tx * w + cx + px + tr.x;
        let ry = ty * w + cy + py + tr.y;
        let rz = tz * w + cz + pz + tr.z;
        let u = rx / rz * fx + ppx;
        let v = ry / rz * fy + ppy;
        let inside = (rz > 1e-3) & (u >= -0.5) & (v >= -0.5) & (u < wl) & (v < hl);
        let (pu, pv) = if inside {
            ((u + 0.5) as u32, (v + 0.5) as u32)
        } else {
            (0, 0)
        };
        let (bu, bv) = ((pu >> shift).min(cols - 1), (pv >> shift).min(rows - 1));
        let k = (bv * cols + bu) as usize;
        // SAFETY: bu < cols and bv < rows, so k < cols · rows, the length of `near`, `far` and (masked)
        // `valid` ([`BlockLookup::of`]).
        let (nr, fr) = unsafe { (*near.get_unchecked(k) as f64, *far.get_unchecked(k) as f64) };
        let pixel = if MASKED {
            // SAFETY: as above.
            let bits = unsafe { *valid.get_unchecked(k) };
            let bit = (pv - bv * block) * block + (pu - bu * block);
            (bit >= 64) | ((bits >> (bit & 63)) & 1 != 0)
        } else {
            true
        };
        out[i] = if !inside | (nr <= 0.0) | !pixel {
            Seen::Unknown
        } else if rz < nr - margin {
            Seen::FreeSpace
        } else if rz <= fr + margin {
            Seen::Surface
        } else {
            Seen::Occluded
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classifies_free_space_surface_and_occlusion() {
        let intr = Intrinsics::pinhole(64, 48, 50.0, 50.0, 31.5, 23.5);
        let mut img = DepthImage::zeros(64, 48);
        for (i, d) in img.data.iter_mut().enumerate() {
            // Left half at 1 m, right half at 2 m, one hole block.
            *d = if i % 64 < 32 { 1000 } else { 2000 };
        }
        for v in 0..4 {
            for u in 0..4 {
                img.data[v * 64 + u] = 0;
            }
        }
        let view = DepthView::new(&img, &intr, &Isometry3::identity(), 4);
        let at = |u: f64, v: f64, z: f64| {
            let p = intr.deproject([u, v], z);
            view.classify(&Point3::new(p[0], p[1], p[2]), 0.05)
        };
        assert_eq!(at(10.0, 20.0, 0.5), Seen::FreeSpace);
        assert_eq!(at(10.0, 20.0, 1.02), Seen::Surface);
        assert_eq!(at(10.0, 20.0, 1.5), Seen::Occluded);
        assert_eq!(at(50.0, 20.0, 1.5), Seen::FreeSpace);
        assert_eq!(at(1.0, 1.0, 0.5), Seen::Unknown);
        assert_eq!(
            view.classify(&Point3::new(0.0, 0.0, -1.0), 0.05),
            Seen::Unknown
        );
        assert_eq!(
            view.classify(&Point3::new(100.0, 0.0, 1.0), 0.05),
            Seen::Unknown
        );
    }

    /// The batch classification is the point-by-point one, bit for bit: random points around and inside a
    /// tilted camera's frustum (behind it, outside the image, on holes, near the block and image edges),
    /// every block size from 1 to 16 (shifted and masked, shifted without a mask, and the point-by-point
    /// fallback of sizes that are not powers of two), with and without lens distortion.
    #[test]
    fn classify_many_is_classify() {
        use crate::camera::distortion::DistortionModel;
        let mut intr = Intrinsics::pinhole(61, 47, 52.0, 49.0, 30.2, 22.7);
        let mut img = DepthImage::zeros(61, 47);
        let mut rng = crate::geometry::rng::Rng::new(7);
        let mut rnd = move || rng.next_f64();
        for d in img.data.iter_mut() {
            // Depth from 0.8 to 2.0 m, a tenth of the pixels without depth.
            *d = if rnd() < 0.1 {
                0
            } else {
                (800.0 + 1200.0 * rnd()) as u16
            };
        }
        let pose = Isometry3::new(
            nalgebra::Vector3::new(0.3, -0.2, 0.5),
            nalgebra::Vector3::new(0.4, -0.7, 0.2),
        );
        let mut points = Vec::new();
        for _ in 0..4000 {
            let (u, v) = (-10.0 + 81.0 * rnd(), -10.0 + 67.0 * rnd());
            let depth = -0.5 + 3.0 * rnd();
            let c = intr.deproject([u, v], depth);
            points.push(pose * Point3::new(c[0], c[1], c[2]));
        }
        // Exactly on the image's edges and on the near-depth limit.
        for (u, v, depth) in [
            (-0.5, 3.0, 1.0),
            (60.5, 3.0, 1.0),
            (3.0, 46.5, 1.0),
            (5.0, 5.0, 1e-3),
        ] {
            let c = intr.deproject([u, v], depth);
            points.push(pose * Point3::new(c[0], c[1], c[2]));
        }
        let (x, y, z): (Vec<f64>, Vec<f64>, Vec<f64>) = (
            points.iter().map(|p| p.x).collect(),
            points.iter().map(|p| p.y).collect(),
            points.iter().map(|p| p.z).collect(),
        );
        let mut kinds = [0usize; 4];
        for distorted in [false, true] {
            if distorted {
                intr.model = DistortionModel::BrownConrady;
                intr.coeffs = [0.05, -0.01, 0.001, 0.0, 0.0];
            }
            for block in 1..=16u32 {
                let view = DepthView::new(&img, &intr, &pose, block);
                for margin in [0.0, 0.02] {
                    let mut many = vec![Seen::Unknown; points.len()];
                    view.classify_many(&x, &y, &z, margin, &mut many);
                    for (p, got) in points.iter().zip(&many) {
                        assert_eq!(*got, view.classify(p, margin), "block {block} at {p:?}");
                        kinds[*got as usize] += 1;
                    }
                }
            }
        }
        // Every kind of answer was tested, many times.
        assert!(kinds.iter().all(|&k| k > 500), "{kinds:?}");
    }

    /// A pixel without depth is unknown even where the rest of its block has depth; its neighbours in the
    /// block still see through a point in front of them. Every block size up to the masked limit, and a
    /// larger one (no mask: the block's depth stands for all its pixels).
    #[test]
    fn a_pixel_without_depth_is_unknown() {
        let intr = Intrinsics::pinhole(64, 48, 50.0, 50.0, 31.5, 23.5);
        let mut img = DepthImage::zeros(64, 48);
        img.data.iter_mut().for_each(|d| *d = 1000);
        let hole = (21usize, 13usize);
        img.data[hole.1 * 64 + hole.0] = 0;
        for block in [1u32, 3, 4, 5, 8, 9] {
            let view = DepthView::new(&img, &intr, &Isometry3::identity(), block);
            let at = |u: usize, v: usize| {
                let p = intr.deproject([u as f64, v as f64], 0.5);
                view.classify(&Point3::new(p[0], p[1], p[2]), 0.05)
            };
            let expected = if block <= MAX_MASKED_BLOCK {
                Seen::Unknown
            } else {
                Seen::FreeSpace
            };
            assert_eq!(at(hole.0, hole.1), expected, "block {block}");
            for (u, v) in [
                (hole.0 + 1, hole.1),
                (hole.0, hole.1 + 1),
                (hole.0 - 1, hole.1 - 1),
            ] {
                assert_eq!(at(u, v), Seen::FreeSpace, "block {block} at {u},{v}");
            }
            // Every pixel but the hole, against the mask.
            for v in 0..48 {
                for u in 0..64 {
                    if (u, v) != hole {
                        assert_eq!(at(u, v), Seen::FreeSpace, "block {block} at {u},{v}");
                    }
                }
            }
        }
    }
}
