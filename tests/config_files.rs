//! `--config` JSON files of `register` and `calibrate`: an unknown key is an error that names the key, an
//! out-of-range value one that names the field; nothing is computed.

mod common;

use common::{depthcal, scratch};
use std::path::Path;

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

fn register(config: &str) -> (i32, String) {
    let root = env!("CARGO_MANIFEST_DIR");
    let (code, _, err) = depthcal(&[
        "register",
        &format!("{root}/clouds/demo_source.ply"),
        &format!("{root}/clouds/demo_target.ply"),
        "--config",
        config,
    ]);
    (code, err)
}

fn calibrate(config: &str) -> (i32, String) {
    let root = env!("CARGO_MANIFEST_DIR");
    let (code, _, err) = depthcal(&[
        "calibrate",
        &format!("{root}/clouds/demo-cell"),
        "--config",
        config,
    ]);
    (code, err)
}

#[test]
fn unknown_keys_are_named() {
    let d = scratch("config-unknown");
    for (cfg, key) in [
        (r#"{"voxle": 0.03}"#, "voxle"),
        (r#"{"icp": {"kernal": "huber"}}"#, "kernal"),
    ] {
        let (code, err) = register(&write(&d, "register.json", cfg));
        assert!(code == 1 || code == 2, "register {cfg}: exit {code}: {err}");
        assert!(err.contains(key), "register {cfg}: {err}");
        assert!(err.contains("register.json"), "register {cfg}: {err}");
    }
    for (cfg, key) in [
        (r#"{"use_prior": false}"#, "use_prior"),
        (r#"{"register": {"voxel": 0.03, "sidded": true}}"#, "sidded"),
        (r#"{"fuse": {"voxel_size": 0.01}}"#, "voxel_size"),
    ] {
        let (code, err) = calibrate(&write(&d, "calibrate.json", cfg));
        assert!(
            code == 1 || code == 2,
            "calibrate {cfg}: exit {code}: {err}"
        );
        assert!(err.contains(key), "calibrate {cfg}: {err}");
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn out_of_range_values_name_the_field() {
    let d = scratch("config-range");
    let (code, err) = register(&write(
        &d,
        "register.json",
        r#"{"icp": {"max_iterations": 0}}"#,
    ));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("icp.max_iterations"), "{err}");
    let (code, err) = calibrate(&write(
        &d,
        "calibrate.json",
        r#"{"register": {"ransac": {"confidence": 2.0}}}"#,
    ));
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("register.ransac.confidence"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}
