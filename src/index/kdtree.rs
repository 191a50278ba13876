//! The 3-D nearest-neighbour index: a thin wrapper over kiddo's `ImmutableKdTree<f32, 3>`.
//!
//! Built once, queried from many threads. All distances returned are **squared** Euclidean distances in
//! the cloud's unit squared, and results are ordered by (distance, index) so that they are deterministic.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// A static kd-tree over a slice of `f32` points. Item ids are indices into that slice.
pub struct KdIndex {
    tree: Option<ImmutableKdTree<f32, 3>>,
    len: usize,
}

fn sort_hits(v: &mut [(usize, f32)]) {
    v.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
}

impl KdIndex {
    /// Builds the index. Points must be finite (see [`crate::PointCloud::drop_non_finite`]).
    pub fn new(points: &[[f32; 3]]) -> Self {
        let tree = if points.is_empty() {
            None
        } else {
            Some(
                ImmutableKdTree::new_from_slice(points)
                    .expect("kd-tree construction failed on finite points"),
            )
        };
        KdIndex {
            tree,
            len: points.len(),
        }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the index holds no points.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The nearest point: `(index, squared distance)`, or `None` for an empty index.
    #[inline]
    pub fn nearest(&self, p: &[f32; 3]) -> Option<(usize, f32)> {
        let t = self.tree.as_ref()?;
        let r = t.query(p).nearest_one::<SquaredEuclidean<f32>>().execute();
        Some((r.item as usize, r.distance))
    }

    /// The `k` nearest points, closest first.
    pub fn knn(&self, p: &[f32; 3], k: usize) -> Vec<(usize, f32)> {
        let (Some(t), Some(k)) = (self.tree.as_ref(), NonZeroUsize::new(k)) else {
            return Vec::new();
        };
        let mut out: Vec<(usize, f32)> = t
            .query(p)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute()
            .into_iter()
            .map(|r| (r.item as usize, r.distance))
            .collect();
        sort_hits(&mut out);
        out
    }

    /// At most `max_n` points within `radius` (not squared), closest first.
    pub fn within(&self, p: &[f32; 3], radius: f32, max_n: usize) -> Vec<(usize, f32)> {
        let (Some(t), Some(k)) = (self.tree.as_ref(), NonZeroUsize::new(max_n)) else {
            return Vec::new();
        };
        let mut out: Vec<(usize, f32)> = t
            .query(p)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .within(radius * radius)
            .execute()
            .into_iter()
            .map(|r| (r.item as usize, r.distance))
            .collect();
        sort_hits(&mut out);
        out
    }

    /// Every point within `radius` (not squared), in index order.
    pub fn within_all(&self, p: &[f32; 3], radius: f32) -> Vec<(usize, f32)> {
        let Some(t) = self.tree.as_ref() else {
            return Vec::new();
        };
        let mut out: Vec<(usize, f32)> = t
            .query(p)
            .within::<SquaredEuclidean<f32>>(radius * radius)
            .unsorted()
            .execute()
            .into_iter()
            .map(|r| (r.item as usize, r.distance))
            .collect();
        out.sort_unstable_by_key(|h| h.0);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    fn brute(points: &[[f32; 3]], q: &[f32; 3]) -> Vec<(usize, f32)> {
        let mut v: Vec<(usize, f32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let d = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                (i, d)
            })
            .collect();
        sort_hits(&mut v);
        v
    }

    /// Every query against a brute-force oracle (uniform, clustered and duplicate points).
    #[test]
    fn matches_brute_force() {
        let mut rng = Rng::new(5);
        let mut pts: Vec<[f32; 3]> = (0..3000)
            .map(|_| {
                [
                    rng.uniform(-1.0, 1.0) as f32,
                    rng.uniform(-1.0, 1.0) as f32,
                    rng.uniform(-1.0, 1.0) as f32,
                ]
            })
            .collect();
        // A tight cluster and exact duplicates.
        for _ in 0..500 {
            pts.push([
                0.5 + rng.uniform(0.0, 1e-3) as f32,
                0.2,
                rng.uniform(0.0, 1e-3) as f32,
            ]);
        }
        let dups = pts[..50].to_vec();
        pts.extend(dups);
        let idx = KdIndex::new(&pts);
        for _ in 0..300 {
            let q = [
                rng.uniform(-1.2, 1.2) as f32,
                rng.uniform(-1.2, 1.2) as f32,
                rng.uniform(-1.2, 1.2) as f32,
            ];
            let b = brute(&pts, &q);
            let (_, d) = idx.nearest(&q).unwrap();
            assert_eq!(d, b[0].1);
            let k = idx.knn(&q, 10);
            let kd: Vec<f32> = k.iter().map(|h| h.1).collect();
            let bd: Vec<f32> = b[..10].iter().map(|h| h.1).collect();
            assert_eq!(kd, bd);
            let r = 0.3f32;
            let mut w: Vec<usize> = idx.within_all(&q, r).iter().map(|h| h.0).collect();
            let mut bw: Vec<usize> = b.iter().filter(|h| h.1 <= r * r).map(|h| h.0).collect();
            w.sort_unstable();
            bw.sort_unstable();
            assert_eq!(w, bw);
            let wn = idx.within(&q, r, 7);
            assert_eq!(wn.len(), bw.len().min(7));
            for (a, c) in wn.iter().zip(b.iter()) {
                assert_eq!(a.1, c.1);
            }
        }
        assert!(KdIndex::new(&[]).nearest(&[0.0; 3]).is_none());
    }
}
