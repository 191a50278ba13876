//! Detection, matching and homography on a synthetic textured image warped by a known homography.

use super::homography::map_point;
use super::*;
use crate::geometry::Rng;
use crate::vision::GreyImage;
use nalgebra::Matrix3;

const W: u32 = 480;
const H: u32 = 360;

/// Mid grey plus random Gaussian blobs (σ 2–12 px, bright and dark) over a `W × H` image.
fn texture(seed: u64) -> GreyImage {
    let mut rng = Rng::new(seed);
    let mut acc = vec![128.0f64; (W * H) as usize];
    for _ in 0..700 {
        let (cx, cy) = (
            rng.uniform(-10.0, W as f64 + 10.0),
            rng.uniform(-10.0, H as f64 + 10.0),
        );
        let s = rng.uniform(2.0, 12.0);
        let a = rng.uniform(-90.0, 90.0);
        let r = (3.0 * s).ceil() as i64;
        for y in (cy as i64 - r).max(0)..(cy as i64 + r + 1).min(H as i64) {
            for x in (cx as i64 - r).max(0)..(cx as i64 + r + 1).min(W as i64) {
                let d2 = (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2);
                acc[(y * W as i64 + x) as usize] += a * (-d2 / (2.0 * s * s)).exp();
            }
        }
    }
    let data = acc
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    GreyImage::new(W, H, data).unwrap()
}

/// `img` seen through `h` (first-image pixels to second-image pixels): bilinear, mid grey outside.
fn warp(img: &GreyImage, h: &Matrix3<f64>) -> GreyImage {
    let inv = h.try_inverse().unwrap();
    let mut data = vec![128u8; img.data.len()];
    for v in 0..img.height {
        for u in 0..img.width {
            let Some(p) = map_point(&inv, &Point2::new(u as f64, v as f64)) else {
                continue;
            };
            if p.x < 0.0
                || p.y < 0.0
                || p.x > (img.width - 1) as f64
                || p.y > (img.height - 1) as f64
            {
                continue;
            }
            let (x0, y0) = (p.x.floor() as u32, p.y.floor() as u32);
            let (x1, y1) = ((x0 + 1).min(img.width - 1), (y0 + 1).min(img.height - 1));
            let (fx, fy) = (p.x - x0 as f64, p.y - y0 as f64);
            let g = |x, y| img.at(x, y) as f64;
            let val = (1.0 - fy) * ((1.0 - fx) * g(x0, y0) + fx * g(x1, y0))
                + fy * ((1.0 - fx) * g(x0, y1) + fx * g(x1, y1));
            data[(v * img.width + u) as usize] = val.round() as u8;
        }
    }
    GreyImage::new(img.width, img.height, data).unwrap()
}

/// A perspective view change: shrink, turn ~7°, tilt.
fn truth() -> Matrix3<f64> {
    Matrix3::new(0.85, -0.11, 45.0, 0.1, 0.88, 20.0, 1.5e-4, -1.0e-4, 1.0)
}

/// Largest distance between the fitted and the true mapping over the part of image 1 that maps into
/// image 2, pixels.
fn worst_error(h: &Matrix3<f64>, truth: &Matrix3<f64>) -> f64 {
    let mut worst: f64 = 0.0;
    for y in (20..H - 20).step_by(20) {
        for x in (20..W - 20).step_by(20) {
            let p = Point2::new(x as f64, y as f64);
            let q = map_point(truth, &p).unwrap();
            if q.x > 0.0 && q.y > 0.0 && q.x < W as f64 && q.y < H as f64 {
                worst = worst.max(transfer_error(h, &p, &q));
            }
        }
    }
    worst
}

struct Outcome {
    matches: usize,
    correct: usize,
    inliers: usize,
    worst_px: f64,
}

fn pipeline(kind: FeatureKind) -> Outcome {
    let h0 = truth();
    let img1 = texture(21);
    let img2 = warp(&img1, &h0);
    let cfg = FeatureConfig {
        kind,
        ..Default::default()
    };
    let f1 = detect_features(&img1, &cfg).unwrap();
    let f2 = detect_features(&img2, &cfg).unwrap();
    assert_eq!(f1.kind(), kind);
    assert!(f1.len() <= cfg.max_features);
    let m = match_features(&f1, &f2, &cfg).unwrap();
    assert!(m.windows(2).all(|w| w[0].query < w[1].query));
    let p1: Vec<_> = m.iter().map(|x| f1.keypoints[x.query].pt).collect();
    let p2: Vec<_> = m.iter().map(|x| f2.keypoints[x.train].pt).collect();
    let correct = p1
        .iter()
        .zip(&p2)
        .filter(|(a, b)| transfer_error(&h0, a, b) < 3.0)
        .count();
    let fit = fit_homography(&p1, &p2, &HomographyConfig::default())
        .unwrap()
        .expect("a homography fits");
    let out = Outcome {
        matches: m.len(),
        correct,
        inliers: fit.inlier_count(),
        worst_px: worst_error(&fit.h, &h0),
    };
    eprintln!(
        "{kind}: {} + {} keypoints, {} matches, {} correct, {} inliers, worst mapping error {:.3} px",
        f1.len(),
        f2.len(),
        out.matches,
        out.correct,
        out.inliers,
        out.worst_px
    );
    out
}

#[test]
fn sift_matches_recover_the_homography() {
    let o = pipeline(FeatureKind::Sift);
    assert!(o.matches >= 150, "{} matches", o.matches);
    assert!(
        o.correct as f64 >= 0.9 * o.matches as f64,
        "{} of {}",
        o.correct,
        o.matches
    );
    assert!(o.inliers >= o.correct * 9 / 10, "{} inliers", o.inliers);
    assert!(o.worst_px < 0.5, "worst {} px", o.worst_px);
}

#[test]
fn orb_and_akaze_matches_recover_the_homography() {
    for kind in [FeatureKind::Orb, FeatureKind::Akaze] {
        let o = pipeline(kind);
        assert!(o.matches >= 60, "{kind}: {} matches", o.matches);
        assert!(
            o.correct as f64 >= 0.8 * o.matches as f64,
            "{kind}: {} of {}",
            o.correct,
            o.matches
        );
        assert!(o.worst_px < 1.5, "{kind}: worst {} px", o.worst_px);
    }
}

#[test]
fn detection_respects_the_mask_limit_and_order() {
    let img = texture(5);
    let cfg = FeatureConfig::default();
    let all = detect_features(&img, &cfg).unwrap();
    assert!(all.len() > 100);
    assert!(all
        .keypoints
        .windows(2)
        .all(|w| w[0].response >= w[1].response));
    let left: Vec<bool> = (0..W * H).map(|i| i % W < W / 2).collect();
    let masked = detect_features_masked(&img, Some(&left), &cfg).unwrap();
    assert!(!masked.is_empty() && masked.len() < all.len());
    assert!(masked
        .keypoints
        .iter()
        .all(|k| k.pt.x < (W / 2) as f64 + 0.5));
    assert!(detect_features_masked(&img, Some(&left[1..]), &cfg).is_err());
    let few = FeatureConfig {
        max_features: 50,
        ..cfg.clone()
    };
    let top = detect_features(&img, &few).unwrap();
    assert_eq!(top.len(), 50);
    // The strongest 50 of an unlimited run (SIFT's own cut keeps equal responses, ours cuts by order).
    assert_eq!(top.keypoints, all.keypoints[..50]);
    for kind in [FeatureKind::Orb, FeatureKind::Akaze] {
        let c = FeatureConfig {
            kind,
            max_features: 0,
            ..cfg.clone()
        };
        let f = detect_features(&img, &c).unwrap();
        assert!(f.len() > 100, "{kind}: {}", f.len());
        assert_eq!(
            f.descriptors.width(),
            if kind == FeatureKind::Orb { 32 } else { 61 }
        );
    }
    let blank = GreyImage::new(64, 48, vec![90; 64 * 48]).unwrap();
    assert!(detect_features(&blank, &cfg).unwrap().is_empty());
    let bad = FeatureConfig { ratio: 1.5, ..cfg };
    assert!(detect_features(&img, &bad).is_err());
}

#[test]
fn results_are_the_same_at_any_thread_count() {
    let img1 = texture(8);
    let img2 = warp(&img1, &truth());
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let cfg = FeatureConfig::default();
                let f1 = detect_features(&img1, &cfg).unwrap();
                let f2 = detect_features(&img2, &cfg).unwrap();
                let m = match_features(&f1, &f2, &cfg).unwrap();
                let p1: Vec<_> = m.iter().map(|x| f1.keypoints[x.query].pt).collect();
                let p2: Vec<_> = m.iter().map(|x| f2.keypoints[x.train].pt).collect();
                let h = fit_homography(&p1, &p2, &HomographyConfig::default()).unwrap();
                (f1, f2, m, h)
            })
    };
    let one = run(1);
    assert!(one.3.is_some());
    assert_eq!(one, run(2));
    // OpenCV's own worker threads (detection runs on them) do not matter either.
    let cv_threads = opencv::core::get_num_threads().unwrap();
    opencv::core::set_num_threads(1).unwrap();
    let serial = run(1);
    opencv::core::set_num_threads(cv_threads).unwrap();
    assert_eq!(one, serial);
}

#[test]
fn pooled_features_keep_their_offsets() {
    let img1 = texture(3);
    let img2 = texture(4);
    let cfg = FeatureConfig {
        max_features: 300,
        ..Default::default()
    };
    let f1 = detect_features(&img1, &cfg).unwrap();
    let f2 = detect_features(&img2, &cfg).unwrap();
    let mut pool = Features::empty(FeatureKind::Sift);
    pool.append(&f1).unwrap();
    pool.append(&f2).unwrap();
    assert_eq!(pool.len(), f1.len() + f2.len());
    assert_eq!(pool.descriptors.len(), pool.len());
    // Every keypoint of image 2 finds itself in the pool, at its offset, at distance 0.
    let nn = knn_match(&f2.descriptors, &pool.descriptors, 1).unwrap();
    let found = nn
        .iter()
        .enumerate()
        .filter(|(i, r)| r[0] == (f1.len() + i, 0.0))
        .count();
    // (The two textures differ and no two keypoints of image 2 share a descriptor row, so there are no
    // ties.)
    assert_eq!(found, f2.len());
    let orb = Features::empty(FeatureKind::Orb);
    assert!(pool.append(&orb).is_err());
    assert_eq!(pool.select(&[f1.len()]).keypoints[0], f2.keypoints[0]);
}

#[test]
fn kind_names_round_trip() {
    for k in [FeatureKind::Sift, FeatureKind::Orb, FeatureKind::Akaze] {
        assert_eq!(k.to_string().parse::<FeatureKind>().unwrap(), k);
        assert_eq!(serde_json::to_string(&k).unwrap(), format!("\"{k}\""));
    }
    assert_eq!(" SIFT ".parse::<FeatureKind>().unwrap(), FeatureKind::Sift);
    assert!("surf".parse::<FeatureKind>().is_err());
    let c: FeatureConfig = serde_json::from_str(r#"{"kind": "akaze", "ratio": 0.7}"#).unwrap();
    assert_eq!(
        (c.kind, c.ratio, c.max_features),
        (FeatureKind::Akaze, 0.7, 2000)
    );
    assert!(serde_json::from_str::<FeatureConfig>(r#"{"detector": "orb"}"#).is_err());
}
