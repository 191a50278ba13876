//! `depthcal profile`: the stage table on a synthetic pair and on the sample clouds, the fine stage alone,
//! and its bad arguments.

mod common;
use common::depthcal;

const CLOUDS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/clouds");

fn json(out: &str) -> serde_json::Value {
    serde_json::from_str(out).unwrap_or_else(|e| panic!("{e}: {out}"))
}

#[test]
fn a_synthetic_pair_is_profiled_stage_by_stage() {
    let (code, out, err) = depthcal(&[
        "profile",
        "--synthetic",
        "30000",
        "--repeat",
        "2",
        "--json",
        "--threads",
        "2",
    ]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    common::assert_documented(&v);
    let names: Vec<&str> = v["stages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["name"].as_str().unwrap())
        .collect();
    for s in [
        "read",
        "scale",
        "downsample_normals",
        "fpfh",
        "match",
        "ransac",
        "icp",
        "total",
    ] {
        assert!(names.contains(&s), "{s} missing from {names:?}");
    }
    for s in v["stages"].as_array().unwrap() {
        assert!(s["wall_ms"].as_f64().unwrap() >= 0.0 && s["wall_ms_min"].as_f64().unwrap() >= 0.0);
    }
    assert!(v["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 0.5);
    assert!(v["error_vs_truth"]["translation_m"].as_f64().unwrap() < 0.01);
    assert_eq!(v["deterministic"], true);
    assert!(!v["icp_levels"].as_array().unwrap().is_empty());
    // The text table says the same.
    let (code, out, err) = depthcal(&["profile", "--synthetic", "5000", "--repeat", "1"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("icp") && out.contains("ICP level 0") && out.contains("error vs truth"),
        "{out}"
    );
}

#[test]
fn the_fine_stage_alone_runs_from_the_guess() {
    let (code, out, err) = depthcal(&[
        "profile",
        "--synthetic",
        "20000",
        "--stages",
        "icp",
        "--repeat",
        "1",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert_eq!(v["fine_only"], true);
    assert_eq!(v["stages"].as_array().unwrap().len(), 1);
    assert!(v["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 0.5);
    // Two files: the fine stage needs --init.
    let (s, t) = (
        format!("{CLOUDS}/demo_source.ply"),
        format!("{CLOUDS}/demo_target.ply"),
    );
    let (code, _, err) = depthcal(&["profile", &s, &t, "--stages", "icp,total"]);
    assert_eq!(code, 1);
    assert!(err.contains("initial guess"), "{err}");
    let truth = format!("{CLOUDS}/demo_truth.txt");
    let (code, out, err) = depthcal(&[
        "profile",
        &s,
        &t,
        "--stages",
        "read,icp,total",
        "--init",
        &truth,
        "--truth",
        &truth,
        "--repeat",
        "1",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    assert_eq!(v["stages"].as_array().unwrap().len(), 3);
    assert!(v["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 1.0);
}

#[test]
fn bad_arguments_are_named() {
    let (code, _, err) = depthcal(&["profile", "--synthetic", "1000", "--stages", "icpp"]);
    assert_eq!(code, 1);
    assert!(err.contains("icpp"), "{err}");
    let (code, _, err) = depthcal(&["profile", "--synthetic", "1000", "--repeat", "0"]);
    assert_eq!(code, 1);
    assert!(err.contains("repeat"), "{err}");
    let (code, _, err) = depthcal(&["profile", "--synthetic", "10"]);
    assert_eq!(code, 1);
    assert!(err.contains("100 to"), "{err}");
    let (code, _, err) = depthcal(&["profile"]);
    assert_eq!(code, 1);
    assert!(err.contains("--synthetic"), "{err}");
    let s = format!("{CLOUDS}/demo_source.ply");
    let (code, _, err) = depthcal(&["profile", &s, &s, "--synthetic", "1000"]);
    assert_eq!(code, 1);
    assert!(err.contains("one or the other"), "{err}");
}

#[test]
fn a_written_synthetic_pair_profiles_from_its_files_as_generated() {
    let d = common::scratch("profile-write-pair").join("pair");
    let (code, out, err) = depthcal(&[
        "profile",
        "--synthetic",
        "20000",
        "--seed",
        "5",
        "--write-pair",
        d.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("wrote"), "{out}");
    let f = |n: &str| d.join(n).to_str().unwrap().to_string();
    // The files give the same fine stage as the generated pair: same clouds, same guess, same truth.
    let fine_stage = |input: &[&str]| {
        let mut args = vec!["profile"];
        args.extend_from_slice(input);
        args.extend_from_slice(&["--stages", "icp", "--repeat", "1", "--json"]);
        json(&depthcal(&args).1)
    };
    let (s, t, init, truth) = (
        f("source.ply"),
        f("target.ply"),
        f("init.txt"),
        f("truth.txt"),
    );
    let from_files = fine_stage(&[&s, &t, "--init", &init, "--truth", &truth]);
    let generated = fine_stage(&["--synthetic", "20000", "--seed", "5"]);
    assert_eq!(from_files["points"], generated["points"]);
    let err = |v: &serde_json::Value| v["error_vs_truth"]["rotation_deg"].as_f64().unwrap();
    assert!((err(&from_files) - err(&generated)).abs() < 1e-6);
    assert!(err(&from_files) < 0.5);
    // It needs --synthetic (a usage error).
    let (code, _, err) = depthcal(&["profile", "--write-pair", d.to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--synthetic"), "{err}");
}
