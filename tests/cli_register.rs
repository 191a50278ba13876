//! The `depthcal register` command as a user runs it: JSON contract, output files, and bad input.

mod common;
use common::*;
use depthcal::geometry::transform::{isometry_from_rows, pose_error, random_isometry};
use depthcal::geometry::Rng;
use depthcal::PointCloud;
use std::path::Path;

fn transform_of(json: &serde_json::Value) -> nalgebra::Isometry3<f64> {
    let m: Vec<f64> = json["transform"]["matrix"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()))
        .collect();
    isometry_from_rows(&m.try_into().unwrap(), "transform").unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn json_contract_output_file_and_init() {
    let dir = scratch("cli-json");
    let scene = synthetic_scene(4, 60_000);
    let (src, tgt, _) = split_overlapping(&scene, 3, 0.7, 0.001);
    let pose = random_isometry(&mut Rng::new(8), 2.5, 0.8);
    let (sp, tp) = (dir.join("s.pcd.ply"), dir.join("t.ply"));
    depthcal::io::write_cloud(&sp, &src.transformed(&pose)).unwrap();
    depthcal::io::write_ply_ascii(&tp, &tgt).unwrap();
    let out = dir.join("aligned.ply");
    let (code, stdout, stderr) = depthcal(&[
        "register",
        s(&sp),
        s(&tp),
        "--json",
        "--output",
        s(&out),
        "--seed",
        "5",
    ]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("stdout is one JSON object");
    common::assert_documented(&v);
    for key in [
        "transform",
        "fitness",
        "inlier_rmse_m",
        "overlap",
        "converged",
        "covariance",
        "timings_ms",
    ] {
        assert!(v.get(key).is_some(), "missing {key}");
    }
    assert_eq!(v["covariance"].as_array().unwrap().len(), 6);
    assert_eq!(v["schema"], "depthcal.registration/1");
    assert_eq!(
        v["transform"]["quaternion_xyzw"].as_array().unwrap().len(),
        4
    );
    assert!(v["converged"].as_bool().unwrap());
    let t = transform_of(&v);
    let (r, d) = pose_error(&t, &pose.inverse());
    assert!(r < 0.1 && d < 3e-3, "{r} deg {d} m");
    // The aligned source lies on the target.
    let aligned = depthcal::io::read_cloud(&out).unwrap();
    assert_eq!(aligned.len(), src.len());
    let (r, d) = pose_error(
        &depthcal::registration::rigid_fit(
            &aligned
                .points
                .iter()
                .map(depthcal::geometry::cloud::to_p64)
                .collect::<Vec<_>>(),
            &src.points
                .iter()
                .map(depthcal::geometry::cloud::to_p64)
                .collect::<Vec<_>>(),
            None,
        )
        .unwrap(),
        &nalgebra::Isometry3::identity(),
    );
    assert!(r < 0.1 && d < 3e-3);
    // A JSON result fed back as --init: ICP only, same answer.
    let init = dir.join("result.json");
    std::fs::write(&init, &stdout).unwrap();
    let (code, stdout2, stderr) =
        depthcal(&["register", s(&sp), s(&tp), "--json", "--init", s(&init)]);
    assert_eq!(code, 0, "{stderr}");
    let v2: serde_json::Value = serde_json::from_str(&stdout2).unwrap();
    assert!(v2["global"].is_null());
    let (r, d) = pose_error(&transform_of(&v2), &t);
    assert!(r < 0.01 && d < 1e-3);
    // Same seed, same bytes of transform.
    let (_, stdout3, _) = depthcal(&[
        "register",
        s(&sp),
        s(&tp),
        "--json",
        "--seed",
        "5",
        "--threads",
        "1",
    ]);
    let v3: serde_json::Value = serde_json::from_str(&stdout3).unwrap();
    assert_eq!(v3["transform"], v["transform"]);
}

fn write_bytes(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn expect_error(args: &[&str], must_name: &str, must_say: &str) {
    let (code, _, stderr) = depthcal(args);
    assert_ne!(code, 0, "expected failure for {args:?}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(
        stderr.contains(must_name),
        "error does not name {must_name}: {stderr}"
    );
    assert!(
        stderr.to_lowercase().contains(must_say),
        "error does not say `{must_say}`: {stderr}"
    );
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = scratch("cli-bad");
    let good = dir.join("good.ply");
    depthcal::io::write_cloud(&good, &synthetic_scene(1, 5000)).unwrap();
    let g = s(&good);

    let empty = write_bytes(&dir, "empty.ply", b"");
    expect_error(&["register", s(&empty), g], "empty.ply", "empty");

    let missing = dir.join("missing.ply");
    expect_error(&["register", s(&missing), g], "missing.ply", "no such file");

    let unknown = write_bytes(&dir, "cloud.obj", b"v 1 2 3\n");
    expect_error(
        &["register", s(&unknown), g],
        "cloud.obj",
        "unknown file format",
    );

    // Truncated binary PLY.
    let full = std::fs::read(&good).unwrap();
    let trunc = write_bytes(&dir, "truncated.ply", &full[..full.len() / 2]);
    expect_error(&["register", s(&trunc), g], "truncated.ply", "truncated");

    // Header lying about the vertex count (says more than there is).
    let text = b"ply\nformat ascii 1.0\nelement vertex 10\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n";
    let lying = write_bytes(&dir, "lying.ply", text);
    expect_error(&["register", s(&lying), g], "lying.ply", "truncated");

    // A two-point cloud.
    let two = write_bytes(&dir, "two.xyz", b"0 0 0\n1 1 1\n");
    expect_error(&["register", s(&two), g], "two.xyz", "at least 10");

    // Not numbers.
    let bad = write_bytes(&dir, "bad.xyz", b"0 0 0\n1 x 1\n");
    expect_error(&["register", s(&bad), g], "bad.xyz", "line 2");

    // A non-rigid --init matrix.
    let init = write_bytes(&dir, "scaled.txt", b"2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
    expect_error(
        &["register", g, g, "--init", s(&init)],
        "scaled.txt",
        "rotation",
    );

    // Output into a missing directory: error, nothing half-written.
    let (code, _, stderr) = depthcal(&[
        "register",
        g,
        g,
        "--output",
        s(&dir.join("nope/aligned.ply")),
    ]);
    assert_ne!(code, 0);
    assert!(stderr.contains("does not exist"), "{stderr}");
}

#[test]
fn nan_points_are_dropped_with_a_warning() {
    let dir = scratch("cli-nan");
    let scene = synthetic_scene(6, 40_000);
    let (src, tgt, _) = split_overlapping(&scene, 2, 0.7, 0.001);
    let mut with_nan = src.clone();
    for k in 0..50 {
        with_nan.points[k * 7] = [f32::NAN, 0.0, f32::INFINITY];
    }
    let (sp, tp) = (dir.join("nan.ply"), dir.join("t.ply"));
    depthcal::io::write_cloud(&sp, &with_nan).unwrap();
    depthcal::io::write_cloud(&tp, &tgt).unwrap();
    let (code, stdout, stderr) = depthcal(&["register", s(&sp), s(&tp), "--json"]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stderr.contains("50 source points"), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let (r, d) = pose_error(&transform_of(&v), &nalgebra::Isometry3::identity());
    assert!(r < 0.1 && d < 3e-3);
}

#[test]
fn planar_cloud_is_reported_degenerate() {
    let dir = scratch("cli-plane");
    let mut rng = Rng::new(3);
    let plane = |rng: &mut Rng| {
        PointCloud::from_points(
            (0..20_000)
                .map(|_| {
                    [
                        rng.uniform(0.0, 2.0) as f32,
                        rng.uniform(0.0, 2.0) as f32,
                        (0.0005 * rng.normal()) as f32,
                    ]
                })
                .collect(),
        )
    };
    let (a, b) = (plane(&mut rng), plane(&mut rng));
    let (ap, bp) = (dir.join("a.ply"), dir.join("b.ply"));
    depthcal::io::write_cloud(&ap, &a).unwrap();
    depthcal::io::write_cloud(&bp, &b).unwrap();
    let init = dir.join("id.txt");
    std::fs::write(&init, "1 0 0 0.01\n0 1 0 0\n0 0 1 0.002\n0 0 0 1\n").unwrap();
    let (code, stdout, stderr) =
        depthcal(&["register", s(&ap), s(&bp), "--json", "--init", s(&init)]);
    assert!(!stderr.contains("panicked"), "{stderr}");
    // A degenerate result is printed in full but not trusted: exit status 3.
    assert_eq!(code, 3, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["degenerate"], serde_json::json!(true), "{stdout}");
    assert_eq!(v["trusted"], serde_json::json!(false), "{stdout}");
    assert!(stderr.contains("unconstrained"), "{stderr}");
    // Without a guess, the global stage either fails with a message or returns a degenerate result.
    let (code, stdout, stderr) = depthcal(&["register", s(&ap), s(&bp), "--json"]);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_ne!(
        code, 0,
        "a bare plane is never a trusted registration: {stdout}"
    );
    if code == 3 {
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(v["trusted"], serde_json::json!(false));
    } else {
        assert!(stderr.contains("error"), "{stderr}");
    }
}
