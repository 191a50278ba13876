//! Writes the generated pair `depthcal profile --synthetic N` registers, for running other tools on the
//! same clouds: `SOURCE.ply`, `TARGET.ply` (binary little-endian PLY, metres), the true source-to-target
//! transform and the initial guess the fine-stage profile starts from (4x4 text matrices).
//!
//! `cargo run --release --example synthetic_pair -- N SEED OUT_DIR` writes `OUT_DIR/source.ply`,
//! `target.ply`, `truth.txt` and `init.txt` (the guess 3° / 5 cm off the truth, as
//! [`depthcal::profile::nearby_guess`]).

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [n, seed, out] = args.as_slice() else {
        return Err("usage: synthetic_pair N SEED OUT_DIR".into());
    };
    let (n, seed, out): (usize, u64, PathBuf) = (n.parse()?, seed.parse()?, out.into());
    std::fs::create_dir_all(&out)?;
    let (s, t, truth) = depthcal::profile::synthetic_pair(n, seed)?;
    depthcal::io::write_cloud(out.join("source.ply"), &s)?;
    depthcal::io::write_cloud(out.join("target.ply"), &t)?;
    depthcal::io::write_matrix_file(out.join("truth.txt"), &truth)?;
    depthcal::io::write_matrix_file(
        out.join("init.txt"),
        &depthcal::profile::nearby_guess(&truth),
    )?;
    println!(
        "{}: {} + {} points",
        out.display(),
        s.points.len(),
        t.points.len()
    );
    Ok(())
}
