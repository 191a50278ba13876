use super::*;
use crate::camera::write_depth_png;
use crate::fusion::tests::{ring_poses, test_camera, Scene};
use crate::io::poses::write_poses;
use nalgebra::{Translation3, UnitQuaternion};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("depthcal-cell-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn hand_eye() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.03, -0.02, 0.11),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 1.3),
    )
}

/// Writes a 2-robot synthetic cell (robot "b" uses matrix poses and a hand-eye JSON file).
pub(crate) fn write_cell(dir: &Path, n: usize) -> CellManifest {
    let scene = Scene::new();
    let intr = test_camera();
    let mut m = CellManifest::new("a");
    for (name, fmt) in [("a", PoseFormat::Kuka), ("b", PoseFormat::Matrix)] {
        std::fs::create_dir_all(dir.join(name).join("depth")).unwrap();
        let mut e = RobotEntry::standard(name, hand_eye());
        e.pose_format = fmt;
        if name == "b" {
            e.poses = "b/poses_matrix.csv".into();
            e.hand_eye = HandEyeSpec::File("b/hand_eye.json".into());
            let rows = crate::geometry::transform::isometry_to_nested(&hand_eye());
            std::fs::write(
                dir.join("b/hand_eye.json"),
                serde_json::json!({ "T_ee_cam": rows }).to_string(),
            )
            .unwrap();
        }
        let mut recs = Vec::new();
        for (i, t_base_cam) in ring_poses(n).iter().enumerate() {
            let id = format!("{i:03}");
            write_depth_png(
                dir.join(frame_path(Path::new(""), &e.depth, &id)),
                &scene.render(&intr, t_base_cam),
            )
            .unwrap();
            recs.push(PoseRecord {
                frame: id,
                pose: t_base_cam * hand_eye().inverse(),
                line: 0,
            });
        }
        write_poses(dir.join(&e.poses), &recs, fmt).unwrap();
        intr.write_json_file(dir.join(&e.intrinsics)).unwrap();
        m.robots.push(e);
    }
    m.write(dir).unwrap();
    m
}

#[test]
fn write_open_and_round_trip_with_unknown_tables() {
    let dir = tmpdir("ok");
    let mut m = write_cell(&dir, 3);
    let cell = Cell::open(&dir).unwrap();
    assert_eq!(cell.robots.len(), 2);
    assert_eq!(cell.reference().name, "a");
    for r in &cell.robots {
        assert_eq!(r.frames.len(), 3);
        let (rot, d) = crate::geometry::transform::pose_error(&r.t_ee_cam, &hand_eye());
        assert!(rot < 1e-6 && d < 1e-9, "{rot} {d}");
        for (i, t) in ring_poses(3).iter().enumerate() {
            let (rot, d) = crate::geometry::transform::pose_error(&r.t_base_cam(i), t);
            assert!(rot < 1e-5 && d < 1e-8, "{}: {rot} deg {d} m", r.name);
        }
        assert_eq!(r.load_depth(1).unwrap().width, 160);
    }
    // Unknown tables and keys survive a read-write cycle.
    let mut text = std::fs::read_to_string(dir.join(MANIFEST_FILE)).unwrap();
    text.push_str("\n[priors]\nmax_distance_m = 3.0\nnote = \"kept\"\n");
    std::fs::write(dir.join(MANIFEST_FILE), &text).unwrap();
    let back = CellManifest::read(&dir).unwrap();
    assert_eq!(back.extra["priors"]["note"].as_str(), Some("kept"));
    back.write(&dir).unwrap();
    let again = CellManifest::read(&dir).unwrap();
    assert_eq!(again, back);
    m.extra = back.extra.clone();
    let (HandEyeSpec::Inline(t0), HandEyeSpec::Inline(t1)) =
        (&m.robots[0].hand_eye, &again.robots[0].hand_eye)
    else {
        panic!("inline hand-eye expected");
    };
    assert!(crate::geometry::transform::pose_error(t0, t1).0 < 1e-9);
    m.robots[0].hand_eye = again.robots[0].hand_eye.clone();
    assert_eq!(again, m);
    // Ground truth round trip.
    assert!(cell.ground_truth().unwrap().is_none());
    let gt = GroundTruth {
        t_base1_base2: Some(hand_eye()),
        extra: Default::default(),
    };
    gt.write(&dir).unwrap();
    let g = GroundTruth::read(&dir).unwrap().unwrap();
    assert!(
        crate::geometry::transform::pose_error(&g.t_base1_base2.unwrap(), &hand_eye()).0 < 1e-9
    );
    let _ = std::fs::remove_dir_all(dir);
}

fn open_err(dir: &Path) -> String {
    Cell::open(dir).unwrap_err().to_string()
}

#[test]
fn problems_are_errors_naming_file_and_row() {
    let dir = tmpdir("bad");
    write_cell(&dir, 3);
    let manifest = std::fs::read_to_string(dir.join(MANIFEST_FILE)).unwrap();

    // A pose row without a depth image.
    std::fs::remove_file(dir.join("a/depth/001.png")).unwrap();
    let e = open_err(&dir);
    assert!(
        e.contains("a/poses.csv") && e.contains("line 3") && e.contains("001.png"),
        "{e}"
    );
    // A depth image of the wrong size.
    write_depth_png(dir.join("a/depth/001.png"), &DepthImage::zeros(80, 60)).unwrap();
    let e = open_err(&dir);
    assert!(
        e.contains("001.png") && e.contains("80x60") && e.contains("160x120"),
        "{e}"
    );
    // An 8-bit PNG.
    {
        let f = std::fs::File::create(dir.join("a/depth/001.png")).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(f), 160, 120);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&vec![1u8; 160 * 120])
            .unwrap();
    }
    let e = open_err(&dir);
    assert!(e.contains("001.png") && e.contains("8-bit"), "{e}");
    let scene = Scene::new();
    write_depth_png(
        dir.join("a/depth/001.png"),
        &scene.render(&test_camera(), &ring_poses(3)[1]),
    )
    .unwrap();
    assert!(Cell::open(&dir).is_ok());

    // A bad pose row.
    let poses = std::fs::read_to_string(dir.join("a/poses.csv")).unwrap();
    std::fs::write(
        dir.join("a/poses.csv"),
        poses.replacen("001,", "001,abc", 1),
    )
    .unwrap();
    let e = open_err(&dir);
    assert!(e.contains("a/poses.csv") && e.contains("line 3"), "{e}");
    std::fs::write(dir.join("a/poses.csv"), &poses).unwrap();

    // An intrinsics file with a missing field.
    let intr = std::fs::read_to_string(dir.join("a/intrinsics.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&intr).unwrap();
    let mut o = v.as_object().unwrap().clone();
    o.remove("ppy");
    std::fs::write(
        dir.join("a/intrinsics.json"),
        serde_json::Value::Object(o).to_string(),
    )
    .unwrap();
    let e = open_err(&dir);
    assert!(e.contains("a/intrinsics.json") && e.contains("ppy"), "{e}");
    std::fs::write(dir.join("a/intrinsics.json"), &intr).unwrap();

    // Manifest problems: missing field, wrong version, unknown reference, bad hand-eye, missing pattern.
    let cases = [
        (
            manifest.replacen("depth = \"a/depth/{frame}.png\"\n", "", 1),
            "depth",
        ),
        (
            manifest.replace("depthcal-cell/1", "depthcal-cell/9"),
            "depthcal-cell/9",
        ),
        (
            manifest.replace("reference = \"a\"", "reference = \"c\""),
            "reference",
        ),
        (
            manifest.replace("a/depth/{frame}.png", "a/depth/x.png"),
            "{frame}",
        ),
        (
            manifest.replacen("hand_eye = [", "hand_eye = [2.0, ", 1),
            "hand_eye",
        ),
        (
            manifest.replace("pose_format = \"kuka\"", "pose_format = \"euler\""),
            "euler",
        ),
    ];
    for (text, want) in cases {
        assert_ne!(text, manifest, "case {want} did not change the manifest");
        std::fs::write(dir.join(MANIFEST_FILE), &text).unwrap();
        let e = open_err(&dir);
        assert!(e.contains("cell.toml") && e.contains(want), "{want}: {e}");
    }
    std::fs::remove_file(dir.join(MANIFEST_FILE)).unwrap();
    let e = open_err(&dir);
    assert!(e.contains("cell.toml"), "{e}");
    let e = open_err(&dir.join("nope"));
    assert!(e.contains("nope"), "{e}");
    let _ = std::fs::remove_dir_all(dir);
}

/// A hand-eye JSON file's `hand_eye_sigma_deg` / `hand_eye_sigma_mm` (as `depthcal handeye --json`
/// writes them) enter the robot's uncertainty unless the robot entry states its own; a bad value is an
/// error naming the file and the key.
#[test]
fn hand_eye_file_sigma_is_taken_unless_the_entry_states_one() {
    let dir = tmpdir("he-sigma");
    let mut m = write_cell(&dir, 3);
    let rows = crate::geometry::transform::isometry_to_nested(&hand_eye());
    let write_he = |extra: serde_json::Value| {
        let mut v = serde_json::json!({ "T_ee_cam": rows });
        v.as_object_mut()
            .unwrap()
            .extend(extra.as_object().unwrap().clone());
        std::fs::write(dir.join("b/hand_eye.json"), v.to_string()).unwrap();
    };
    let b = |cell: &Cell| cell.robots[1].uncertainty.clone();
    // No sigma in the file: the defaults.
    let plain = b(&Cell::open(&dir).unwrap());
    assert_eq!(plain, RobotUncertainty::default());
    // The file's sigma.
    write_he(serde_json::json!({"hand_eye_sigma_deg": 0.02, "hand_eye_sigma_mm": 0.3}));
    let u = b(&Cell::open(&dir).unwrap());
    assert!((u.hand_eye_rotation_rad - 0.02f64.to_radians()).abs() < 1e-15);
    assert!((u.hand_eye_translation_m - 0.3e-3).abs() < 1e-15);
    assert!(u.stated.contains(&"hand_eye_sigma_mm".to_string()));
    // The entry's own key wins over the file's.
    m.robots[1].hand_eye_sigma_mm = Some(1.5);
    m.write(&dir).unwrap();
    let u = b(&Cell::open(&dir).unwrap());
    assert!((u.hand_eye_translation_m - 1.5e-3).abs() < 1e-15);
    assert!((u.hand_eye_rotation_rad - 0.02f64.to_radians()).abs() < 1e-15);
    // A negative sigma in the file is an error naming it and the key.
    write_he(serde_json::json!({"hand_eye_sigma_deg": -1.0}));
    let e = open_err(&dir);
    assert!(
        e.contains("hand_eye.json") && e.contains("hand_eye_sigma_deg"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
