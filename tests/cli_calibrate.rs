//! `depthcal calibrate` and `depthcal compare` end to end on the demo cell shipped in `clouds/demo-cell`
//! (simulated, depth only): the refined and the `--no-refine` reports, and `compare` skipping the image
//! methods with their reasons.

mod common;
use common::depthcal;

const DEMO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/clouds/demo-cell");

fn json(out: &str) -> serde_json::Value {
    serde_json::from_str(out).unwrap_or_else(|e| panic!("{e}: {out}"))
}

#[test]
fn calibrate_refines_and_no_refine_reports_the_initial_estimate() {
    let (code, out, err) = depthcal(&["calibrate", DEMO, "--json", "--threads", "2"]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    common::assert_documented(&v);
    assert_eq!(v["refined"], true);
    assert!(v["error_vs_truth"]["rotation_deg"].as_f64().unwrap() < 0.1);
    assert!(v["error_vs_truth"]["translation_m"].as_f64().unwrap() < 1e-3);
    let (code, out, err) =
        depthcal(&["calibrate", DEMO, "--json", "--no-refine", "--threads", "2"]);
    assert_eq!(code, 0, "{err}");
    let n = json(&out);
    common::assert_documented(&n);
    assert_eq!(n["refined"], false);
    assert_eq!(n["transform"], n["initial"]["transform"]);
    assert!(
        n["fitness"].is_null(),
        "no cloud quality without refinement: {}",
        n["fitness"]
    );
    assert!(
        n["initial"]["error_vs_truth"]["rotation_deg"]
            .as_f64()
            .unwrap()
            < 2.0
    );
    // The image methods need what the demo cell does not have.
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--method", "marker"]);
    assert_ne!(code, 0);
    assert!(err.contains("[markers]") || err.contains("vision"), "{err}");
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--method", "depth", "--detector", "orb"]);
    assert_ne!(code, 0);
    assert!(err.contains("--detector is for --method features"), "{err}");
}

#[test]
fn compare_runs_depth_and_says_why_the_others_are_skipped() {
    let (code, out, err) = depthcal(&["compare", DEMO, "--json", "--threads", "2"]);
    assert_eq!(code, 0, "{err}");
    let v = json(&out);
    common::assert_documented(&v);
    let m = v["methods"].as_array().unwrap();
    let depth = m.iter().find(|x| x["method"] == "depth").unwrap();
    assert_eq!(depth["status"], "ok");
    assert!(depth["error_vs_truth"]["translation_m"].as_f64().unwrap() < 1e-3);
    assert!(depth["disagreement"].is_null(), "nothing to disagree with");
    for name in ["checkerboard", "marker", "features"] {
        let x = m.iter().find(|x| x["method"] == name).unwrap();
        assert_eq!(x["status"], "skipped", "{x}");
        assert!(!x["reason"].as_str().unwrap().is_empty());
    }
    let (code, out, _) = depthcal(&["compare", DEMO, "--threads", "2"]);
    assert_eq!(code, 0);
    assert!(out.contains("depth") && out.contains("skipped"), "{out}");
}

/// Two bases cannot share one footprint: an answer that puts them 2 cm apart (here given with `--init`
/// and kept with `--no-refine`) is not trusted, and the reason gives the distance; `min_base_distance_m`
/// 0 turns the check off, and a negative one is an error naming the key.
#[test]
fn bases_on_top_of_each_other_are_not_trusted() {
    let dir = common::scratch("coincident-bases");
    let init = dir.join("init.txt");
    std::fs::write(&init, "1 0 0 0.02\n0 1 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let init = init.to_str().unwrap();
    let args = ["calibrate", DEMO, "--json", "--no-refine", "--init", init];
    let (code, out, err) = depthcal(&args);
    assert_eq!(code, 3, "{err}");
    let v = json(&out);
    assert_eq!(v["trusted"], false);
    let reasons = v["reasons"].to_string();
    assert!(
        reasons.contains("base would stand 0.020 m from robot")
            && reasons.contains("min_base_distance_m 0.12 m"),
        "{reasons}"
    );
    let off = dir.join("off.json");
    std::fs::write(&off, r#"{"min_base_distance_m": 0}"#).unwrap();
    let (_, out, err) = depthcal(&[&args[..], &["--config", off.to_str().unwrap()]].concat());
    let v = json(&out);
    assert!(
        !v["reasons"].to_string().contains("base would stand"),
        "{err}"
    );
    let bad = dir.join("bad.json");
    std::fs::write(&bad, r#"{"min_base_distance_m": -1}"#).unwrap();
    let (code, _, err) = depthcal(&["calibrate", DEMO, "--config", bad.to_str().unwrap()]);
    assert_ne!(code, 0);
    assert!(err.contains("min_base_distance_m"), "{err}");
}

/// The precision bound: the demo cell's registration leaves a 1-σ of a few hundredths of a degree and a
/// fraction of a millimetre, so with the bound set below that the same answer is not trusted and the reason
/// gives the spread and the bound; the default trusts it.
#[test]
fn an_answer_the_geometry_pins_too_loosely_is_not_trusted() {
    let dir = common::scratch("precision-bound");
    let tight = dir.join("tight.json");
    std::fs::write(
        &tight,
        r#"{"max_registration_sigma_deg": 0.001, "max_registration_sigma_m": null}"#,
    )
    .unwrap();
    let (code, out, err) = depthcal(&[
        "calibrate",
        DEMO,
        "--json",
        "--threads",
        "2",
        "--config",
        tight.to_str().unwrap(),
    ]);
    assert_eq!(code, 3, "{err}");
    let v = json(&out);
    assert_eq!(v["trusted"], false);
    let reasons = v["reasons"].to_string();
    assert!(
        reasons.contains("the geometry pins the answer only to")
            && reasons.contains("more than the 0.001° / none"),
        "{reasons}"
    );
    // The answer is the default run's: the bound reads the result, it does not change it.
    let (code, def, err) = depthcal(&["calibrate", DEMO, "--json", "--threads", "2"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(json(&def)["transform"], v["transform"]);
}

/// A cell of three robots whose third is the second's frames again under another name: each pair with
/// the reference is trusted on its own, but the joint solution puts two bases on one footprint, so
/// neither is trusted (exit 3); every robot is in the JSON.
#[test]
fn a_third_robot_with_the_second_robots_frames_is_not_trusted() {
    let dir = common::scratch("three-robots");
    let demo = std::fs::read_to_string(format!("{DEMO}/cell.toml")).unwrap();
    let right =
        &demo[demo.find("[[robot]]\nname = \"right\"").unwrap()..demo.find("[priors]").unwrap()];
    let text = format!("{demo}\n{}", right.replace("\"right\"", "\"third\""))
        .replace("\"left/", &format!("\"{DEMO}/left/"))
        .replace("\"right/", &format!("\"{DEMO}/right/"));
    // The [priors] table must stay last: move the third robot above it.
    let (head, priors) = text.split_at(text.find("[priors]").unwrap());
    let (priors, third) = priors.split_at(priors.find("[[robot]]").unwrap());
    std::fs::write(
        dir.join("cell.toml"),
        format!("allow_outside_paths = true\n{head}{third}\n{priors}"),
    )
    .unwrap();
    let cell = dir.to_str().unwrap();
    let (code, out, err) = depthcal(&["calibrate", cell, "--json"]);
    assert_eq!(code, 3, "{err}");
    let v = json(&out);
    let robots = v["robots"].as_array().expect("robots");
    assert_eq!(robots.len(), 2, "{}", v["robots"]);
    for r in robots {
        assert_eq!(r["trusted"], false, "{r}");
        assert!(
            r["reasons"]
                .to_string()
                .contains("closer than two robots' bases can"),
            "{r}"
        );
    }
    assert_eq!(v["pairs"].as_array().unwrap().len(), 3);
    assert_eq!(v["trusted"], false);
    // The flags of the two-robot path are refused with a reason.
    let (_, _, err) = depthcal(&["calibrate", cell, "--no-refine"]);
    assert!(
        err.contains("--no-refine and --refine-hand-eye are for cells of two robots"),
        "{err}"
    );
}
