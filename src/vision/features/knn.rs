//! Exhaustive k-nearest-neighbour search between two descriptor sets, parallel over chunks of query rows
//! (rayon).
//!
//! - Float (SIFT) rows: squared distances `|q|² + |t|² − 2 q·t` with the dot products of a whole block
//!   from one matrix product (nalgebra's `matrixmultiply` GEMM), then the square root, as OpenCV's
//!   `BFMatcher` (`NORM_L2`) reports them. SIFT descriptors are whole numbers (0–255, `|q|² ≈ 2¹⁸`), so
//!   every product and sum is exact in `f32` and the distances equal `BFMatcher`'s bit for bit, at about a
//!   fifth of its time (see the module tests).
//! - Binary (ORB, AKAZE) rows: OpenCV's `BFMatcher` with `NORM_HAMMING` (SIMD popcount).
//!
//! Each query row's result depends only on that row and the train set, so the output is the same at any
//! thread count; equal distances come in train-index order (the nearer of two equal candidates is the one
//! with the lower index).

use super::super::cv;
use super::Descriptors;
use crate::error::{Error, Result};
use nalgebra::{DMatrix, DMatrixView};
use opencv::core::{no_array, DMatch, Vector, NORM_HAMMING};
use opencv::features2d::BFMatcher;
use opencv::prelude::*;
use rayon::prelude::*;

/// Query rows per parallel work item.
const CHUNK_ROWS: usize = 128;

/// Per query row: `(train index, distance)`, nearest first.
type Neighbours = Vec<Vec<(usize, f32)>>;
/// Train rows per matrix product of the float path (the product block is `TRAIN_BLOCK × CHUNK_ROWS`).
const TRAIN_BLOCK: usize = 2048;

/// For every row of `query`, its `k` nearest rows of `train` as `(train index, distance)`, nearest first
/// (fewer when `train` has fewer than `k` rows). Distances are Euclidean for SIFT descriptors and Hamming
/// (differing bits) for ORB and AKAZE ones; equal distances come in train-index order.
///
/// Errors when `k` is 0 or the two sets are of different kinds or widths.
pub fn knn_match(
    query: &Descriptors,
    train: &Descriptors,
    k: usize,
) -> Result<Vec<Vec<(usize, f32)>>> {
    if k == 0 {
        return Err(Error::InvalidInput("knn_match needs k ≥ 1".into()));
    }
    if query.kind() != train.kind() {
        return Err(Error::InvalidInput(format!(
            "cannot match {} descriptors against {} descriptors",
            query.kind(),
            train.kind()
        )));
    }
    let (nq, nt) = (query.len(), train.len());
    if nq == 0 {
        return Ok(Vec::new());
    }
    if nt == 0 {
        return Ok(vec![Vec::new(); nq]);
    }
    if query.width() != train.width() {
        return Err(Error::InvalidInput(format!(
            "cannot match {} descriptors of {} values against rows of {} values",
            query.kind(),
            query.width(),
            train.width()
        )));
    }
    let kk = k.min(nt);
    if query.kind().is_binary() {
        return in_chunks(nq, |s, e| {
            opencv_chunk(query, train, s, e, kk, NORM_HAMMING)
        });
    }
    let (q, t) = (
        query.float_values().expect("SIFT rows are float"),
        train.float_values().expect("SIFT rows are float"),
    );
    let w = query.width();
    let t_norms: Vec<f32> = t.chunks_exact(w).map(squared_norm).collect();
    // Train blocks as column-major `nb × w` matrices (contiguous: nalgebra's small-matrix product
    // mishandles strided views).
    let blocks: Vec<DMatrix<f32>> = t
        .chunks(TRAIN_BLOCK * w)
        .map(|c| DMatrixView::from_slice(c, w, c.len() / w).transpose())
        .collect();
    in_chunks(nq, |s, e| {
        Ok(float_chunk(&q[s * w..e * w], &blocks, &t_norms, w, kk))
    })
}

/// `f(start, end)` over chunks of `CHUNK_ROWS` query rows in parallel, concatenated in order.
fn in_chunks(
    nq: usize,
    f: impl Fn(usize, usize) -> Result<Vec<Vec<(usize, f32)>>> + Sync,
) -> Result<Vec<Vec<(usize, f32)>>> {
    let starts: Vec<usize> = (0..nq).step_by(CHUNK_ROWS).collect();
    let parts: Vec<Result<Neighbours>> = starts
        .par_iter()
        .map(|&s| f(s, (s + CHUNK_ROWS).min(nq)))
        .collect();
    let mut out = Vec::with_capacity(nq);
    for p in parts {
        out.extend(p?);
    }
    Ok(out)
}

fn squared_norm(r: &[f32]) -> f32 {
    r.iter().map(|x| x * x).sum()
}

/// Inserts `(j, d)` into `best` (sorted by distance, at most `k` long) after any equal distance.
#[inline]
fn insert(best: &mut Vec<(usize, f32)>, k: usize, j: usize, d: f32) {
    if best.len() == k {
        if d >= best[k - 1].1 {
            return;
        }
        best.pop();
    }
    let at = best.partition_point(|&(_, e)| e <= d);
    best.insert(at, (j, d));
}

/// The float path for the query rows `q` (row-major, `w` values each) against the train `blocks`
/// (`TRAIN_BLOCK` rows each but the last) with squared norms `t_norms`.
fn float_chunk(
    q: &[f32],
    blocks: &[DMatrix<f32>],
    t_norms: &[f32],
    w: usize,
    k: usize,
) -> Vec<Vec<(usize, f32)>> {
    let n = q.len() / w;
    let q_norms: Vec<f32> = q.chunks_exact(w).map(squared_norm).collect();
    // Qᵀ: w × n, column-major = the row-major query rows.
    let qt = DMatrixView::from_slice(q, w, n);
    let mut best: Vec<Vec<(usize, f32)>> = vec![Vec::with_capacity(k + 1); n];
    let mut dist = vec![0.0f32; TRAIN_BLOCK];
    for (b, tb) in blocks.iter().enumerate() {
        let (b0, nb) = (b * TRAIN_BLOCK, tb.nrows());
        // G = T_block · Qᵀ: nb × n, column i = the dot products of query i.
        let g = tb * qt;
        for (i, (col, bi)) in g.as_slice().chunks_exact(nb).zip(&mut best).enumerate() {
            let qn = q_norms[i];
            for ((d, &dot), &tn) in dist.iter_mut().zip(col).zip(&t_norms[b0..b0 + nb]) {
                *d = (qn + tn - 2.0 * dot).max(0.0).sqrt();
            }
            for (j, &d) in dist[..nb].iter().enumerate() {
                if bi.len() < k || d < bi[k - 1].1 {
                    insert(bi, k, b0 + j, d);
                }
            }
        }
    }
    best
}

/// OpenCV's `BFMatcher` with `norm` for query rows `start..end`.
fn opencv_chunk(
    query: &Descriptors,
    train: &Descriptors,
    start: usize,
    end: usize,
    k: usize,
    norm: i32,
) -> Result<Vec<Vec<(usize, f32)>>> {
    let q = query.rows_mat(start, end)?.expect("a chunk is never empty");
    let t = train
        .rows_mat(0, train.len())?
        .expect("the train set is not empty");
    let matcher = BFMatcher::create(norm, false).map_err(|e| cv::error("BFMatcher::create", e))?;
    let mut found: Vector<Vector<DMatch>> = Vector::new();
    matcher
        .knn_train_match(&q, &t, &mut found, k as i32, &no_array(), false)
        .map_err(|e| cv::error("BFMatcher::knnMatch", e))?;
    if found.len() != end - start {
        return Err(Error::Failed(format!(
            "BFMatcher returned {} result rows for {} query rows",
            found.len(),
            end - start
        )));
    }
    Ok(found
        .iter()
        .map(|row| {
            let mut r: Vec<(usize, f32)> = row
                .iter()
                .map(|m| (m.train_idx as usize, m.distance))
                .collect();
            r.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            r
        })
        .collect())
}

/// OpenCV's `BFMatcher` on the whole sets (the reference of the float path's tests).
#[cfg(test)]
fn knn_opencv(
    query: &Descriptors,
    train: &Descriptors,
    k: usize,
) -> Result<Vec<Vec<(usize, f32)>>> {
    let norm = if query.kind().is_binary() {
        NORM_HAMMING
    } else {
        opencv::core::NORM_L2
    };
    in_chunks(query.len(), |s, e| {
        opencv_chunk(query, train, s, e, k.min(train.len()), norm)
    })
}

#[cfg(test)]
mod tests {
    use super::super::FeatureKind;
    use super::*;
    use crate::geometry::Rng;

    /// Integer-valued float rows (as SIFT's are), so every squared distance is exact in `f32` and ties
    /// are real ties.
    fn float_rows(rng: &mut Rng, n: usize, width: usize, levels: usize) -> Descriptors {
        let v = (0..n * width).map(|_| rng.below(levels) as f32).collect();
        Descriptors::from_f32(FeatureKind::Sift, width, v).unwrap()
    }

    fn binary_rows(rng: &mut Rng, kind: FeatureKind, n: usize, width: usize) -> Descriptors {
        let v = (0..n * width).map(|_| rng.below(256) as u8).collect();
        Descriptors::from_bytes(kind, width, v).unwrap()
    }

    /// Every train row's distance, sorted by (distance, index), first `k`.
    fn oracle(q: &Descriptors, t: &Descriptors, k: usize) -> Vec<Vec<(usize, f32)>> {
        (0..q.len())
            .map(|i| {
                let mut d: Vec<(usize, f32)> = (0..t.len())
                    .map(|j| {
                        let dist = match (q.float_row(i), t.float_row(j)) {
                            (Some(a), Some(b)) => {
                                let s: f64 =
                                    a.iter().zip(b).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
                                (s as f32).sqrt()
                            }
                            _ => {
                                let (a, b) = (q.binary_row(i).unwrap(), t.binary_row(j).unwrap());
                                a.iter()
                                    .zip(b)
                                    .map(|(x, y)| (x ^ y).count_ones())
                                    .sum::<u32>() as f32
                            }
                        };
                        (j, dist)
                    })
                    .collect();
                d.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
                d.truncate(k);
                d
            })
            .collect()
    }

    #[test]
    fn knn_equals_the_exhaustive_oracle_with_ties() {
        let mut rng = Rng::new(7);
        // Few levels in few dimensions: many exactly equal distances, so the tie order is tested.
        for (q, t) in [
            (
                float_rows(&mut rng, 150, 4, 3),
                float_rows(&mut rng, 300, 4, 3),
            ),
            (
                float_rows(&mut rng, 130, 128, 256),
                float_rows(&mut rng, 200, 128, 256),
            ),
            // More train rows than one product block.
            (
                float_rows(&mut rng, 300, 16, 4),
                float_rows(&mut rng, 5000, 16, 4),
            ),
            (
                binary_rows(&mut rng, FeatureKind::Orb, 140, 1),
                binary_rows(&mut rng, FeatureKind::Orb, 250, 1),
            ),
            (
                binary_rows(&mut rng, FeatureKind::Akaze, 100, 61),
                binary_rows(&mut rng, FeatureKind::Akaze, 90, 61),
            ),
        ] {
            for k in [1, 2, 5] {
                let got = knn_match(&q, &t, k).unwrap();
                assert_eq!(got, oracle(&q, &t, k), "{} k={k}", q.kind());
                assert_eq!(got, knn_opencv(&q, &t, k).unwrap(), "{} k={k}", q.kind());
            }
        }
    }

    #[test]
    fn small_and_mismatched_sets() {
        let mut rng = Rng::new(3);
        let q = float_rows(&mut rng, 5, 8, 10);
        let t = float_rows(&mut rng, 2, 8, 10);
        // k larger than the train set: all train rows.
        let r = knn_match(&q, &t, 4).unwrap();
        assert!(r.iter().all(|row| row.len() == 2));
        assert_eq!(r, oracle(&q, &t, 2));
        let empty = Descriptors::empty(FeatureKind::Sift);
        assert!(knn_match(&empty, &t, 2).unwrap().is_empty());
        assert_eq!(knn_match(&q, &empty, 2).unwrap(), vec![Vec::new(); 5]);
        assert!(knn_match(&q, &t, 0).is_err());
        let wide = float_rows(&mut rng, 2, 9, 10);
        assert!(knn_match(&q, &wide, 1).is_err());
        let orb = binary_rows(&mut rng, FeatureKind::Orb, 3, 8);
        assert!(knn_match(&q, &orb, 1).is_err());
    }

    #[test]
    fn knn_is_the_same_at_any_thread_count() {
        let mut rng = Rng::new(11);
        let q = float_rows(&mut rng, 700, 32, 8);
        let t = float_rows(&mut rng, 500, 32, 8);
        let run = |n: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
                .install(|| knn_match(&q, &t, 3).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(2));
        assert_eq!(one, run(3));
    }

    /// The pooled-set size the calibration uses: 10 000 × 10 000 SIFT descriptors (and ORB ones). Prints
    /// the times of `knn_match` and of OpenCV's `BFMatcher` (run with `--ignored --nocapture`) and checks
    /// that they agree.
    #[test]
    #[ignore = "timing, about 20 s: run with --ignored --nocapture"]
    fn knn_timing_10k_by_10k() {
        let mut rng = Rng::new(5);
        let q = float_rows(&mut rng, 10_000, 128, 256);
        let t = float_rows(&mut rng, 10_000, 128, 256);
        let qb = binary_rows(&mut rng, FeatureKind::Orb, 10_000, 32);
        let tb = binary_rows(&mut rng, FeatureKind::Orb, 10_000, 32);
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let time = |f: &(dyn Fn() -> Vec<Vec<(usize, f32)>> + Sync)| {
                let t0 = std::time::Instant::now();
                let r = pool.install(f);
                (r, t0.elapsed().as_secs_f64())
            };
            let (r, t_ours) = time(&|| knn_match(&q, &t, 2).unwrap());
            let (r_cv, t_cv) = time(&|| knn_opencv(&q, &t, 2).unwrap());
            let (rb, t_bin) = time(&|| knn_match(&qb, &tb, 2).unwrap());
            println!(
                "10000 x 10000, k = 2, {threads} thread(s): SIFT knn_match {t_ours:.2} s \
                 (OpenCV BFMatcher {t_cv:.2} s), ORB knn_match {t_bin:.2} s"
            );
            assert_eq!(r, r_cv);
            assert_eq!(rb.len(), 10_000);
            let sample: Vec<usize> = (0..10_000).step_by(997).collect();
            let want = oracle(&q.select(&sample), &t, 2);
            for (s, w) in sample.iter().zip(want) {
                assert_eq!(r[*s], w);
            }
        }
    }
}
