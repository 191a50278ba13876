//! The 3-D nearest-neighbour index: a static kd-tree over `f32` points, built in parallel and queried
//! from many threads.
//!
//! Median splits along the widest axis, leaves of at most 12 points stored contiguously with their
//! original indices, and each node's tight bounding box: a query visits the children nearer box first and
//! skips any box farther than its current bound. Tight boxes (rather than the split planes alone) keep
//! queries far from the cloud cheap: above a large plane, split-plane bounds leave every cell under the
//! query's horizontal disc to visit. It replaced kiddo's `ImmutableKdTree` (6.3), measured on 225k points
//! of three 3 m planes at 1 cm with 20k queries, half on the surfaces and half 0.2-1 m off them, CPU
//! time on a loaded 2-core machine: nearest 49-74 ms against kiddo's 209-259 ms; the 30 nearest within
//! 2 cm of 10k points on the surfaces 37-46 ms against 85-148 ms; build 11 ms against 38-58 ms; and a
//! nearest search bounded by a distance ([`KdIndex::nearest_within`], what ICP asks) 19-39 ms.
//!
//! All distances returned are **squared** Euclidean distances in the cloud's unit squared, computed in
//! `f32`; ties are broken by index, so results are deterministic and do not depend on the thread count.

/// Points per leaf at most.
const LEAF: usize = 12;

/// How far beyond the asked distance limit [`KdIndex::nearest_within_memo`]'s searches look, as a
/// factor of it: a query with nothing within the limit can then move by up to half the limit before it
/// must search again (with 1.0 an unpaired point searches at every call). On ICP over the 7-Scenes and
/// generated 1M pairs of BENCHMARK.md, 1.0, 1.25, 1.5 and 2.0 took the same time within the machine's
/// noise (50 iterations over 576k points 5.4-5.7 s; the generated pair's 5 iterations 224-256 ms).
pub const MEMO_REACH: f32 = 1.5;

/// The relative margin [`KdIndex::nearest_within_memo`] keeps below the distance of the other points:
/// an `f32` squared distance is within a few units of `f32::EPSILON` (relative) of the exact one, so
/// 1e-5 is a hundred times what rounding can move it.
pub const MEMO_MARGIN: f32 = 1e-5;

/// One moving query's last search, for [`KdIndex::nearest_within_memo`]: where the query was, its
/// nearest point and distance, and the distance within which no other point lay (cloud units).
#[derive(Clone, Copy, Debug)]
pub struct NearestMemo {
    at: [f32; 3],
    id: u32,
    near: f32,
    clear: f32,
}

impl NearestMemo {
    /// A memo that knows nothing: the first call searches.
    pub const EMPTY: NearestMemo = NearestMemo {
        at: [0.0; 3],
        id: u32::MAX,
        near: f32::INFINITY,
        clear: f32::NEG_INFINITY,
    };
}

/// The order (distance, then index) of a neighbour `(index, squared distance)` as one integer: the bits of
/// a squared distance, never negative nor NaN within a radius, order as the number does (`f32::total_cmp`),
/// and indices fit in 32 bits. Comparing integers is a fraction of the cost of the two-key comparison.
#[inline]
fn distance_then_index(&(i, d2): &(usize, f32)) -> u64 {
    debug_assert!(d2 >= 0.0 && i <= u32::MAX as usize);
    ((d2.to_bits() as u64) << 32) | i as u64
}

/// A node of the tree with the tight bounding box of its points: an internal node has the children `a`
/// and `b` (node indices); a leaf holds the points `a..b` of the reordered array.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    a: u32,
    b: u32,
    leaf: bool,
}

/// The placeholder a node starts as.
const EMPTY_NODE: Node = Node {
    lo: [0.0; 3],
    hi: [0.0; 3],
    a: 0,
    b: 0,
    leaf: true,
};

/// The tree proper: its nodes (the root first), and the points reordered leaf by leaf with their original
/// indices.
struct Tree {
    nodes: Vec<Node>,
    items: Vec<([f32; 3], u32)>,
    /// `slot[id]`: where point `id` lies in `items`.
    slot: Vec<u32>,
}

/// Squared distance in `f32`, summed x, y, z.
#[inline(always)]
fn dist2(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    dx * dx + dy * dy + dz * dz
}

/// Squared distance from `q` to a node's box (0 inside).
#[inline(always)]
fn box_dist2(q: &[f32; 3], n: &Node) -> f32 {
    let mut s = 0.0;
    for (k, &qk) in q.iter().enumerate() {
        let d = (n.lo[k] - qk).max(qk - n.hi[k]).max(0.0);
        s += d * d;
    }
    s
}

/// `(d, i)` before `(e, j)`: by distance, ties by index.
#[inline(always)]
fn before(d: f32, i: u32, e: f32, j: u32) -> bool {
    d < e || (d == e && i < j)
}

/// Nodes of the subtree over `n` points.
fn subtree_nodes(n: usize) -> usize {
    if n <= LEAF {
        1
    } else {
        1 + subtree_nodes(n / 2) + subtree_nodes(n - n / 2)
    }
}

/// Subtrees of more points than this are built on two threads.
const PARALLEL_BUILD: usize = 32_768;

/// The deepest stack a query needs: one entry per tree level (a median split halves the points).
const STACK: usize = 64;

impl Tree {
    fn build(points: &[[f32; 3]]) -> Tree {
        let mut items: Vec<([f32; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (*p, i as u32))
            .collect();
        let mut nodes = vec![EMPTY_NODE; subtree_nodes(points.len())];
        Self::build_rec(&mut items, 0, &mut nodes, 0);
        let mut slot = vec![0u32; items.len()];
        for (k, (_, id)) in items.iter().enumerate() {
            slot[*id as usize] = k as u32;
        }
        Tree { nodes, items, slot }
    }

    /// Fills `nodes` (exactly the subtree's, its root first, node indices from `first`) with the subtree
    /// over `items` (which start at `offset` in the whole array). The split is at the median of the
    /// box's widest axis, ties by index: the same tree at any thread count.
    fn build_rec(items: &mut [([f32; 3], u32)], offset: usize, nodes: &mut [Node], first: usize) {
        let n = items.len();
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for (p, _) in items.iter() {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if n <= LEAF {
            nodes[0] = Node {
                lo,
                hi,
                a: offset as u32,
                b: (offset + n) as u32,
                leaf: true,
            };
            return;
        }
        let dim = (0..3).fold(0, |best, k| {
            if hi[k] - lo[k] > hi[best] - lo[best] {
                k
            } else {
                best
            }
        });
        let mid = n / 2;
        items.select_nth_unstable_by(mid, |x, y| {
            x.0[dim].total_cmp(&y.0[dim]).then(x.1.cmp(&y.1))
        });
        let (root, rest) = nodes.split_first_mut().expect("a node per subtree");
        let (ln, rn) = rest.split_at_mut(subtree_nodes(mid));
        let (left, right) = (first + 1, first + 1 + ln.len());
        *root = Node {
            lo,
            hi,
            a: left as u32,
            b: right as u32,
            leaf: false,
        };
        let (l, r) = items.split_at_mut(mid);
        if n > PARALLEL_BUILD {
            rayon::join(
                || Self::build_rec(l, offset, ln, left),
                || Self::build_rec(r, offset + mid, rn, right),
            );
        } else {
            Self::build_rec(l, offset, ln, left);
            Self::build_rec(r, offset + mid, rn, right);
        }
    }

    /// Visits the leaves whose boxes lie within the current bound of `q`, nearer child first. `bound`
    /// gives the bound (it may shrink as `leaf` finds points); `leaf` gets each leaf's points.
    #[inline(always)]
    fn search(
        &self,
        q: &[f32; 3],
        mut bound: impl FnMut() -> f32,
        mut leaf: impl FnMut(&[([f32; 3], u32)]),
    ) {
        let mut stack = [(0u32, 0f32); STACK];
        let root = &self.nodes[0];
        let d0 = box_dist2(q, root);
        if d0 > bound() {
            return;
        }
        stack[0] = (0, d0);
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (ni, lb) = stack[top];
            if lb > bound() {
                continue;
            }
            let node = &self.nodes[ni as usize];
            if node.leaf {
                leaf(&self.items[node.a as usize..node.b as usize]);
                continue;
            }
            let (l, r) = (node.a, node.b);
            let dl = box_dist2(q, &self.nodes[l as usize]);
            let dr = box_dist2(q, &self.nodes[r as usize]);
            let ((n, dn), (f, df)) = if dl <= dr {
                ((l, dl), (r, dr))
            } else {
                ((r, dr), (l, dl))
            };
            let b = bound();
            if df <= b {
                stack[top] = (f, df);
                top += 1;
            }
            if dn <= b {
                stack[top] = (n, dn);
                top += 1;
            }
        }
    }

    /// The nearest point within squared distance `max_d2` (inclusive): `(index, d²)`; ties to the
    /// smaller index.
    #[inline]
    fn nearest(&self, q: &[f32; 3], max_d2: f32) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        let bound = std::cell::Cell::new(max_d2);
        self.search(
            q,
            || bound.get(),
            |pts| {
                for (p, id) in pts {
                    let d = dist2(q, p);
                    if d < bound.get() || (d == bound.get() && best.is_none_or(|(b, _)| *id < b)) {
                        best = Some((*id, d));
                        bound.set(d);
                    }
                }
            },
        );
        best
    }

    /// The nearest point within squared distance `max_d2` (inclusive; ties to the smaller index) and the
    /// squared distance of the next nearest, or `max_d2` when no other point lies within it.
    #[inline]
    fn nearest_two(&self, q: &[f32; 3], max_d2: f32) -> (Option<(u32, f32)>, f32) {
        let mut first: Option<(u32, f32)> = None;
        let second = std::cell::Cell::new(max_d2);
        self.search(
            q,
            || second.get(),
            |pts| {
                for (p, id) in pts {
                    let d = dist2(q, p);
                    if d > second.get() {
                        continue;
                    }
                    match first {
                        Some((fi, fd)) if !before(d, *id, fd, fi) => second.set(d),
                        _ => {
                            if let Some((_, fd)) = first {
                                second.set(fd);
                            }
                            first = Some((*id, d));
                        }
                    }
                }
            },
        );
        (first, second.get())
    }

    /// Whether any point lies at squared distance strictly below `max_d2`: stops at the first one found,
    /// visiting the nearer child first.
    #[inline]
    fn any_closer(&self, q: &[f32; 3], max_d2: f32) -> bool {
        let mut stack = [0u32; STACK];
        if box_dist2(q, &self.nodes[0]) >= max_d2 {
            return false;
        }
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if node.leaf {
                if self.items[node.a as usize..node.b as usize]
                    .iter()
                    .any(|(p, _)| dist2(q, p) < max_d2)
                {
                    return true;
                }
                continue;
            }
            let (l, r) = (node.a, node.b);
            let dl = box_dist2(q, &self.nodes[l as usize]);
            let dr = box_dist2(q, &self.nodes[r as usize]);
            let ((n, dn), (f, df)) = if dl <= dr {
                ((l, dl), (r, dr))
            } else {
                ((r, dr), (l, dl))
            };
            if df < max_d2 {
                stack[top] = f;
                top += 1;
            }
            if dn < max_d2 {
                stack[top] = n;
                top += 1;
            }
        }
        false
    }

    /// The (at most) `k` nearest points within squared distance `max_d2`, into `out` sorted by
    /// (distance, index).
    fn knn_into(&self, q: &[f32; 3], k: usize, max_d2: f32, out: &mut Vec<(usize, f32)>) {
        out.clear();
        if k == 0 {
            return;
        }
        // The bound: max_d2 until k are found, then the k-th distance.
        let bound = std::cell::Cell::new(max_d2);
        self.search(
            q,
            || bound.get(),
            |pts| {
                for (p, id) in pts {
                    let d = dist2(q, p);
                    if d > bound.get() {
                        continue;
                    }
                    if out.len() == k {
                        let (li, ld) = out[k - 1];
                        if !before(d, *id, ld, li as u32) {
                            continue;
                        }
                        out.pop();
                    }
                    let mut pos = out.len();
                    while pos > 0 && before(d, *id, out[pos - 1].1, out[pos - 1].0 as u32) {
                        pos -= 1;
                    }
                    out.insert(pos, (*id as usize, d));
                    if out.len() == k {
                        bound.set(out[k - 1].1);
                    }
                }
            },
        );
    }

    /// Every point within squared distance `max_d2`, appended to `out` unordered.
    fn within_into(&self, q: &[f32; 3], max_d2: f32, out: &mut Vec<(usize, f32)>) {
        self.search(
            q,
            || max_d2,
            |pts| {
                for (p, id) in pts {
                    let d = dist2(q, p);
                    if d <= max_d2 {
                        out.push((*id as usize, d));
                    }
                }
            },
        );
    }
}

/// A static kd-tree over a slice of `f32` points. Item ids are indices into that slice.
pub struct KdIndex {
    tree: Option<Tree>,
    len: usize,
}

impl KdIndex {
    /// Builds the index. Points must be finite (see [`crate::PointCloud::drop_non_finite`]).
    pub fn new(points: &[[f32; 3]]) -> Self {
        assert!(
            points.len() < u32::MAX as usize,
            "a kd-tree indexes fewer than 2^32 points"
        );
        let tree = (!points.is_empty()).then(|| Tree::build(points));
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
        self.nearest_within(p, f32::INFINITY)
    }

    /// The nearest point at most `max_d2` away (a **squared** distance, inclusive): `(index, squared
    /// distance)`, or `None` when there is none. Much cheaper than [`KdIndex::nearest`] for points far
    /// from the cloud, whose result would be thrown away anyway.
    #[inline]
    pub fn nearest_within(&self, p: &[f32; 3], max_d2: f32) -> Option<(usize, f32)> {
        let (i, d) = self.tree.as_ref()?.nearest(p, max_d2)?;
        Some((i as usize, d))
    }

    /// [`KdIndex::nearest_within`] for a query that moves a little between calls (ICP's source points from
    /// one iteration to the next): the same answer, without a search while the query stays within what
    /// `memo` (this query's own, [`NearestMemo::EMPTY`] at first) knows from its last search. That search
    /// found the nearest point and the distance within which no other point lies, and looked up to
    /// [`MEMO_REACH`] times `sqrt(max_d2)`; a query moved by `m` since keeps its nearest point while that
    /// point's distance plus `2 m` stays below the other points' (the triangle inequality), and keeps
    /// having none within `sqrt(max_d2)` while `m` stays below the rest of the reach. A relative margin
    /// ([`MEMO_MARGIN`]) covers the `f32` rounding, so the answer is always the one a search would give.
    /// A memo belongs to one query and one index: one filled by another index means nothing here.
    #[inline]
    pub fn nearest_within_memo(
        &self,
        p: &[f32; 3],
        max_d2: f32,
        memo: &mut NearestMemo,
    ) -> Option<(usize, f32)> {
        let tree = self.tree.as_ref()?;
        let moved = dist2(p, &memo.at).sqrt();
        let clear = memo.clear * (1.0 - MEMO_MARGIN) - moved;
        if memo.id != u32::MAX {
            if memo.near + moved < clear {
                let (q, id) = &tree.items[tree.slot[memo.id as usize] as usize];
                let d = dist2(p, q);
                return (d <= max_d2).then_some((*id as usize, d));
            }
        } else if clear > max_d2.sqrt() {
            return None;
        }
        let reach = max_d2.sqrt() * MEMO_REACH;
        let (first, second) = tree.nearest_two(p, reach * reach);
        *memo = NearestMemo {
            at: *p,
            id: first.map_or(u32::MAX, |f| f.0),
            near: first.map_or(f32::INFINITY, |f| f.1.sqrt()),
            clear: second.sqrt(),
        };
        first
            .filter(|&(_, d)| d <= max_d2)
            .map(|(i, d)| (i as usize, d))
    }

    /// Whether any point lies closer than `max_d2` (a **squared** distance, exclusive) to `p`: the same
    /// answer as `nearest(p).is_some_and(|(_, d)| d < max_d2)`, but the search stops at the first such
    /// point instead of looking for the nearest. What counting inliers asks.
    #[inline]
    pub fn any_closer_than(&self, p: &[f32; 3], max_d2: f32) -> bool {
        self.tree.as_ref().is_some_and(|t| t.any_closer(p, max_d2))
    }

    /// The `k` nearest points, closest first (ties by index).
    pub fn knn(&self, p: &[f32; 3], k: usize) -> Vec<(usize, f32)> {
        let mut out = Vec::with_capacity(k.min(self.len));
        self.knn_into(p, k, &mut out);
        out
    }

    /// As [`KdIndex::knn`], into `out` (cleared first; reuse it across queries to save the allocation).
    pub fn knn_into(&self, p: &[f32; 3], k: usize, out: &mut Vec<(usize, f32)>) {
        out.clear();
        if let Some(t) = &self.tree {
            t.knn_into(p, k, f32::INFINITY, out);
        }
    }

    /// At most `max_n` points within `radius` (not squared, inclusive), closest first (ties by index).
    pub fn within(&self, p: &[f32; 3], radius: f32, max_n: usize) -> Vec<(usize, f32)> {
        let mut out = Vec::new();
        self.within_into(p, radius, max_n, &mut out);
        out
    }

    /// As [`KdIndex::within`], into `out` (cleared first; reuse it across queries to save the
    /// allocation).
    pub fn within_into(
        &self,
        p: &[f32; 3],
        radius: f32,
        max_n: usize,
        out: &mut Vec<(usize, f32)>,
    ) {
        out.clear();
        let Some(t) = &self.tree else {
            return;
        };
        if max_n <= 32 {
            t.knn_into(p, max_n, radius * radius, out);
            return;
        }
        // Many neighbours (FPFH's 100): gather all within the radius, then keep the `max_n` first by
        // (distance, index): the same set and order as the bounded k-nearest search, without its
        // insertion sort of up to `max_n` entries per point found.
        t.within_into(p, radius * radius, out);
        if out.len() > max_n {
            out.select_nth_unstable_by_key(max_n - 1, distance_then_index);
            out.truncate(max_n);
        }
        out.sort_unstable_by_key(distance_then_index);
    }

    /// Every point within `radius` (not squared, inclusive), in index order.
    pub fn within_all(&self, p: &[f32; 3], radius: f32) -> Vec<(usize, f32)> {
        let mut out = Vec::new();
        if let Some(t) = &self.tree {
            t.within_into(p, radius * radius, &mut out);
        }
        out.sort_unstable_by_key(|h| h.0);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Rng;

    fn sort_hits(v: &mut [(usize, f32)]) {
        v.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    }

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
            // Exactly the brute force's answers, ties by index included.
            assert_eq!(idx.nearest(&q), Some(b[0]));
            assert_eq!(idx.knn(&q, 10), b[..10].to_vec());
            let r2 = 0.01f32;
            let want = (b[0].1 <= r2).then_some(b[0]);
            assert_eq!(idx.nearest_within(&q, r2), want);
            // Strictly closer: at, just above and just below the nearest distance, and at r2.
            for t in [r2, b[0].1, b[0].1.next_up(), b[0].1.next_down(), 0.0] {
                assert_eq!(idx.any_closer_than(&q, t), b[0].1 < t, "{t}");
            }
            let r = 0.3f32;
            let mut w: Vec<usize> = idx.within_all(&q, r).iter().map(|h| h.0).collect();
            let mut bw: Vec<usize> = b.iter().filter(|h| h.1 <= r * r).map(|h| h.0).collect();
            w.sort_unstable();
            bw.sort_unstable();
            assert_eq!(w, bw);
            let wide = idx.within(&q, r, 40);
            let want: Vec<(usize, f32)> = b
                .iter()
                .filter(|h| h.1 <= r * r)
                .take(40)
                .copied()
                .collect();
            assert_eq!(wide, want);
            let wn = idx.within(&q, r, 7);
            assert_eq!(
                wn,
                b.iter()
                    .filter(|h| h.1 <= r * r)
                    .take(7)
                    .copied()
                    .collect::<Vec<_>>()
            );
        }
        assert!(KdIndex::new(&[]).nearest(&[0.0; 3]).is_none());
        let mut memo = NearestMemo::EMPTY;
        assert!(KdIndex::new(&[])
            .nearest_within_memo(&[0.0; 3], 1.0, &mut memo)
            .is_none());
        assert!(!KdIndex::new(&[]).any_closer_than(&[0.0; 3], f32::INFINITY));
        // Exact duplicates: a query on a point is at distance 0, not closer than 0.
        assert!(!idx.any_closer_than(&pts[0], 0.0));
        assert!(idx.any_closer_than(&pts[0], f32::MIN_POSITIVE));
        assert!(KdIndex::new(&[]).knn(&[0.0; 3], 3).is_empty());
    }

    /// Queries that wander in steps from 1e-6 to 0.3 (on and off a noisy plane, among duplicates), each
    /// with its own memo, against brute force at several limits; tiny steps keep the memo (no search).
    #[test]
    fn memo_gives_the_search_answer() {
        let mut rng = Rng::new(17);
        let mut pts: Vec<[f32; 3]> = (0..4000)
            .map(|_| {
                [
                    rng.uniform(0.0, 1.0) as f32,
                    rng.uniform(0.0, 1.0) as f32,
                    rng.uniform(-2e-3, 2e-3) as f32,
                ]
            })
            .collect();
        let dups = pts[..100].to_vec();
        pts.extend(dups);
        let idx = KdIndex::new(&pts);
        let mut kept = 0;
        for (w, r2) in [(0usize, 4e-4f32), (1, 1e-2), (2, 1e-6), (3, f32::INFINITY)] {
            for walker in 0..20 {
                let mut memo = NearestMemo::EMPTY;
                let mut q = if walker % 4 == 0 {
                    pts[walker * 7]
                } else {
                    [
                        rng.uniform(0.0, 1.0) as f32,
                        rng.uniform(0.0, 1.0) as f32,
                        rng.uniform(-0.05, 0.05) as f32,
                    ]
                };
                for step in 0..60 {
                    let size: f64 = [1e-6, 1e-4, 1e-3, 1e-2, 0.3][(step + w + walker) % 5];
                    for v in q.iter_mut() {
                        *v += rng.uniform(-size, size) as f32;
                    }
                    let before = memo.at;
                    let b = brute(&pts, &q);
                    let want = (b[0].1 <= r2).then_some(b[0]);
                    assert_eq!(
                        idx.nearest_within_memo(&q, r2, &mut memo),
                        want,
                        "{q:?} {r2}"
                    );
                    if size < 1e-5 && step > 0 && memo.at == before {
                        kept += 1;
                    }
                }
            }
        }
        assert!(kept > 100, "{kept} answers kept without a search");
        // On a duplicated point: the earlier index, memo or not.
        for k in 0..100 {
            let mut memo = NearestMemo::EMPTY;
            for _ in 0..2 {
                let got = idx.nearest_within_memo(&pts[k], 0.01, &mut memo);
                assert_eq!(got, brute(&pts, &pts[k]).first().copied());
                assert_eq!(got.map(|h| h.0), Some(k));
            }
        }
    }

    /// Queries far from the cloud (above a plane, outside it) and a cloud big enough for the parallel
    /// build, against brute force; the same tree at one and two threads.
    #[test]
    fn far_queries_and_parallel_build() {
        let mut rng = Rng::new(9);
        let pts: Vec<[f32; 3]> = (0..70_000)
            .map(|i| {
                let (a, b) = (rng.uniform(0.0, 3.0) as f32, rng.uniform(0.0, 3.0) as f32);
                let n = rng.uniform(-5e-4, 5e-4) as f32;
                match i % 3 {
                    0 => [a, b, n],
                    1 => [a, n, b],
                    _ => [n, a, b],
                }
            })
            .collect();
        let idx = KdIndex::new(&pts);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let idx1 = one.install(|| KdIndex::new(&pts));
        for _ in 0..60 {
            let q = [
                rng.uniform(-1.0, 4.0) as f32,
                rng.uniform(-1.0, 4.0) as f32,
                rng.uniform(0.2, 2.0) as f32,
            ];
            let b = brute(&pts, &q);
            assert_eq!(idx.nearest(&q), Some(b[0]));
            assert_eq!(idx1.nearest(&q), Some(b[0]));
            assert_eq!(idx.knn(&q, 5), b[..5].to_vec());
            assert_eq!(
                idx.nearest_within(&q, 0.04),
                (b[0].1 <= 0.04).then_some(b[0])
            );
            for t in [0.04, b[0].1, b[0].1.next_up(), 1e-4] {
                assert_eq!(idx.any_closer_than(&q, t), b[0].1 < t, "{t}");
            }
        }
    }
}
