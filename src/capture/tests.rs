use super::*;
use crate::geometry::pose::KukaPose;

fn stamps(name: &str, ts: &[f64]) -> StreamFrames {
    StreamFrames {
        name: name.into(),
        frames: ts
            .iter()
            .enumerate()
            .map(|(i, &t)| FrameStamp {
                t_s: t,
                key: i as u64,
            })
            .collect(),
    }
}

fn rows(text: &str) -> PoseRows {
    PoseRows::parse(text, None, Path::new("p.csv")).unwrap()
}

#[test]
fn pose_rows_with_and_without_time() {
    let r = rows("frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n# c\na,1.5,1,2,3,0,0,0\n\nb,2.25,4,5,6,90,0,0\n");
    assert_eq!(r.format, PoseFormat::Kuka);
    assert_eq!(r.times_s, Some(vec![1.5, 2.25]));
    assert_eq!(r.records[1].line, 5);
    assert!((r.records[1].pose.translation.vector.x - 0.004).abs() < 1e-15);
    let r = rows("frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1,2,3,0,0,0\n");
    assert!(r.times_s.is_none());
    let e = PoseRows::parse(
        "frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1,1,2,3,0,0,0\nb,x,1,2,3,0,0,0\n",
        None,
        Path::new("q.csv"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("q.csv") && e.contains("line 3") && e.contains("t_s"),
        "{e}"
    );
}

#[test]
fn order_matching_needs_equal_counts() {
    let r = rows("frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1,2,3,0,0,0\nb,1,2,3,0,0,0\n");
    let cfg = MatchConfig::default();
    let m = match_frames(
        &r,
        &stamps("d", &[0.1, 0.2]),
        None,
        &cfg,
        Path::new("r.bag"),
    )
    .unwrap();
    assert_eq!(
        m.iter().map(|m| (m.row, m.depth)).collect::<Vec<_>>(),
        vec![(0, 0), (1, 1)]
    );
    let e = match_frames(&r, &stamps("d", &[0.1]), None, &cfg, Path::new("r.bag"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("p.csv") && e.contains("line 3") && e.contains("frame b"),
        "{e}"
    );
    let e = match_frames(
        &r,
        &stamps("d", &[0.1, 0.2, 0.3]),
        None,
        &cfg,
        Path::new("r.bag"),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("p.csv") && e.contains("3 depth frames") && e.contains("--match time"),
        "{e}"
    );
}

#[test]
fn time_matching_picks_nearest_within_tolerance() {
    let r = rows(
        "frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,0.21,1,2,3,0,0,0\nb,0.099,1,2,3,0,0,0\n",
    );
    let cfg = MatchConfig {
        mode: MatchMode::Time { tolerance_s: 0.015 },
        ..Default::default()
    };
    let d = stamps("d", &[0.0, 0.1, 0.2, 0.3]);
    let c = stamps("c", &[0.005, 0.104, 0.19, 0.31]);
    let m = match_frames(&r, &d, Some(&c), &cfg, Path::new("r.bag")).unwrap();
    assert_eq!(
        m.iter()
            .map(|m| (m.row, m.depth, m.color))
            .collect::<Vec<_>>(),
        vec![(0, 2, Some(2)), (1, 1, Some(1))]
    );
    // Too far.
    let far = rows("frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,0.05,1,2,3,0,0,0\n");
    let e = match_frames(&far, &d, None, &cfg, Path::new("r.bag"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("p.csv") && e.contains("line 2") && e.contains("50.0 ms away"),
        "{e}"
    );
    // Two rows on one frame.
    let two = rows(
        "frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,0.1,1,2,3,0,0,0\nb,0.101,1,2,3,0,0,0\n",
    );
    let e = match_frames(&two, &d, None, &cfg, Path::new("r.bag"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 3") && e.contains("line 2"), "{e}");
    // No time column.
    let nt = rows("frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1,2,3,0,0,0\n");
    let e = match_frames(&nt, &d, None, &cfg, Path::new("r.bag"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("t_s"), "{e}");
    // Colour too far from its depth frame.
    let c_far = stamps("c", &[0.05, 0.15, 0.25]);
    let cfg2 = MatchConfig {
        color_tolerance_s: 0.01,
        ..cfg
    };
    let e = match_frames(&r, &d, Some(&c_far), &cfg2, Path::new("r.bag"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("r.bag") && e.contains("colour"), "{e}");
}

#[test]
fn next_ids_continue_the_numbering() {
    let ids: Vec<String> = ["000", "001", "0007", "x"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    assert_eq!(next_frame_ids(&ids, 2), vec!["0008", "0009"]);
    assert_eq!(next_frame_ids(&[], 2), vec!["000", "001"]);
}

fn frame(id: &str, w: u32, h: u32, v: u16, color: bool) -> NewFrame {
    NewFrame {
        id: id.into(),
        t_base_ee: KukaPose {
            x_mm: 100.0 + v as f64,
            y_mm: -20.0,
            z_mm: 300.0,
            a_deg: 10.0,
            b_deg: 20.0,
            c_deg: 30.0,
        }
        .to_isometry(),
        depth: DepthImage {
            width: w,
            height: h,
            data: (0..w * h).map(|i| v + i as u16).collect(),
        },
        color: color.then(|| RgbImage {
            width: w,
            height: h,
            data: vec![v as u8; (w * h * 3) as usize],
        }),
        source: format!("test frame {id}"),
        pose_origin: format!("test pose {id}"),
    }
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("depthcal-capture-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn listing(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn append_creates_then_extends_and_never_overwrites() {
    let dir = scratch("append");
    let intr = Intrinsics::pinhole(8, 6, 7.0, 7.0, 3.5, 2.5);
    let setup = RobotSetup::new("left", Some(Isometry3::identity()));
    let rep = append_frames(&dir, &setup, &intr, &[frame("000", 8, 6, 500, true)]).unwrap();
    assert!(rep.created_cell && rep.created_robot && rep.color);
    assert_eq!(rep.frames_total, 1);
    // Second call appends; the first pose row stays byte for byte.
    let poses = dir.join("left/poses.csv");
    let before = std::fs::read_to_string(&poses).unwrap();
    let rep = append_frames(
        &dir,
        &RobotSetup::new("left", None),
        &intr,
        &[frame("001", 8, 6, 600, true), frame("002", 8, 6, 700, true)],
    )
    .unwrap();
    assert!(!rep.created_cell && !rep.created_robot);
    assert_eq!(rep.frames_total, 3);
    let after = std::fs::read_to_string(&poses).unwrap();
    assert!(after.starts_with(&before));
    let cell = Cell::open(&dir).unwrap();
    let r = cell.robot("left").unwrap();
    assert_eq!(r.load_depth(2).unwrap().data[5], 705);
    let x = r.frames[1].t_base_ee.translation.vector.x;
    assert!((x - 0.7).abs() < 1e-9, "{x}");

    let snapshot = listing(&dir);
    let fail = |frames: &[NewFrame], setup: &RobotSetup, intr: &Intrinsics, want: &str| {
        let e = append_frames(&dir, setup, intr, frames)
            .unwrap_err()
            .to_string();
        assert!(e.contains(want), "{e}");
        assert_eq!(listing(&dir), snapshot, "nothing written after: {e}");
    };
    let left = RobotSetup::new("left", None);
    // An id the robot has.
    fail(
        &[frame("003", 8, 6, 1, true), frame("001", 8, 6, 1, true)],
        &left,
        &intr,
        "already in",
    );
    // An id twice.
    fail(
        &[frame("005", 8, 6, 1, true), frame("005", 8, 6, 1, true)],
        &left,
        &intr,
        "repeats",
    );
    // Wrong size.
    fail(&[frame("006", 8, 5, 1, true)], &left, &intr, "8x5");
    // Missing colour where the robot stores colour.
    fail(&[frame("007", 8, 6, 1, false)], &left, &intr, "no colour");
    // Other intrinsics.
    let other = Intrinsics {
        fx: 7.5,
        ..intr.clone()
    };
    fail(&[frame("008", 8, 6, 1, true)], &left, &other, "fx");
    // Other hand-eye.
    let moved = RobotSetup::new("left", Some(Isometry3::translation(0.0, 0.0, 0.1)));
    fail(&[frame("009", 8, 6, 1, true)], &moved, &intr, "hand_eye");
    // A new robot without hand-eye.
    fail(
        &[frame("000", 8, 6, 1, true)],
        &RobotSetup::new("right", None),
        &intr,
        "hand-eye",
    );
    // A stray image file where a new frame would go.
    std::fs::write(dir.join("left/depth/010.png"), b"stray").unwrap();
    let snapshot = listing(&dir);
    let e = append_frames(&dir, &left, &intr, &[frame("010", 8, 6, 1, true)])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("010.png") && e.contains("never overwritten"),
        "{e}"
    );
    assert_eq!(listing(&dir), snapshot);
    // A second robot joins the cell; the reference stays.
    let rep = append_frames(
        &dir,
        &RobotSetup::new("right", Some(Isometry3::translation(0.0, 0.0, 0.05))),
        &intr,
        &[frame("000", 8, 6, 9, false)],
    )
    .unwrap();
    assert!(rep.created_robot && !rep.color);
    let cell = Cell::open(&dir).unwrap();
    assert_eq!(cell.manifest.reference, "left");
    assert_eq!(cell.robots.len(), 2);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn import_settings_are_checked_and_name_the_field() {
    let field = |r: Result<()>| match r {
        Err(Error::Config { field, .. }) => field,
        other => panic!("expected a configuration error, got {other:?}"),
    };
    MatchConfig::default().validate().unwrap();
    let bad_time = MatchConfig {
        mode: MatchMode::Time { tolerance_s: -0.1 },
        ..Default::default()
    };
    assert_eq!(field(bad_time.validate()), "mode.tolerance_s");
    let bad_color = MatchConfig {
        color_tolerance_s: f64::NAN,
        ..Default::default()
    };
    assert_eq!(field(bad_color.validate()), "color_tolerance_s");
    // match_frames refuses the bad settings before it looks at the frames.
    let r = rows("frame,t_s,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1.5,1,2,3,0,0,0\n");
    let e = match_frames(
        &r,
        &stamps("depth", &[1.5]),
        None,
        &bad_time,
        Path::new("r.bag"),
    )
    .unwrap_err();
    assert!(e.to_string().contains("tolerance_s"), "{e}");

    #[cfg(feature = "rosbag")]
    {
        use crate::capture::rosbag::BagImportConfig;
        BagImportConfig::default().validate().unwrap();
        let c = BagImportConfig {
            depth_scale: Some(0.0),
            ..Default::default()
        };
        assert_eq!(field(c.validate()), "depth_scale");
        let c = BagImportConfig {
            color_topic: Some(" ".into()),
            ..Default::default()
        };
        assert_eq!(field(c.validate()), "color_topic");
    }
}
