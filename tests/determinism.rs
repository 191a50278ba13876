//! `register`, `calibrate` and `simulate` give the same bytes at 1, 2 and 4 threads (issue 15).

mod common;
use common::*;
use std::path::Path;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The bits of every number of `v`'s "transform".
fn transform_bits(stdout: &str) -> Vec<u64> {
    let v: serde_json::Value = serde_json::from_str(stdout).expect("one JSON object");
    v["transform"]["matrix"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter())
        .map(|x| x.as_f64().unwrap().to_bits())
        .collect()
}

const THREADS: [&str; 3] = ["1", "2", "4"];

#[test]
fn register_is_identical_at_1_2_and_4_threads() {
    let d = scratch("det-register");
    let clouds = Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds");
    let (src, tgt) = (
        clouds.join("demo_source.ply"),
        clouds.join("demo_target.ply"),
    );
    let mut runs = Vec::new();
    for n in THREADS {
        let out = d.join(format!("aligned-{n}.ply"));
        let (code, stdout, stderr) = depthcal(&[
            "--threads",
            n,
            "register",
            s(&src),
            s(&tgt),
            "--json",
            "--seed",
            "7",
            "--output",
            s(&out),
        ]);
        assert_eq!(code, 0, "{n} threads: {stderr}");
        runs.push((transform_bits(&stdout), std::fs::read(&out).unwrap()));
    }
    for (k, r) in runs.iter().enumerate().skip(1) {
        assert_eq!(r.0, runs[0].0, "transform at {} threads", THREADS[k]);
        assert!(r.1 == runs[0].1, "output bytes at {} threads", THREADS[k]);
    }
}

#[test]
fn simulate_and_calibrate_are_identical_at_1_2_and_4_threads() {
    let d = scratch("det-sim");
    let mut cells = Vec::new();
    for n in THREADS {
        let cell = d.join(format!("cell-{n}"));
        let (code, _, stderr) = depthcal(&[
            "--threads",
            n,
            "simulate",
            s(&cell),
            "--frames",
            "4",
            "--seed",
            "11",
        ]);
        assert_eq!(code, 0, "{n} threads: {stderr}");
        let files: Vec<(std::path::PathBuf, Vec<u8>)> = listing(&cell)
            .into_iter()
            .map(|(p, b)| (p.strip_prefix(&cell).unwrap().to_path_buf(), b))
            .collect();
        assert!(files.len() > 8, "{files:?}");
        cells.push(files);
    }
    for (k, c) in cells.iter().enumerate().skip(1) {
        assert!(
            c == &cells[0],
            "simulate bytes differ at {} threads",
            THREADS[k]
        );
    }
    let cell = d.join("cell-1");
    let mut transforms = Vec::new();
    for n in THREADS {
        let (code, stdout, stderr) = depthcal(&["--threads", n, "calibrate", s(&cell), "--json"]);
        assert!(code == 0 || code == 3, "{n} threads: {stderr}");
        transforms.push(transform_bits(&stdout));
    }
    for (k, t) in transforms.iter().enumerate().skip(1) {
        assert_eq!(t, &transforms[0], "calibrate at {} threads", THREADS[k]);
    }
}
