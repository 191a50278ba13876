//! Reading clouds: a binary PLY of 250 000 points with normals (6 MB, what `fuse` and Open3D write), the
//! same points without normals, and the same 6 MB as a binary PCD (what PCL writes), from a file in the
//! page cache.
//!
//! `cargo bench --bench io`.

use criterion::{criterion_group, criterion_main, Criterion};
use depthcal::geometry::PointCloud;
use depthcal::io::{read_cloud, write_cloud};
use std::hint::black_box;

/// A deterministic cloud of `n` points on a wavy surface, with normals when asked.
fn cloud(n: usize, normals: bool) -> PointCloud {
    let side = (n as f64).sqrt().ceil() as usize;
    let points: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let (u, v) = ((i % side) as f32 * 0.004, (i / side) as f32 * 0.004);
            [u, v, 0.05 * (u * 7.0).sin() * (v * 5.0).cos()]
        })
        .collect();
    let normals = normals.then(|| points.iter().map(|_| [0.0, 0.0, 1.0]).collect());
    PointCloud {
        points,
        normals,
        colors: None,
    }
}

/// A binary PCD (v0.7) of a cloud with normals: x y z normal_x normal_y normal_z, little-endian floats.
fn binary_pcd(c: &PointCloud) -> Vec<u8> {
    let n = c.len();
    let mut out = format!(
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\n\
         COUNT 1 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    .into_bytes();
    let normals = c.normals.as_ref().expect("normals");
    for (p, q) in c.points.iter().zip(normals) {
        for v in p.iter().chain(q) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn bench_read(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("depthcal-bench-io-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut g = c.benchmark_group("read");
    g.sample_size(30);
    for (name, normals) in [("ply_250k_normals", true), ("ply_250k", false)] {
        let path = dir.join(format!("{name}.ply"));
        write_cloud(&path, &cloud(250_000, normals)).unwrap();
        let mb = std::fs::metadata(&path).unwrap().len() as f64 / 1e6;
        eprintln!("{name}: {mb:.1} MB");
        g.bench_function(name, |b| {
            b.iter(|| black_box(read_cloud(&path).unwrap().len()))
        });
    }
    let path = dir.join("pcd_250k_normals.pcd");
    std::fs::write(&path, binary_pcd(&cloud(250_000, true))).unwrap();
    g.bench_function("pcd_250k_normals", |b| {
        b.iter(|| black_box(read_cloud(&path).unwrap().len()))
    });
    g.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench_read);
criterion_main!(benches);
