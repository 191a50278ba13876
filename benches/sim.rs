//! The depth simulator: one 640x480 frame (ray casting + noise, with and without the colour image) and a whole
//! two-robot cell of 2×20 frames written to disk.
//!
//! `cargo bench --bench sim` (set `RAYON_NUM_THREADS=2` to pin the thread count).

use criterion::{criterion_group, criterion_main, Criterion};
use depthcal::sim::{render_frame, NoiseConfig, SimCell, SimConfig};
use std::hint::black_box;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let cell = SimCell::generate(&SimConfig::default()).unwrap();
    let r = &cell.robots[0];
    let t = r.t_world_cam(3);
    let mut g = c.benchmark_group("sim");
    g.sample_size(20);
    for (name, noise, color) in [
        ("render_640x480_ideal", NoiseConfig::none(), false),
        ("render_640x480_noise", NoiseConfig::default(), false),
        ("render_640x480_noise_color", NoiseConfig::default(), true),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                black_box(render_frame(&cell.scene, &r.camera, &t, &noise, 1, color).unwrap())
            })
        });
    }
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    let dir = std::env::temp_dir().join(format!("depthcal-bench-sim-{}", std::process::id()));
    g.bench_function("simulate_cell_2x20_640x480", |b| {
        b.iter(|| {
            let cell = SimCell::generate(&SimConfig::default()).unwrap();
            black_box(cell.write(&dir, &|_| {}).unwrap())
        })
    });
    g.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench);
criterion_main!(benches);
