//! The CLI against a hostile user (issue 15): outputs that are inputs, interrupted writes, absurd thread
//! counts, cell paths leaving the cell, checks that came only after the work, misleading messages. Each
//! case asserts the exit status, the message, and that the inputs are byte-identical afterwards.

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn clouds() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("clouds")
}

/// A copy of the demo clouds and of the demo cell in a scratch directory.
fn workspace(name: &str) -> PathBuf {
    let d = scratch(name);
    for f in ["demo_source.ply", "demo_target.ply"] {
        std::fs::copy(clouds().join(f), d.join(f)).unwrap();
    }
    copy_dir(&clouds().join("demo-cell"), &d.join("cell"));
    d
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let q = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

fn temp_files(dir: &Path) -> Vec<PathBuf> {
    listing(dir)
        .into_iter()
        .map(|(p, _)| p)
        .filter(|p| depthcal::tempfiles::is_temp_path(p))
        .collect()
}

fn set_poses(cell: &Path, robot_poses: &str) {
    let m = cell.join("cell.toml");
    let t = std::fs::read_to_string(&m).unwrap();
    std::fs::write(&m, t.replace("\"left/poses.csv\"", robot_poses)).unwrap();
}

#[test]
fn an_output_that_is_an_input_is_refused() {
    let d = workspace("same-file");
    let (src, tgt) = (d.join("demo_source.ply"), d.join("demo_target.ply"));
    std::os::unix::fs::symlink(&src, d.join("link.ply")).unwrap();
    std::fs::hard_link(&tgt, d.join("hard.ply")).unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    let poses = d.join("cell/left/poses.csv");
    std::fs::hard_link(&poses, d.join("poses_link.ply")).unwrap();
    let before = listing(&d);
    let sub_src = format!("{}/sub/../demo_source.ply", d.display());
    let dot_tgt = format!("{}/./demo_target.ply", d.display());
    for (out, input) in [
        (s(&src), "SOURCE"),
        (sub_src.as_str(), "SOURCE"),
        (dot_tgt.as_str(), "TARGET"),
        (s(&d.join("link.ply")), "SOURCE"),
        (s(&d.join("hard.ply")), "TARGET"),
    ] {
        let (code, stdout, stderr) = depthcal(&["register", s(&src), s(&tgt), "--output", out]);
        assert_eq!(code, 1, "{out}: {stderr}");
        assert!(stdout.is_empty(), "{stdout}");
        assert!(
            stderr.contains("refusing to write --output")
                && stderr.contains(out)
                && stderr.contains(input),
            "{stderr}"
        );
    }
    // convert p.csv --output p.csv, any spelling.
    let other = format!("{}/cell/left/../left/poses.csv", d.display());
    for out in [s(&poses), other.as_str()] {
        let (code, _, stderr) =
            depthcal(&["convert", s(&poses), "--to", "matrix", "--output", out]);
        assert_eq!(code, 1, "{stderr}");
        assert!(
            stderr.contains("refusing to write --output") && stderr.contains("pose file"),
            "{stderr}"
        );
    }
    // fuse: a hard link to a file the cell reads.
    let (code, _, stderr) = depthcal(&[
        "fuse",
        s(&d.join("cell")),
        "--output",
        s(&d.join("poses_link.ply")),
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("refusing to write --output") && stderr.contains("robot \"left\"'s poses"),
        "{stderr}"
    );
    assert_eq!(listing(&d), before, "an input changed");
}

#[test]
fn outputs_are_checked_before_any_work() {
    let d = workspace("late-checks");
    let (src, tgt) = (d.join("demo_source.ply"), d.join("demo_target.ply"));
    let before = listing(&d);
    let missing = d.join("no/such/dir/out.ply");
    let t = Instant::now();
    let (code, _, stderr) = depthcal(&["register", s(&src), s(&tgt), "--output", s(&missing)]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("does not exist"), "{stderr}");
    let (code, _, stderr) = depthcal(&[
        "register",
        s(&src),
        s(&tgt),
        "--output",
        s(&d.join("out.pcd")),
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("unsupported output extension .pcd") && stderr.contains(".ply"),
        "{stderr}"
    );
    let (code, _, stderr) = depthcal(&[
        "fuse",
        s(&d.join("cell")),
        "--output",
        s(&d.join("nodir/fused.ply")),
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("does not exist"), "{stderr}");
    // A malformed optional ground_truth.json: reported before calibrating (which takes seconds).
    std::fs::write(
        d.join("cell/ground_truth.json"),
        "{\"T_base1_base2\": [1, 2",
    )
    .unwrap();
    for cmd in ["calibrate", "compare"] {
        let (code, stdout, stderr) = depthcal(&[cmd, s(&d.join("cell"))]);
        assert_eq!(code, 1, "{stderr}");
        assert!(
            stdout.is_empty() && stderr.contains("ground_truth.json"),
            "{stderr}"
        );
    }
    assert!(
        t.elapsed() < Duration::from_secs(3),
        "checks took {:?}",
        t.elapsed()
    );
    let mut after = listing(&d);
    after.retain(|(p, _)| !p.ends_with("ground_truth.json"));
    let mut b = before;
    b.retain(|(p, _)| !p.ends_with("ground_truth.json"));
    assert_eq!(after, b);
}

#[test]
fn thread_counts_are_capped_before_any_work() {
    let src = clouds().join("demo_source.ply");
    let tgt = clouds().join("demo_target.ply");
    let t = Instant::now();
    for n in ["100000", "2000", "18446744073709551615"] {
        let (code, stdout, stderr) = depthcal(&["--threads", n, "register", s(&src), s(&tgt)]);
        assert_eq!(code, 2, "{n}: {stderr}");
        assert!(stdout.is_empty());
        assert!(
            stderr.contains(&format!("--threads {n} is more than")) && stderr.contains("per core"),
            "{stderr}"
        );
    }
    let (code, _, stderr) = depthcal(&["--threads", "18446744073709551616", "register", "a", "b"]);
    assert_eq!(code, 2, "{stderr}");
    let (code, _, stderr) = depthcal(&["--threads", "0", "register", "a", "b"]);
    assert!(code == 2 && stderr.contains("at least 1"), "{stderr}");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_depthcal"))
        .args(["register", s(&src), s(&tgt)])
        .env("RAYON_NUM_THREADS", "100000")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("RAYON_NUM_THREADS 100000 is more than"),
        "{stderr}"
    );
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
}

#[test]
fn cell_paths_stay_in_the_cell() {
    let d = workspace("cell-paths");
    let cell = d.join("cell");
    let out = d.join("fused.ply");
    let secret = d.join("secret.csv");
    std::fs::write(
        &secret,
        "top secret line\nframe,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n",
    )
    .unwrap();
    let run = || depthcal(&["fuse", s(&cell), "--output", s(&out)]);
    set_poses(&cell, "\"../../../../etc/passwd\"");
    let before = listing(&d);
    let (code, _, stderr) = run();
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains(
            "field `poses` = \"../../../../etc/passwd\" leads outside the cell directory"
        ) && stderr.contains("allow_outside_paths = true")
            && !stderr.contains("root:"),
        "{stderr}"
    );
    let m = std::fs::read_to_string(cell.join("cell.toml")).unwrap();
    std::fs::write(
        cell.join("cell.toml"),
        m.replace("\"../../../../etc/passwd\"", &format!("{:?}", s(&secret))),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("is an absolute path") && !stderr.contains("top secret"),
        "{stderr}"
    );
    // A symlink inside the cell that leads out of it.
    std::os::unix::fs::symlink(&secret, cell.join("left/escape.csv")).unwrap();
    let m = std::fs::read_to_string(cell.join("cell.toml")).unwrap();
    std::fs::write(
        cell.join("cell.toml"),
        m.replace(&format!("{:?}", s(&secret)), "\"left/escape.csv\""),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("leads outside the cell directory") && !stderr.contains("top secret"),
        "{stderr}"
    );
    // The opt-in follows the path, but an error still does not echo the file's lines.
    let m = std::fs::read_to_string(cell.join("cell.toml")).unwrap();
    std::fs::write(
        cell.join("cell.toml"),
        format!("allow_outside_paths = true\n{m}"),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("outside the cell directory: its content is not shown")
            && !stderr.contains("top secret"),
        "{stderr}"
    );
    // A temporary file is never read as data.
    std::fs::copy(
        cell.join("left/poses.csv"),
        cell.join("left/.poses.csv.tmp-1"),
    )
    .unwrap();
    let m = std::fs::read_to_string(cell.join("cell.toml")).unwrap();
    std::fs::write(
        cell.join("cell.toml"),
        m.replace("\"left/escape.csv\"", "\"left/.poses.csv.tmp-1\""),
    )
    .unwrap();
    let (code, _, stderr) = run();
    assert_eq!(code, 1, "{stderr}");
    assert!(stderr.contains("temporary file"), "{stderr}");
    assert!(!out.exists());
    assert_eq!(
        listing(&d)
            .into_iter()
            .filter(|(p, _)| p.starts_with(d.join("cell/right")))
            .collect::<Vec<_>>(),
        before
            .into_iter()
            .filter(|(p, _)| p.starts_with(d.join("cell/right")))
            .collect::<Vec<_>>()
    );
}

#[test]
fn sigterm_and_sigint_leave_no_temporary_files() {
    for (sig, code) in [(libc::SIGTERM, 143), (libc::SIGINT, 130)] {
        let d = scratch(&format!("signal-{sig}"));
        let out = d.join("sim");
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_depthcal"))
            .args(["simulate", s(&out), "--frames", "60", "--seed", "3"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // Wait until it is writing frames, then interrupt it.
        let t = Instant::now();
        while listing(&out).len() < 3 && t.elapsed() < Duration::from_secs(30) {
            std::thread::sleep(Duration::from_millis(20));
        }
        // SAFETY: signalling our own child.
        unsafe { libc::kill(child.id() as libc::pid_t, sig) };
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "signal {sig}: {status:?}");
        assert!(temp_files(&d).is_empty(), "{:?}", temp_files(&d));
        assert!(!out.join("cell.toml").exists(), "the cell was finished");
    }
}

#[test]
fn stale_temporary_files_are_removed_when_writing_beside_them() {
    let d = workspace("stale");
    // A process that has ended: its pid is free.
    let mut c = std::process::Command::new("true").spawn().unwrap();
    let dead = c.id();
    c.wait().unwrap();
    let stale = d.join(format!(".aligned.ply.tmp-{dead}"));
    let live = d.join(format!(".other.ply.tmp-{}", std::process::id()));
    std::fs::write(&stale, b"half a cloud").unwrap();
    std::fs::write(&live, b"being written").unwrap();
    let (src, tgt) = (d.join("demo_source.ply"), d.join("demo_target.ply"));
    let (code, _, stderr) = depthcal(&[
        "register",
        s(&src),
        s(&tgt),
        "--output",
        s(&d.join("aligned.ply")),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(d.join("aligned.ply").exists());
    assert!(!stale.exists(), "the stale temporary file is still there");
    assert!(live.exists(), "a live process's temporary file was removed");
}

#[test]
fn the_readme_crop_syntax_is_accepted() {
    let d = workspace("crop");
    let out = d.join("left.ply");
    let cell = d.join("cell");
    for crop in [
        vec!["--crop", "-0.5,-1,0,1,0.5,0.5"],
        vec!["--crop=-0.5,-1,0,1,0.5,0.5"],
    ] {
        let mut args = vec!["fuse", s(&cell), "--output", s(&out)];
        args.extend(crop);
        let (code, stdout, stderr) = depthcal(&args);
        assert_eq!(code, 0, "{stderr}");
        assert!(stdout.contains("wrote"), "{stdout}");
    }
    let (code, _, stderr) = depthcal(&["fuse", s(&cell), "--output", s(&out), "--crop", "1,2,3"]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains("expected 6 numbers x0,y0,z0,x1,y1,z1"),
        "{stderr}"
    );
}

#[test]
fn millimetres_onto_metres_is_named() {
    let d = workspace("units");
    let src = d.join("demo_source.ply");
    let mut mm = depthcal::io::read_cloud(&src).unwrap();
    for p in &mut mm.points {
        for v in p.iter_mut() {
            *v *= 1000.0;
        }
    }
    let src_mm = d.join("source_mm.ply");
    depthcal::io::write_cloud(&src_mm, &mm).unwrap();
    let before = listing(&d);
    let (code, _, stderr) = depthcal(&["register", s(&src_mm), s(&d.join("demo_target.ply"))]);
    assert!(code == 1 || code == 3, "{code}: {stderr}");
    assert!(
        stderr.contains("warning: the extents of SOURCE")
            && stderr.contains("millimetres vs metres")
            && stderr.matches("millimetres vs metres").count() >= 2,
        "{stderr}"
    );
    assert_eq!(listing(&d), before);
}

#[test]
fn a_voxel_larger_than_the_cloud_is_named() {
    let (src, tgt) = (
        clouds().join("demo_source.ply"),
        clouds().join("demo_target.ply"),
    );
    let (code, _, stderr) = depthcal(&["register", s(&src), s(&tgt), "--voxel", "100"]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("voxel 100 exceeds the extent of the clouds")
            && stderr.contains("SOURCE 5.98")
            && stderr.contains("TARGET 4.65"),
        "{stderr}"
    );
    let (code, _, stderr) = depthcal(&["register", s(&src), s(&tgt), "--voxel=-1"]);
    assert!(code == 1 && stderr.contains("positive"), "{stderr}");
}

#[test]
fn fusing_into_a_few_points_is_an_error() {
    let d = workspace("fuse-voxel");
    let out = d.join("fused.ply");
    let before = listing(&d);
    let (code, _, stderr) = depthcal(&[
        "fuse",
        s(&d.join("cell")),
        "--output",
        s(&out),
        "--voxel",
        "1e9",
    ]);
    assert_eq!(code, 1, "{stderr}");
    assert!(
        stderr.contains("the fused cloud has only") && stderr.contains("too few to register"),
        "{stderr}"
    );
    assert!(!out.exists());
    assert_eq!(listing(&d), before);
}
