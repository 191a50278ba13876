//! Robustness sweep of `register` on seeded synthetic pairs: `cargo run --release --example sweep -- N`.
use depthcal::geometry::transform::{pose_error, random_isometry};
use depthcal::geometry::Rng;
use depthcal::registration::{register, RegisterConfig};
use depthcal::sim::{demo_scene, split_overlapping};

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(20);
    let mut fails = 0;
    for seed in 0..n {
        let mut rng = Rng::new(1000 + seed);
        let scene = demo_scene(seed, 120_000);
        let overlap = rng.uniform(0.4, 0.8);
        let (src, tgt, frac) = split_overlapping(&scene, seed + 7, overlap, 0.001);
        let p = random_isometry(&mut rng, std::f64::consts::PI, 1.0);
        let reg = register(
            &src.transformed(&p),
            &tgt,
            None,
            &RegisterConfig {
                seed,
                ..Default::default()
            },
        )
        .unwrap();
        let (r, t) = pose_error(&reg.transform, &p.inverse());
        let ok = r < 0.1 && t < 1e-3 * tgt.extent();
        if !ok {
            fails += 1;
        }
        println!(
            "seed {seed:3} overlap {frac:.2}: {r:8.4} deg {:9.3} mm {}",
            t * 1e3,
            if ok { "" } else { "FAIL" }
        );
    }
    println!("{fails} failures of {n}");
}
