//! Diagnostics of the global stage against a known truth: `diag SRC TGT GT.txt [orientation]`.
use depthcal::features::{compute_fpfh, FpfhConfig};
use depthcal::geometry::cloud::transform_point;
use depthcal::index::KdIndex;
use depthcal::preprocess::normals::*;
use depthcal::preprocess::scale::*;
use depthcal::preprocess::voxel::voxel_downsample;
use depthcal::registration::correspondence::*;
use depthcal::registration::ransac::*;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let src = depthcal::io::read_cloud(&a[1]).unwrap();
    let tgt = depthcal::io::read_cloud(&a[2]).unwrap();
    let gt = depthcal::io::read_matrix_file(&a[3]).unwrap();
    let orient_mode = a.get(4).map(|s| s.as_str()).unwrap_or("centroid");
    let sp = estimate_spacing(&src.points)
        .unwrap()
        .max(estimate_spacing(&tgt.points).unwrap());
    let v = a.get(5).map(|s| s.parse().unwrap()).unwrap_or_else(|| {
        (voxel_for_target(&src.points, 5000, 1.5 * sp).unwrap()
            * voxel_for_target(&tgt.points, 5000, 1.5 * sp).unwrap())
        .sqrt()
    });
    let prep = |c: &depthcal::PointCloud| {
        let d = voxel_downsample(c, v).unwrap();
        let idx = KdIndex::new(&d.points);
        let mut n = estimate_normals(
            &d.points,
            &idx,
            &NormalConfig {
                radius: Some(2.0 * v),
                max_neighbors: 30,
            },
        );
        let o = match orient_mode {
            "origin" => Orientation::TowardPoint([0.0; 3]),
            "local" => Orientation::LocalCentroid(5.0 * v),
            "local10" => Orientation::LocalCentroid(10.0 * v),
            _ => Orientation::TowardCentroid,
        };
        orient(&d.points, &mut n, o);
        let f = compute_fpfh(
            &d.points,
            &n,
            &idx,
            &FpfhConfig {
                radius: 5.0 * v,
                max_neighbors: 100,
            },
        );
        (d, idx, f)
    };
    let (s, _si, sf) = prep(&src);
    let (t, ti, tf) = prep(&tgt);
    let tau = 1.5 * v;
    for (name, m) in [
        ("mutual", MatchConfig::default()),
        (
            "oneway",
            MatchConfig {
                mutual: false,
                ..Default::default()
            },
        ),
    ] {
        let corr = match_features(&sf, &tf, &m);
        let good = corr
            .iter()
            .filter(|c| {
                let p = transform_point(&gt, &s.points[c.source as usize]);
                let q = t.points[c.target as usize];
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                    < tau as f32
            })
            .count();
        let r = ransac(
            &s.points,
            &t.points,
            &ti,
            &corr,
            &RansacConfig {
                inlier_distance: tau,
                ..Default::default()
            },
            0,
        )
        .unwrap();
        let (re, te) = depthcal::geometry::transform::pose_error(&r.transform, &gt);
        if std::env::var("CANDS").is_ok() {
            for (c, f, t) in &r.candidates {
                let (re, te) = depthcal::geometry::transform::pose_error(t, &gt);
                println!("   cand count {c:4} fitness {f:.3}  err {re:7.2} deg {te:.3}");
            }
        }
        println!("voxel {v:.4} {name}: {} corr, {good} true inliers; ransac {} inliers fitness {:.3} -> err {re:.2} deg {te:.3}; GT fitness {:.3}",
            corr.len(), r.inlier_count, r.fitness, cloud_fitness(&s.points, &ti, &gt, tau));
    }
}
