//! depthcal's side of `scripts/bench_peers.py`: the single stages BENCHMARK.md compares with Open3D and
//! small_gicp, timed in-process on one pair, as one JSON line.
//!
//! `cargo run --release --example stage_times -- SOURCE TARGET TRUTH INIT OUT_DIR [REPEAT]`
//!
//! SOURCE and TARGET are clouds in metres, TRUTH the true and INIT a nearby SOURCE→TARGET transform (4x4
//! text matrices). Each stage runs REPEAT times (default 3) and reports its fastest wall time in ms:
//! - `kdtree_build`: the index over TARGET; `nn_queries`: the nearest neighbour of up to 1M SOURCE points
//!   moved by TRUTH, in parallel (their mean distance is reported, equal for any exact search);
//! - `normals`: TARGET's normals, 30 neighbours within 2 cm, the kd-tree build included;
//! - `fpfh`: FPFH (radius 25 cm, 100 neighbours, kd-tree included) of TARGET downsampled at 5 cm, normals
//!   (10 cm, 30) computed beforehand;
//! - `icp_iteration`, `icp_converged`: point-to-plane ICP (Huber, 10 cm reach, the target's kd-tree build
//!   included) of SOURCE and TARGET downsampled at 1 cm, every source point used, target normals (2 cm,
//!   30) computed beforehand, from INIT: one step, then to convergence (at most 50 steps); with the
//!   iterations and the error against TRUTH.
//!
//! The downsampled clouds go to OUT_DIR (`fpfh_target.ply`, `icp_source.ply`, `icp_target.ply`) so the
//! peers run on the very same points.

use depthcal::features::{compute_fpfh, FpfhConfig};
use depthcal::geometry::transform::pose_error;
use depthcal::index::KdIndex;
use depthcal::io::{read_cloud, read_matrix_file, write_cloud};
use depthcal::preprocess::normals::{estimate_normals, NormalConfig};
use depthcal::preprocess::voxel::voxel_downsample;
use depthcal::registration::{icp, IcpCloud, IcpConfig};
use nalgebra::Point3;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

/// The fastest of `repeat` runs of `f`, ms, and its last result.
fn best<T>(repeat: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut ms = f64::INFINITY;
    let mut out = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let r = f();
        ms = ms.min(t.elapsed().as_secs_f64() * 1e3);
        out = Some(r);
    }
    (ms, out.expect("one run"))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 5 {
        return Err("usage: stage_times SOURCE TARGET TRUTH INIT OUT_DIR [REPEAT]".into());
    }
    let (source, target) = (read_cloud(&args[0])?, read_cloud(&args[1])?);
    let (truth, init) = (read_matrix_file(&args[2])?, read_matrix_file(&args[3])?);
    let out = PathBuf::from(&args[4]);
    let repeat: usize = args.get(5).map_or(Ok(3), |r| r.parse())?;
    std::fs::create_dir_all(&out)?;
    let tp = &target.points;

    let (build_ms, index) = best(repeat, || KdIndex::new(tp));
    let queries: Vec<[f32; 3]> = source
        .points
        .iter()
        .take(1_000_000)
        .map(|p| {
            let q = truth * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [q.x as f32, q.y as f32, q.z as f32]
        })
        .collect();
    let (nn_ms, d2) = best(repeat, || {
        queries
            .par_iter()
            .map(|q| index.nearest(q).map_or(0.0, |(_, d2)| d2))
            .collect::<Vec<f32>>()
    });
    let nn_mean = d2.iter().map(|&d| (d as f64).sqrt()).sum::<f64>() / d2.len().max(1) as f64;

    let ncfg = |r: f64| NormalConfig {
        radius: Some(r),
        max_neighbors: 30,
    };
    let (normals_ms, _) = best(repeat, || {
        estimate_normals(tp, &KdIndex::new(tp), &ncfg(0.02))
    });

    let coarse = voxel_downsample(&target, 0.05)?;
    write_cloud(out.join("fpfh_target.ply"), &coarse)?;
    let cn = estimate_normals(&coarse.points, &KdIndex::new(&coarse.points), &ncfg(0.1));
    let fcfg = FpfhConfig {
        radius: 0.25,
        max_neighbors: 100,
    };
    let (fpfh_ms, _) = best(repeat, || {
        compute_fpfh(&coarse.points, &cn, &KdIndex::new(&coarse.points), &fcfg)
    });

    let (s1, t1) = (
        voxel_downsample(&source, 0.01)?,
        voxel_downsample(&target, 0.01)?,
    );
    write_cloud(out.join("icp_source.ply"), &s1)?;
    write_cloud(out.join("icp_target.ply"), &t1)?;
    let tn = estimate_normals(&t1.points, &KdIndex::new(&t1.points), &ncfg(0.02));
    let src = IcpCloud {
        points: &s1.points,
        normals: None,
        covariances: None,
    };
    let tgt = IcpCloud {
        points: &t1.points,
        normals: Some(&tn),
        covariances: None,
    };
    let run = |iterations: usize| {
        let cfg = IcpConfig {
            max_correspondence_distance: 0.1,
            max_iterations: iterations,
            ..IcpConfig::default()
        };
        icp(&src, &tgt, &KdIndex::new(&t1.points), &init, &cfg)
    };
    let (one_ms, _) = best(repeat, || run(1));
    let (conv_ms, r) = best(repeat, || run(50));
    let r = r?;
    let (rot, tr) = pose_error(&r.transform, &truth);
    println!(
        "{}",
        serde_json::json!({
            "lib": "depthcal",
            "threads": rayon::current_num_threads(),
            "points": [source.points.len(), target.points.len()],
            "kdtree_build_ms": build_ms,
            "nn_queries": queries.len(),
            "nn_queries_ms": nn_ms,
            "nn_mean_distance": nn_mean,
            "normals_ms": normals_ms,
            "fpfh_points": coarse.points.len(),
            "fpfh_ms": fpfh_ms,
            "icp_points": [s1.points.len(), t1.points.len()],
            "icp_iteration_ms": one_ms,
            "icp_converged_ms": conv_ms,
            "icp_iterations": r.iterations,
            "icp_converged": r.converged,
            "icp_error_deg": rot,
            "icp_error_mm": tr * 1e3,
        })
    );
    Ok(())
}
