//! Every hot stage of `register`, on the sample clouds in `clouds/` (a simulated scene, ~28k points each),
//! on generated pairs of 10k, 100k and 1M points a side (`depthcal::profile::synthetic_pair`; 5M too with
//! `DEPTHCAL_BENCH_5M=1`) and, when present, on the 3DMatch pair 1→0 from `../shared/data` (~260k points
//! each). Each group reads its own pair back from a binary PLY in `read_ply`.
//!
//! `cargo bench --bench registration` (set `RAYON_NUM_THREADS=2` to pin the thread count;
//! `-- synthetic_1m` for one group).

use criterion::{criterion_group, criterion_main, Criterion};
use depthcal::features::nearest::nearest_both_ways;
use depthcal::features::{compute_fpfh, FpfhConfig};
use depthcal::index::KdIndex;
use depthcal::preprocess::normals::{estimate_normals, orient, NormalConfig, Orientation};
use depthcal::preprocess::scale::{estimate_spacing, voxel_for_target};
use depthcal::preprocess::voxel::voxel_downsample;
use depthcal::registration::correspondence::{match_features, MatchConfig};
use depthcal::registration::verify::{verify_candidates, VerifyConfig};
use depthcal::registration::{
    icp, ransac, register, IcpCloud, IcpConfig, PoseConstraint, RansacConfig, RegisterConfig,
};
use depthcal::PointCloud;
use nalgebra::Isometry3;
use std::hint::black_box;
use std::path::Path;

fn pairs() -> Vec<(&'static str, PointCloud, PointCloud)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut sizes = vec![
        ("synthetic_10k", 10_000),
        ("synthetic_100k", 100_000),
        ("synthetic_1m", 1_000_000),
    ];
    if std::env::var("DEPTHCAL_BENCH_5M").is_ok_and(|v| v == "1") {
        sizes.push(("synthetic_5m", 5_000_000));
    }
    let synthetic = sizes.into_iter().map(|(name, n)| {
        let (s, t, _) = depthcal::profile::synthetic_pair(n, 1).unwrap();
        (name, s, t)
    });
    let mut out = vec![(
        "demo",
        depthcal::io::read_cloud(root.join("clouds/demo_source.ply")).unwrap(),
        depthcal::io::read_cloud(root.join("clouds/demo_target.ply")).unwrap(),
    )];
    let d = root.join("../shared/data/3dmatch-redkitchen");
    if d.is_dir() {
        out.push((
            "3dmatch_1_0",
            depthcal::io::read_cloud(d.join("cloud_bin_1.ply")).unwrap(),
            depthcal::io::read_cloud(d.join("cloud_bin_0.ply")).unwrap(),
        ));
    }
    out.extend(synthetic);
    out
}

fn stages(c: &mut Criterion) {
    for (name, src, tgt) in pairs() {
        let mut g = c.benchmark_group(name);
        g.sample_size(10);
        let ply = std::env::temp_dir().join(format!("depthcal-bench-{name}.ply"));
        depthcal::io::write_cloud(&ply, &tgt).unwrap();
        g.bench_function("read_ply", |b| {
            b.iter(|| black_box(depthcal::io::read_cloud(&ply).unwrap()))
        });
        std::fs::remove_file(&ply).ok();
        g.bench_function("scale", |b| {
            b.iter(|| {
                let s = estimate_spacing(&src.points).unwrap();
                black_box(voxel_for_target(&src.points, 5000, 1.5 * s).unwrap())
            })
        });
        let s = estimate_spacing(&src.points).unwrap();
        let v = voxel_for_target(&src.points, 5000, 1.5 * s).unwrap();
        g.bench_function("voxel_downsample", |b| {
            b.iter(|| black_box(voxel_downsample(&src, v).unwrap()))
        });
        let prep = |c: &PointCloud| {
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
            orient(&d.points, &mut n, Orientation::LocalCentroid(5.0 * v));
            (d, idx, n)
        };
        let (sd, si, sn) = prep(&src);
        let (td, ti, tn) = prep(&tgt);
        g.bench_function("kdtree_build", |b| {
            b.iter(|| black_box(KdIndex::new(&td.points)))
        });
        g.bench_function("normals", |b| {
            b.iter(|| {
                black_box(estimate_normals(
                    &sd.points,
                    &si,
                    &NormalConfig {
                        radius: Some(2.0 * v),
                        max_neighbors: 30,
                    },
                ))
            })
        });
        let fcfg = FpfhConfig {
            radius: 5.0 * v,
            max_neighbors: 100,
        };
        g.bench_function("fpfh", |b| {
            b.iter(|| black_box(compute_fpfh(&sd.points, &sn, &si, &fcfg)))
        });
        let sf = compute_fpfh(&sd.points, &sn, &si, &fcfg);
        let tf = compute_fpfh(&td.points, &tn, &ti, &fcfg);
        g.bench_function("feature_nn_both_ways", |b| {
            b.iter(|| black_box(nearest_both_ways(&sf, &tf)))
        });
        let corr = match_features(&sf, &tf, &MatchConfig::default());
        let rcfg = RansacConfig {
            inlier_distance: 1.5 * v,
            ..Default::default()
        };
        g.bench_function("ransac", |b| {
            b.iter(|| black_box(ransac(&sd.points, &td.points, &ti, &corr, &rcfg, 0).unwrap()))
        });
        let found = ransac(&sd.points, &td.points, &ti, &corr, &rcfg, 0).unwrap();
        let init = found.transform;
        // Verification of RANSAC's best distinct hypotheses (short ICP + alignment score each).
        let vcfg = VerifyConfig::default();
        let candidates: Vec<Isometry3<f64>> = found
            .candidates
            .iter()
            .take(vcfg.max_candidates)
            .map(|c| c.2)
            .collect();
        g.bench_function("verify", |b| {
            b.iter(|| {
                black_box(verify_candidates(
                    &sd.points,
                    &sn,
                    &td.points,
                    &tn,
                    &ti,
                    &candidates,
                    v,
                    &PoseConstraint::default(),
                    None,
                    false,
                    &vcfg,
                ))
            })
        });
        let icfg = IcpConfig {
            max_correspondence_distance: 3.0 * v,
            translation_tolerance: 1e-3 * v,
            ..Default::default()
        };
        g.bench_function("icp_level0", |b| {
            b.iter(|| {
                let target = IcpCloud {
                    points: &td.points,
                    normals: Some(&tn),
                    covariances: None,
                };
                black_box(icp(&IcpCloud::points(&sd.points), &target, &ti, &init, &icfg).unwrap())
            })
        });
        g.bench_function("register_total", |b| {
            b.iter(|| black_box(register(&src, &tgt, None, &RegisterConfig::default()).unwrap()))
        });
        g.finish();
    }
}

criterion_group!(benches, stages);
criterion_main!(benches);
