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
