//! Cells of three or more robots through the CLI: `simulate --robots N` writes every robot's truth,
//! `calibrate` solves every base at once (each within 0.1° / 2 mm of the truth, trusted, normalised errors
//! below 3), a robot whose frames show another scene is named and not given a pose (exit 3, the others
//! still printed), and bad cells and flags are errors naming the key.
//!
//! Cells of the independent generator too (`tests/common/foreign.rs`, robots round a table, the idle
//! ones' arms in candle pose in view, RealSense-like artefacts, no `[priors]`): one 3-robot and one 4-robot
//! cell in CI; `DEPTHCAL_MULTI_SWEEP=N cargo test --release --test multi_robot foreign -- --nocapture`
//! runs N seeds of each (`DEPTHCAL_MULTI_SWEEP_FIRST=S`, default 4000) and prints one line per robot.

mod common;
use common::foreign::{generate, Aim, ForeignConfig, Ground, Rand};
use common::{depthcal, scratch};
use serde_json::Value;
use std::path::Path;

fn json(out: &str) -> Value {
    serde_json::from_str(out).unwrap_or_else(|e| panic!("{e}: {out}"))
}

fn simulate(dir: &Path, robots: usize, seed: u64) -> Value {
    let (code, out, err) = depthcal(&[
        "simulate",
        dir.to_str().unwrap(),
        "--robots",
        &robots.to_string(),
        "--seed",
        &seed.to_string(),
        "--frames",
        "16",
        "--no-color",
        "--force",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    json(&out)
}

/// The robot's entry of `calibrate --json`'s `robots`.
fn robot<'a>(v: &'a Value, name: &str) -> &'a Value {
    v["robots"]
        .as_array()
        .expect("robots")
        .iter()
        .find(|r| r["name"] == name)
        .unwrap_or_else(|| panic!("no robot {name}: {}", v["robots"]))
}

#[test]
fn three_robots_round_a_table_are_each_right_and_trusted() {
    let dir = scratch("multi-three");
    let sim = simulate(&dir, 3, 5);
    assert_eq!(sim["robots"].as_array().unwrap().len(), 3);
    assert_eq!(sim["shared_fraction"].as_array().unwrap().len(), 3);
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("ground_truth.json")).unwrap())
            .unwrap();
    assert_eq!(truth["robots"].as_array().unwrap().len(), 3);
    let outdir = scratch("multi-three-out");
    let _ = std::fs::remove_dir_all(&outdir);
    let (code, out, err) = depthcal(&[
        "calibrate",
        dir.to_str().unwrap(),
        "--json",
        "--output",
        outdir.to_str().unwrap(),
    ]);
    let v = json(&out);
    assert_eq!(code, 0, "{err}\n{}", v["reasons"]);
    assert_eq!(v["trusted"], true);
    for name in ["right", "robot3"] {
        let r = robot(&v, name);
        assert_eq!(r["trusted"], true, "{r}");
        let rot = r["error_vs_truth"]["rotation_deg"].as_f64().unwrap();
        let t = r["error_vs_truth"]["translation_m"].as_f64().unwrap();
        assert!(rot < 0.1 && t < 0.002, "{name}: {rot} deg, {t} m");
        for part in ["rotation", "translation"] {
            let z = r["normalised_error"][part].as_f64().unwrap();
            assert!(z < 3.0, "{name}: normalised {part} {z}");
        }
        assert!(r["ros2"]
            .as_str()
            .unwrap()
            .contains(&format!("{name}_base")));
    }
    let pairs = v["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for p in pairs {
        assert_eq!(p["verdict"], "agrees", "{p}");
        assert!(p["loop_error"].as_f64().unwrap() < 4.0, "{p}");
    }
    // The two-robot fields show the first other robot in the joint solution.
    assert_eq!(v["other"], "right");
    assert_eq!(
        v["transform"]["matrix"],
        robot(&v, "right")["transform"]["matrix"]
    );
    // --output: one static transform (joint, TF entry) per robot, each robot's matrix and controller
    // frames, every robot's cloud, the JSON.
    let read =
        |f: &str| std::fs::read_to_string(outdir.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
    let launch = read("static_tf.launch.py");
    assert_eq!(
        launch.matches("static_transform_publisher").count(),
        2,
        "{launch}"
    );
    assert!(
        launch.contains("\"--child-frame-id\", \"robot3_base\""),
        "{launch}"
    );
    let urdf = read("base_joint.urdf.xacro");
    assert_eq!(urdf.matches("<joint ").count(), 2, "{urdf}");
    let tf = read("tf.yaml");
    assert_eq!(tf.matches("child_frame_id:").count(), 2, "{tf}");
    for name in ["right", "robot3"] {
        let m: Vec<f64> = read(&format!("T_left_{name}.txt"))
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        let want: Vec<f64> = robot(&v, name)["transform"]["matrix"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|row| row.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
            .collect();
        assert_eq!(m.len(), 16);
        assert!(
            m.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-9),
            "{m:?} vs {want:?}"
        );
        for f in ["kuka_base", "ur_pose", "abb_wobj"] {
            assert!(read(&format!("{f}_{name}.txt")).contains(&format!("{name}_base")));
        }
        assert!(outdir.join(format!("cloud_{name}.ply")).is_file());
    }
    assert!(outdir.join("cloud_reference.ply").is_file());
    assert_eq!(json(&read("calibration.json"))["robots"], v["robots"]);
    // Run again into the same directory (it holds only what calibrate writes), on one thread: every
    // robot's pose is bit-identical.
    let (code, out, err) = depthcal(&[
        "--threads",
        "1",
        "calibrate",
        dir.to_str().unwrap(),
        "--json",
        "--output",
        outdir.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let one = json(&out);
    for name in ["right", "robot3"] {
        assert_eq!(
            robot(&one, name)["transform"],
            robot(&v, name)["transform"],
            "{name}: one thread against all"
        );
    }
    common::assert_documented(&v);
    for r in v["robots"].as_array().unwrap() {
        common::assert_documented_section(r, "depthcal.calibration/1", " robot entries");
    }
    for p in pairs {
        common::assert_documented_section(p, "depthcal.calibration/1", " pair entries");
    }
}

#[test]
fn a_robot_whose_frames_show_another_scene_is_not_calibrated() {
    let dir = scratch("multi-foreign-robot");
    let other = scratch("multi-foreign-robot-source");
    simulate(&dir, 3, 8);
    simulate(&other, 3, 9);
    // robot3's frames, poses and hand-eye from another cell.
    let r3 = dir.join("robot3");
    std::fs::remove_dir_all(&r3).unwrap();
    std::fs::create_dir_all(r3.join("depth")).unwrap();
    for f in ["poses.csv", "intrinsics.json"] {
        std::fs::copy(other.join("robot3").join(f), r3.join(f)).unwrap();
    }
    for e in std::fs::read_dir(other.join("robot3/depth")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), r3.join("depth").join(e.file_name())).unwrap();
    }
    let hand_eye = |text: &str| -> String {
        let at = text.find("name = \"robot3\"").unwrap();
        let line = text[at..]
            .lines()
            .find(|l| l.starts_with("hand_eye"))
            .unwrap();
        line.to_string()
    };
    let mine = std::fs::read_to_string(dir.join("cell.toml")).unwrap();
    let theirs = std::fs::read_to_string(other.join("cell.toml")).unwrap();
    let text = mine.replace(&hand_eye(&mine), &hand_eye(&theirs));
    std::fs::write(dir.join("cell.toml"), text).unwrap();
    let (code, out, err) = depthcal(&["calibrate", dir.to_str().unwrap(), "--json"]);
    assert_eq!(code, 3, "{err}");
    let v = json(&out);
    let r3 = robot(&v, "robot3");
    assert_eq!(r3["trusted"], false, "{r3}");
    assert!(r3["transform"].is_null(), "{r3}");
    let why = r3["reasons"].to_string();
    assert!(
        why.contains("robot \\\"robot3\\\" is not calibrated")
            && why.contains("pair left - robot3"),
        "{why}"
    );
    // The other robot is still calibrated, and right.
    let right = robot(&v, "right");
    assert_eq!(right["trusted"], true, "{right}");
    assert!(right["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 0.1);
    // The text names it too, and the report shows it without a pose and says why.
    let report = scratch("multi-foreign-robot-report");
    let (code, out, _) = depthcal(&[
        "calibrate",
        dir.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert_eq!(code, 3);
    let html = std::fs::read_to_string(report.join("report.html")).unwrap();
    assert!(html.contains("data-trusted=\"false\""));
    assert!(html.contains("NOT calibrated") && html.contains("no pose:"));
    assert!(html.contains("robot &quot;robot3&quot; is not calibrated"));
    assert!(out.contains("T_left_robot3: NOT calibrated"), "{out}");
    assert!(
        out.contains("T_left_right: right base -> left base"),
        "{out}"
    );
    // plan names robot3 as the weakest base and says why each of its pairs does not count.
    let (code, plan, err) = depthcal(&["plan", dir.to_str().unwrap(), "--json"]);
    assert_eq!(code, 3, "{err}");
    let p = json(&plan);
    let r = &p["robots"];
    assert_eq!(r["weakest"], "robot3", "{r}");
    assert!(r["bases"][1]["sigma_mm"].is_null());
    for q in r["pairs"].as_array().unwrap() {
        assert_eq!(q["verdict"], "not_usable", "{q}");
        assert!(q["advice"]
            .as_str()
            .unwrap()
            .contains("not trusted on its own"));
    }
}

#[test]
fn compare_sets_every_route_to_each_base_side_by_side() {
    let dir = scratch("multi-compare");
    simulate(&dir, 3, 6);
    let (code, out, err) = depthcal(&["compare", dir.to_str().unwrap(), "--json"]);
    let v = json(&out);
    assert_eq!(code, 0, "{err}\n{}", v["reasons"]);
    common::assert_documented(&v);
    let pairs = v["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for r in v["robots"].as_array().unwrap() {
        common::assert_documented_section(r, "depthcal.routes/1", " robot entries");
        let name = r["name"].as_str().unwrap();
        let routes = r["routes"].as_array().unwrap();
        let names: Vec<&str> = routes
            .iter()
            .map(|x| x["route"].as_str().unwrap())
            .collect();
        let other = if name == "right" { "robot3" } else { "right" };
        assert_eq!(
            names,
            [
                "joint solution".to_string(),
                format!("left - {name}"),
                format!("left - {other} - {name}")
            ],
            "{name}"
        );
        assert_eq!(routes[0]["from_joint"]["translation_m"], 0.0);
        // The direct route is the pair's own result.
        let direct = pairs
            .iter()
            .find(|p| p["reference"] == "left" && p["other"] == name)
            .unwrap();
        assert_eq!(routes[1]["transform"], direct["transform"]);
        for x in routes {
            common::assert_documented_section(x, "depthcal.routes/1", " route entries");
            assert_eq!(x["trusted"], true, "{x}");
            let e = &x["error_vs_truth"];
            let (deg, m) = (
                e["rotation_deg"].as_f64().unwrap(),
                e["translation_m"].as_f64().unwrap(),
            );
            assert!(
                deg < 0.1 && m < 0.002,
                "{name} {}: {deg} deg {m} m",
                x["route"]
            );
            let z = x["normalised_error"]["pose"].as_f64().unwrap();
            assert!(z < 3.0, "{name} {}: normalised {z}", x["route"]);
        }
        assert!(names.contains(&r["best_vs_truth"].as_str().unwrap()));
    }
    // The text shows the same routes.
    let (code, out, _) = depthcal(&["compare", dir.to_str().unwrap()]);
    assert_eq!(code, 0);
    assert!(
        out.contains("left - right - robot3") && out.contains("closest to the truth"),
        "{out}"
    );
    // plan: every base's strength, the weakest is the largest 1-σ, the planned pair touches it.
    let (code, out, err) = depthcal(&["plan", dir.to_str().unwrap(), "--json"]);
    assert_eq!(code, 0, "{err}");
    let p = json(&out);
    common::assert_documented(&p);
    let r = &p["robots"];
    let bases = r["bases"].as_array().unwrap();
    assert_eq!(bases.len(), 2);
    let weakest = bases
        .iter()
        .max_by(|a, b| {
            a["sigma_mm"]
                .as_f64()
                .unwrap()
                .total_cmp(&b["sigma_mm"].as_f64().unwrap())
        })
        .unwrap();
    assert_eq!(r["weakest"], weakest["robot"]);
    let planned = r["planned_pair"].as_array().unwrap();
    assert!(planned.contains(&r["weakest"]), "{r}");
    assert_eq!(p["reference"], planned[0]);
    assert_eq!(p["other"], planned[1]);
    assert_eq!(r["pairs"].as_array().unwrap().len(), 2);
    assert_eq!(p["hand_eyes"].as_array().unwrap().len(), 2);
    assert!(r["pair_inputs_sigma_mm"].as_f64().unwrap() > 0.0);
}

#[test]
fn bad_cells_and_flags_of_many_robots_are_errors() {
    let dir = scratch("multi-bad");
    simulate(&dir, 3, 2);
    let cell = dir.to_str().unwrap();
    // The two-robot flags, and the methods that name one pair.
    for (args, want) in [
        (vec!["--no-refine"], "for cells of two robots"),
        (vec!["--refine-hand-eye"], "for cells of two robots"),
        (vec!["--method", "marker"], "from depth (--method depth)"),
    ] {
        let mut a = vec!["calibrate", cell];
        a.extend(args.iter().copied());
        let (code, _, err) = depthcal(&a);
        assert_ne!(code, 0, "{args:?}");
        assert_ne!(code, 3, "{args:?}: an error, not an untrusted result");
        assert!(err.contains(want), "{args:?}: {err}");
    }
    // compare: the image methods and --no-refine give one pair.
    for (args, want) in [
        (vec!["--methods", "marker"], "--methods depth"),
        (vec!["--no-refine"], "for cells of two robots"),
    ] {
        let mut a = vec!["compare", cell];
        a.extend(args.iter().copied());
        let (code, _, err) = depthcal(&a);
        assert_eq!(code, 1, "compare {args:?}: {err}");
        assert!(err.contains(want), "compare {args:?}: {err}");
    }
    // A reference that is not a robot.
    let toml = std::fs::read_to_string(dir.join("cell.toml")).unwrap();
    std::fs::write(
        dir.join("cell.toml"),
        toml.replace("reference = \"left\"", "reference = \"nobody\""),
    )
    .unwrap();
    let (code, _, err) = depthcal(&["calibrate", cell]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("reference") && err.contains("nobody"), "{err}");
    // One robot only.
    let one = &toml[..toml.find("[[robot]]\nname = \"right\"").unwrap()];
    std::fs::write(dir.join("cell.toml"), one).unwrap();
    let (code, _, err) = depthcal(&["calibrate", cell]);
    assert_ne!(code, 0);
    assert!(err.contains("needs two robots"), "{err}");
    // The simulator's limits.
    for n in ["1", "9"] {
        let (code, _, err) = depthcal(&["simulate", cell, "--robots", n, "--force"]);
        assert_ne!(code, 0);
        assert!(err.contains("--robots"), "{err}");
    }
}

/// One foreign cell of `2 + extra` robots for `seed`: views 12-20, 640x480 or 424x240, flying pixels and
/// holes, every idle robot's arm in view, a floor at table level or a table on legs, sometimes pedestals.
/// `DEPTHCAL_MULTI_SWEEP_AIM=own_side` aims each robot's cameras at its own side of the table (robots
/// across the table then share little).
fn foreign_cell(seed: u64, extra: usize) -> ForeignConfig {
    let aim = match std::env::var("DEPTHCAL_MULTI_SWEEP_AIM").as_deref() {
        Ok("own_side") => Aim::OwnSide,
        _ => Aim::Shared,
    };
    let mut r = Rand::keyed(&[seed, 0x3417, extra as u64]);
    let views = 12 + (r.uniform() * 9.0) as usize;
    let (width, height) = if r.uniform() < 0.5 {
        (640, 480)
    } else {
        (424, 240)
    };
    ForeignConfig {
        seed,
        views,
        width,
        height,
        extra_robots: extra,
        other_robot_in_view: true,
        flying_pixels: true,
        holes: true,
        ground: if r.uniform() < 0.5 {
            Ground::FloorOnly
        } else {
            Ground::TableOnLegs
        },
        pedestal: r.uniform() < 0.3,
        pose_noise_mm: 0.1 * r.uniform(),
        aim,
        ..ForeignConfig::default()
    }
}

/// One robot of a calibrated cell: name, (rotation error °, translation error m) or `None` without a pose,
/// trusted, normalised pose error.
type RobotRow = (String, Option<(f64, f64)>, bool, Option<f64>);

/// Calibrates a foreign cell: the exit status and a row per robot but the reference.
fn run_foreign(cfg: &ForeignConfig) -> (i32, Vec<RobotRow>) {
    let dir = scratch(&format!("multi-foreign-{}-{}", cfg.seed, cfg.extra_robots));
    let cell = generate(&dir, cfg);
    let (code, out, err) = depthcal(&["calibrate", dir.to_str().unwrap(), "--json"]);
    assert!(code == 0 || code == 3, "{err}");
    let v = json(&out);
    let rows = cell.names[1..]
        .iter()
        .map(|name| {
            let r = robot(&v, name);
            let e = r["error_vs_truth"].as_object().map(|e| {
                (
                    e["rotation_deg"].as_f64().unwrap(),
                    e["translation_m"].as_f64().unwrap(),
                )
            });
            let z = r["normalised_error"]["pose"].as_f64();
            (name.clone(), e, r["trusted"] == true, z)
        })
        .collect();
    let _ = std::fs::remove_dir_all(&dir);
    (code, rows)
}

#[test]
fn foreign_cells_of_three_and_four_robots() {
    let n: u64 = std::env::var("DEPTHCAL_MULTI_SWEEP")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let first: u64 = std::env::var("DEPTHCAL_MULTI_SWEEP_FIRST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4000);
    let mut wrong_trusted = Vec::new();
    let mut counts = [0usize; 4]; // right+trusted, right+refused, wrong+refused, wrong+trusted
    for seed in first..first + n {
        for extra in [1, 2] {
            let cfg = foreign_cell(seed, extra);
            let (code, rows) = run_foreign(&cfg);
            for (name, e, trusted, z) in rows {
                let right = e.is_some_and(|(r, t)| r < 0.1 && t < 0.002);
                counts[match (right, trusted) {
                    (true, true) => 0,
                    (true, false) => 1,
                    (false, false) => 2,
                    (false, true) => 3,
                }] += 1;
                println!(
                    "seed {seed} robots {} {name}: {} trusted {trusted} z {} exit {code} ({} views {}x{}, {:?}, pedestal {}, aim {:?})",
                    2 + extra,
                    e.map_or("no pose".to_string(), |(r, t)| format!("{r:.4} deg / {:.3} mm", t * 1e3)),
                    z.map_or("-".to_string(), |z| format!("{z:.2}")),
                    cfg.views,
                    cfg.width,
                    cfg.height,
                    cfg.ground,
                    cfg.pedestal,
                    cfg.aim
                );
                if !right && trusted {
                    wrong_trusted.push(format!("seed {seed} robots {} {name}", 2 + extra));
                }
                if n == 1 && cfg.aim == Aim::Shared {
                    // The CI cells: every base right, trusted, with an honest covariance.
                    assert!(
                        right && trusted,
                        "seed {seed}, {} robots, {name}: {e:?}, trusted {trusted}",
                        2 + extra
                    );
                    assert!(z.is_some_and(|z| z < 3.0), "{name}: z {z:?}");
                }
            }
        }
    }
    println!(
        "robots right and trusted {}, right but refused {}, wrong and refused {}, wrong and trusted {}",
        counts[0], counts[1], counts[2], counts[3]
    );
    assert!(
        wrong_trusted.is_empty(),
        "wrong and trusted: {wrong_trusted:?}"
    );
}
