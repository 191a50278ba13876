//! The point cloud type.

use nalgebra::{Isometry3, Point3, Vector3};

/// A point cloud: `f32` positions with optional per-point normals and colours.
///
/// Positions are in the cloud's own unit (metres by convention; millimetre clouds work too because every
/// scale-dependent parameter is derived from the data). When `normals` or `colors` are present they have one
/// entry per point.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions.
    pub points: Vec<[f32; 3]>,
    /// Unit normals, one per point, if known.
    pub normals: Option<Vec<[f32; 3]>>,
    /// RGB colours (0-255), one per point, if known.
    pub colors: Option<Vec<[u8; 3]>>,
}

impl PointCloud {
    /// A cloud of bare positions.
    pub fn from_points(points: Vec<[f32; 3]>) -> Self {
        PointCloud {
            points,
            normals: None,
            colors: None,
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Keeps only the points whose index satisfies `keep`, preserving order (and normals and colours).
    pub fn retain_indices(&self, idx: &[usize]) -> PointCloud {
        PointCloud {
            points: idx.iter().map(|&i| self.points[i]).collect(),
            normals: self
                .normals
                .as_ref()
                .map(|n| idx.iter().map(|&i| n[i]).collect()),
            colors: self
                .colors
                .as_ref()
                .map(|c| idx.iter().map(|&i| c[i]).collect()),
        }
    }

    /// Drops points with a NaN or infinite coordinate (or normal); returns how many were dropped.
    pub fn drop_non_finite(&mut self) -> usize {
        let finite = |p: &[f32; 3]| p.iter().all(|v| v.is_finite());
        let keep: Vec<usize> = (0..self.len())
            .filter(|&i| {
                finite(&self.points[i]) && self.normals.as_ref().is_none_or(|n| finite(&n[i]))
            })
            .collect();
        let dropped = self.len() - keep.len();
        if dropped > 0 {
            *self = self.retain_indices(&keep);
        }
        dropped
    }

    /// Applies a rigid transform to positions (and rotates normals), computing in `f64`.
    pub fn transform(&mut self, t: &Isometry3<f64>) {
        for p in &mut self.points {
            *p = transform_point(t, p);
        }
        if let Some(ns) = &mut self.normals {
            for n in ns.iter_mut() {
                let v = t.rotation * Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
                *n = [v.x as f32, v.y as f32, v.z as f32];
            }
        }
    }

    /// A transformed copy.
    pub fn transformed(&self, t: &Isometry3<f64>) -> PointCloud {
        let mut c = self.clone();
        c.transform(t);
        c
    }

    /// Axis-aligned bounding box `(min, max)`, or `None` for an empty cloud.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.points.first()?;
        Some(
            self.points
                .iter()
                .fold((first, first), |(mut lo, mut hi), p| {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                    (lo, hi)
                }),
        )
    }

    /// Length of the bounding-box diagonal (the cloud's extent), 0 for an empty cloud.
    pub fn extent(&self) -> f64 {
        self.bounds()
            .map(|(lo, hi)| {
                (0..3)
                    .map(|k| ((hi[k] - lo[k]) as f64).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .unwrap_or(0.0)
    }

    /// Mean of the positions in `f64`.
    pub fn centroid(&self) -> Point3<f64> {
        let mut s = Vector3::zeros();
        for p in &self.points {
            s += Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        }
        Point3::from(s / self.len().max(1) as f64)
    }
}

/// Applies `t` to an `f32` point, computing in `f64`.
#[inline]
pub fn transform_point(t: &Isometry3<f64>, p: &[f32; 3]) -> [f32; 3] {
    let q = t * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    [q.x as f32, q.y as f32, q.z as f32]
}

/// Converts an `f32` array point to an `f64` nalgebra point.
#[inline]
pub fn to_p64(p: &[f32; 3]) -> Point3<f64> {
    Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Converts an `f32` array vector to an `f64` nalgebra vector.
#[inline]
pub fn to_v64(p: &[f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}
