//! Writes the sample clouds in `clouds/` that the README's first command registers:
//! `cargo run --release --example make_sample_clouds`.
//!
//! A simulated room corner with boxes, spheres and cylinders, split into two parts sharing about 60% of
//! the source, each independently subsampled with 1 mm noise; the source is then moved by a known
//! transform, written to `clouds/demo_truth.txt` (it maps the source file's points into the target's frame).

use depthcal::geometry::transform::random_isometry;
use depthcal::geometry::Rng;
use depthcal::sim::{demo_scene, split_overlapping};

fn main() -> depthcal::Result<()> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds");
    std::fs::create_dir_all(&dir).map_err(|e| depthcal::Error::io(&dir, e))?;
    let scene = demo_scene(2026, 80_000);
    let (src, tgt, shared) = split_overlapping(&scene, 7, 0.6, 0.001);
    let mut rng = Rng::new(99);
    let pose = random_isometry(&mut rng, 150f64.to_radians(), 1.0);
    let moved = src.transformed(&pose);
    depthcal::io::write_cloud(dir.join("demo_source.ply"), &moved)?;
    depthcal::io::write_cloud(dir.join("demo_target.ply"), &tgt)?;
    // truth maps the written source into the target frame: p_tgt = p_src_original = pose⁻¹ · p_written
    depthcal::io::write_matrix_file(dir.join("demo_truth.txt"), &pose.inverse())?;
    println!(
        "wrote {} source and {} target points ({:.0}% of the source is shared) to {}",
        moved.len(),
        tgt.len(),
        shared * 100.0,
        dir.display()
    );
    Ok(())
}
