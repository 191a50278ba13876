//! `depthcal import` of ROS1 `.bag` recordings with the built-in reader: bags written here in the ROS1 bag
//! format 2.0 (uncompressed, LZ4 and BZ2 chunks; the ROS driver's and librealsense's topic layouts) are
//! imported into cells, and the cells must hold exactly the recorded depth values, intrinsics, colour, poses and
//! frame count. Bad input gives an error naming the file and row, exit code 1, and nothing written.

mod common;

use common::bag::*;
use common::{depthcal, listing};

use depthcal::cell::Cell;
use depthcal::geometry::pose::KukaPose;
use depthcal::geometry::transform::pose_error;
use depthcal::io::poses::PoseFormat;
use std::path::Path;

/// The depth of pixel (u, v) in frame k (raw units; 0 = no data).
fn depth_value(u: u32, v: u32, k: u32) -> u16 {
    if (u * 3 + v + k).is_multiple_of(13) {
        0
    } else {
        (300 + 11 * u + 17 * v + 1000 * k) as u16
    }
}

fn color_value(u: u32, v: u32, k: u32) -> [u8; 3] {
    [
        (u * 5 + k) as u8,
        (v * 7 + 2 * k) as u8,
        (u + v + 100) as u8,
    ]
}

const T0_NS: u64 = 1_700_000_000_123_000_000;
const PERIOD_NS: u64 = 33_333_333;

fn frame_time(k: u32) -> u64 {
    T0_NS + k as u64 * PERIOD_NS
}

fn depth_msg(k: u32, w: u32, h: u32, big_endian: bool) -> Vec<u8> {
    let mut px = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let d = depth_value(u, v, k);
            px.extend(if big_endian {
                d.to_be_bytes()
            } else {
                d.to_le_bytes()
            });
        }
    }
    image_msg(frame_time(k), (w, h), "16UC1", big_endian, 2, &px, 6)
}

fn color_msg(k: u32, w: u32, h: u32) -> Vec<u8> {
    let mut px = Vec::new();
    for v in 0..h {
        for u in 0..w {
            let [r, g, b] = color_value(u, v, k);
            px.extend([b, g, r]);
        }
    }
    image_msg(frame_time(k) + 2_000_000, (w, h), "bgr8", false, 3, &px, 0)
}

fn ros_driver_cam() -> Cam {
    Cam {
        w: 20,
        h: 15,
        fx: 17.125,
        fy: 16.875,
        ppx: 9.75,
        ppy: 7.25,
        model: "plumb_bob",
        d: vec![0.0625, -0.125, 0.001953125, -0.0009765625, 0.03125],
    }
}

/// A bag in the ROS realsense2_camera layout: depth, camera info, colour, and distractors.
fn ros_driver_bag(path: &Path, frames: u32, compression: &[Compression]) -> Cam {
    let cam = ros_driver_cam();
    let mut msgs = Vec::new();
    for k in 0..frames {
        let t = frame_time(k);
        msgs.push(msg(
            "/camera/depth/camera_info",
            "sensor_msgs/CameraInfo",
            t,
            camera_info_msg(t, &cam),
        ));
        msgs.push(msg(
            "/camera/color/image_raw",
            "sensor_msgs/Image",
            t + 1000,
            color_msg(k, cam.w, cam.h),
        ));
        // Frame 2 is stored big-endian.
        msgs.push(msg(
            "/camera/depth/image_rect_raw",
            "sensor_msgs/Image",
            t + 2000,
            depth_msg(k, cam.w, cam.h, k == 2),
        ));
        msgs.push(msg(
            "/camera/infra1/image_rect_raw",
            "sensor_msgs/Image",
            t + 3000,
            image_msg(
                t,
                (cam.w, cam.h),
                "mono8",
                false,
                1,
                &vec![9u8; (cam.w * cam.h) as usize],
                0,
            ),
        ));
        msgs.push(msg("/rosout", "rosgraph_msgs/Log", t + 4000, vec![1, 2, 3]));
    }
    write_bag(path, &msgs, 7, compression);
    cam
}

fn kuka(k: usize) -> KukaPose {
    KukaPose {
        x_mm: 400.0 + 10.5 * k as f64,
        y_mm: -120.25 + 3.0 * k as f64,
        z_mm: 610.0,
        a_deg: 12.0 * k as f64 - 30.0,
        b_deg: 45.5,
        c_deg: -170.0 + k as f64,
    }
}

fn write_pose_file(path: &Path, ids: &[String], times: Option<&[f64]>, first_k: usize) {
    common::write_kuka_pose_file(path, ids, times, |i| kuka(first_k + i));
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn ids(range: std::ops::Range<usize>) -> Vec<String> {
    range.map(|i| format!("p{i:02}")).collect()
}

/// Checks that robot `robot` of `cell` holds recorded frames `ks` under `ids` with poses `kuka(first_k + i)`.
fn check_frames(cell: &Path, robot: &str, ids: &[String], ks: &[u32], first_k: usize, color: bool) {
    let cell = Cell::open(cell).unwrap();
    let r = cell.robot(robot).unwrap();
    for (i, (id, &k)) in ids.iter().zip(ks).enumerate() {
        let idx = r
            .frames
            .iter()
            .position(|f| &f.id == id)
            .expect("frame id in the cell");
        let img = r.load_depth(idx).unwrap();
        let (w, h) = (img.width, img.height);
        for v in 0..h {
            for u in 0..w {
                assert_eq!(
                    img.get(u, v),
                    depth_value(u, v, k),
                    "frame {id} (recorded {k}) pixel ({u},{v})"
                );
            }
        }
        let (rot, t) = pose_error(&r.frames[idx].t_base_ee, &kuka(first_k + i).to_isometry());
        assert!(
            rot < 1e-6 && t < 1e-9,
            "frame {id}: pose off by {rot} deg {t} m"
        );
        if color {
            let p = r.frames[idx].color_path.as_ref().expect("colour path");
            let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(p).unwrap()));
            let mut reader = dec.read_info().unwrap();
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            let info = reader.next_frame(&mut buf).unwrap();
            assert_eq!(info.color_type, png::ColorType::Rgb);
            for v in 0..h {
                for u in 0..w {
                    let o = ((v * w + u) * 3) as usize;
                    assert_eq!(
                        &buf[o..o + 3],
                        &color_value(u, v, k),
                        "colour of {id} at ({u},{v})"
                    );
                }
            }
        }
    }
}

#[test]
fn ros_driver_bag_imports_exact_depth_intrinsics_colour_and_poses() {
    let dir = common::scratch("bag-driver");
    let bag = dir.join("rec.bag");
    let cam = ros_driver_bag(
        &bag,
        6,
        &[Compression::None, Compression::Lz4, Compression::Bz2],
    );
    let poses = dir.join("poses.csv");
    let frame_ids = ids(0..6);
    write_pose_file(&poses, &frame_ids, None, 0);
    let cell = dir.join("cell");
    let (code, out, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "left",
        "--poses",
        s(&poses),
        "--hand-eye",
        "identity",
        "--color",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let report: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(report["schema"], "depthcal.import/1");
    common::assert_documented(&report);
    assert!(report["seconds"].as_f64().unwrap() >= 0.0);
    assert_eq!(report["intrinsics"]["fx"], cam.fx);
    assert_eq!(report["depth_stream"], "/camera/depth/image_rect_raw");
    assert_eq!(report["color_stream"], "/camera/color/image_raw");
    assert_eq!(report["depth_frames_in_recording"], 6);
    assert_eq!(report["append"]["frames_total"], 6);

    let opened = Cell::open(&cell).unwrap();
    assert_eq!(opened.manifest.reference, "left");
    let r = opened.robot("left").unwrap();
    assert_eq!(r.frames.len(), 6);
    let i = &r.intrinsics;
    assert_eq!((i.width, i.height), (cam.w, cam.h));
    assert_eq!(
        (i.fx, i.fy, i.ppx, i.ppy),
        (cam.fx, cam.fy, cam.ppx, cam.ppy)
    );
    assert_eq!(i.model, depthcal::camera::DistortionModel::BrownConrady);
    assert_eq!(i.coeffs.to_vec(), cam.d);
    assert_eq!(i.depth_scale, 0.001, "REP 118: 16UC1 depth is millimetres");
    check_frames(&cell, "left", &frame_ids, &[0, 1, 2, 3, 4, 5], 0, true);
    // Frames are recorded under the pose file's ids, and the stamps are the images' header stamps.
    let stamps: Vec<f64> = report["stamps_s"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for (k, t) in stamps.iter().enumerate() {
        assert!((t - frame_time(k as u32) as f64 * 1e-9).abs() < 1e-6, "{t}");
    }
    // The cell's pose file is KUKA, the input's format.
    let text = std::fs::read_to_string(cell.join("left/poses.csv")).unwrap();
    assert!(text.starts_with(&PoseFormat::Kuka.header()));

    // --list shows the streams without writing anything.
    let (code, out, err) = depthcal(&["import", s(&bag), "--list", "--color"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("/camera/depth/image_rect_raw: 6 frames"),
        "{out}"
    );
    let (code, out, err) = depthcal(&["import", s(&bag), "--list", "--color", "--json"]);
    assert_eq!(code, 0, "{err}");
    let list: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(list["schema"], "depthcal.recording/1");
    common::assert_documented(&list);
    assert_eq!(list["depth_frames"], 6);
    assert_eq!(list["color_stream"], "/camera/color/image_raw");
    assert_eq!(list["depth_stamps_s"], report["stamps_s"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn time_matching_picks_frames_and_appends_without_overwriting() {
    let dir = common::scratch("bag-time");
    let bag = dir.join("rec.bag");
    ros_driver_bag(&bag, 8, &[Compression::Lz4]);
    let cell = dir.join("cell");
    // Rows at frames 1, 4 and 6 (a few ms off), then an append at frames 2 and 7.
    let t = |k: u32, off_ms: f64| frame_time(k) as f64 * 1e-9 + off_ms * 1e-3;
    let poses = dir.join("poses-a.csv");
    let first = ids(0..3);
    write_pose_file(&poses, &first, Some(&[t(1, 3.0), t(4, -5.0), t(6, 0.0)]), 0);
    let args = |p: &Path| {
        vec![
            "import".to_string(),
            s(&bag).into(),
            s(&cell).into(),
            "--robot".into(),
            "right".into(),
            "--poses".into(),
            s(p).into(),
            "--match".into(),
            "time".into(),
            "--tolerance-ms".into(),
            "8".into(),
            "--hand-eye".into(),
            "1,0,0,0, 0,1,0,0, 0,0,1,0.05, 0,0,0,1".into(),
        ]
    };
    let run = |p: &Path| {
        let a = args(p);
        depthcal(&a.iter().map(|s| s.as_str()).collect::<Vec<_>>())
    };
    let (code, _, err) = run(&poses);
    assert_eq!(code, 0, "{err}");
    check_frames(&cell, "right", &first, &[1, 4, 6], 0, false);
    let cell_opened = Cell::open(&cell).unwrap();
    let he = cell_opened.robot("right").unwrap().t_ee_cam;
    assert!((he.translation.vector.z - 0.05).abs() < 1e-12);

    let poses_b = dir.join("poses-b.csv");
    let second = ids(3..5);
    write_pose_file(&poses_b, &second, Some(&[t(2, 1.0), t(7, -1.0)]), 3);
    let (code, _, err) = run(&poses_b);
    assert_eq!(code, 0, "{err}");
    check_frames(&cell, "right", &second, &[2, 7], 3, false);
    assert_eq!(
        Cell::open(&cell)
            .unwrap()
            .robot("right")
            .unwrap()
            .frames
            .len(),
        5
    );

    // The same rows again: the ids exist, nothing changes.
    let before = listing(&cell);
    let (code, _, err) = run(&poses_b);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("poses-b.csv line 2") && err.contains("already in"),
        "{err}"
    );
    assert_eq!(listing(&cell), before);

    // A row with no frame within the tolerance names the file and line.
    let poses_c = dir.join("poses-c.csv");
    write_pose_file(&poses_c, &ids(10..12), Some(&[t(3, 0.0), t(5, 15.0)]), 10);
    let (code, _, err) = run(&poses_c);
    assert_eq!(code, 1);
    assert!(
        err.contains("poses-c.csv") && err.contains("line 3") && err.contains("8.0 ms"),
        "{err}"
    );
    assert_eq!(listing(&cell), before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn librealsense_layout_with_depth_units_and_32fc1_metres() {
    let dir = common::scratch("bag-rs-layout");
    // librealsense's ROS1 layout: mono16 depth, camera info under info/, the Depth Units option.
    let cam = Cam {
        w: 12,
        h: 9,
        fx: 10.5,
        fy: 10.25,
        ppx: 5.5,
        ppy: 4.0,
        model: "Inverse Brown Conrady",
        d: vec![-0.05, 0.0625, -0.0005, 0.0007, -0.02],
    };
    let depth_topic = "/device_0/sensor_0/Depth_0/image/data";
    let mut msgs = vec![msg(
        "/device_0/sensor_0/option/Depth_Units/value",
        "std_msgs/Float32",
        T0_NS,
        0.0001f32.to_le_bytes().to_vec(),
    )];
    msgs.push(msg(
        "/device_0/sensor_0/Depth_0/info/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(T0_NS, &cam),
    ));
    // An infrared stream in mono16 too: the depth topic is told apart by its name.
    msgs.push(msg(
        "/device_0/sensor_1/Infrared_1/info/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(
            T0_NS,
            &Cam {
                fx: 99.0,
                ..ros_driver_cam()
            },
        ),
    ));
    for k in 0..3 {
        let mut px = Vec::new();
        for v in 0..cam.h {
            for u in 0..cam.w {
                px.extend(depth_value(u, v, k).to_le_bytes());
            }
        }
        msgs.push(msg(
            depth_topic,
            "sensor_msgs/Image",
            frame_time(k),
            image_msg(frame_time(k), (cam.w, cam.h), "mono16", false, 2, &px, 0),
        ));
        msgs.push(msg(
            "/device_0/sensor_1/Infrared_1/image/data",
            "sensor_msgs/Image",
            frame_time(k),
            image_msg(frame_time(k), (cam.w, cam.h), "mono16", false, 2, &px, 0),
        ));
    }
    let bag = dir.join("rs.bag");
    write_bag(&bag, &msgs, 4, &[Compression::None]);
    let poses = dir.join("poses.csv");
    let frame_ids = ids(0..3);
    write_pose_file(&poses, &frame_ids, None, 0);
    let cell = dir.join("cell");
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "cam",
        "--poses",
        s(&poses),
        "--hand-eye",
        "identity",
    ]);
    assert_eq!(code, 0, "{err}");
    let opened = Cell::open(&cell).unwrap();
    let i = &opened.robot("cam").unwrap().intrinsics;
    assert_eq!(
        i.depth_scale, 0.0001f32 as f64,
        "the recording's Depth Units"
    );
    assert_eq!(
        i.model,
        depthcal::camera::DistortionModel::InverseBrownConrady
    );
    assert_eq!((i.fx, i.ppy), (10.5, 4.0));
    assert_eq!(i.coeffs.to_vec(), cam.d);
    check_frames(&cell, "cam", &frame_ids, &[0, 1, 2], 0, false);

    // 32FC1 metres: stored as units of the depth scale (default 1 mm), NaN / negative / too far as 0.
    let mut msgs = vec![msg(
        "/cam/depth/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(
            T0_NS,
            &Cam {
                model: "plumb_bob",
                d: vec![0.0; 5],
                ..cam
            },
        ),
    )];
    let metres = [0.4004f32, 1.2345, f32::NAN, -1.0, 70.0, 0.0];
    let mut px = Vec::new();
    for i in 0..(12 * 9) {
        px.extend(metres[i % metres.len()].to_le_bytes());
    }
    msgs.push(msg(
        "/cam/depth/image",
        "sensor_msgs/Image",
        T0_NS,
        image_msg(T0_NS, (12, 9), "32FC1", false, 4, &px, 0),
    ));
    let bag32 = dir.join("f32.bag");
    write_bag(&bag32, &msgs, 10, &[Compression::None]);
    write_pose_file(&poses, &ids(0..1), None, 0);
    let cell32 = dir.join("cell32");
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag32),
        s(&cell32),
        "--robot",
        "cam",
        "--poses",
        s(&poses),
        "--hand-eye",
        "identity",
    ]);
    assert_eq!(code, 0, "{err}");
    let opened = Cell::open(&cell32).unwrap();
    let r = opened.robot("cam").unwrap();
    assert_eq!(r.intrinsics.model, depthcal::camera::DistortionModel::None);
    let img = r.load_depth(0).unwrap();
    let want = [400u16, 1235, 0, 0, 0, 0];
    for (i, d) in img.data.iter().enumerate() {
        assert_eq!(*d, want[i % want.len()], "pixel {i}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_recordings_and_pose_files_are_clear_errors_and_write_nothing() {
    let dir = common::scratch("bag-bad");
    let bag = dir.join("rec.bag");
    ros_driver_bag(&bag, 4, &[Compression::None]);
    let poses = dir.join("poses.csv");
    write_pose_file(&poses, &ids(0..4), None, 0);
    let cell = dir.join("cell");
    let import = |bag: &Path, poses: &Path, extra: &[&str]| {
        let mut a = vec![
            "import",
            s(bag),
            s(&cell),
            "--robot",
            "left",
            "--poses",
            s(poses),
            "--hand-eye",
            "identity",
        ];
        a.extend_from_slice(extra);
        depthcal(&a)
    };
    let expect_error = |(code, _, err): (i32, String, String), want: &[&str]| {
        assert_eq!(code, 1, "{err}");
        for w in want {
            assert!(err.contains(w), "expected {w:?} in: {err}");
        }
        assert!(!err.contains("panicked"), "{err}");
        assert!(listing(&cell).is_empty(), "nothing may be written: {err}");
    };

    // More pose rows than frames, and fewer.
    let five = dir.join("five.csv");
    write_pose_file(&five, &ids(0..5), None, 0);
    expect_error(
        import(&bag, &five, &[]),
        &["five.csv", "line 6", "frame p04", "4 depth frames"],
    );
    let three = dir.join("three.csv");
    write_pose_file(&three, &ids(0..3), None, 0);
    expect_error(
        import(&bag, &three, &[]),
        &["three.csv", "3 pose rows", "4 depth frames"],
    );
    // A bad pose row.
    let bad = dir.join("bad.csv");
    std::fs::write(
        &bad,
        "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\na,1,2,3,4,5,6\nb,1,2,x,4,5,6\n",
    )
    .unwrap();
    expect_error(import(&bag, &bad, &[]), &["bad.csv", "line 3", "z_mm"]);
    // --match time without a t_s column.
    expect_error(
        import(&bag, &poses, &["--match", "time"]),
        &["poses.csv", "t_s"],
    );
    // A truncated bag (the index is cut off).
    let bytes = std::fs::read(&bag).unwrap();
    let cut = dir.join("cut.bag");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    expect_error(import(&cut, &poses, &[]), &["cut.bag", "index"]);
    // Not a bag at all, and a ROS2 file.
    let txt = dir.join("notes.bag");
    std::fs::write(&txt, "hello\n").unwrap();
    expect_error(import(&txt, &poses, &[]), &["notes.bag", "ROSBAG V2.0"]);
    let db = dir.join("fake.bag");
    std::fs::write(&db, b"SQLite format 3\0rest").unwrap();
    expect_error(
        import(&db, &poses, &["--reader", "rosbag"]),
        &["fake.bag", "ROS2"],
    );
    // A missing recording.
    expect_error(import(&dir.join("nope.bag"), &poses, &[]), &["nope.bag"]);
    // A topic that is not there / not depth.
    expect_error(
        import(&bag, &poses, &["--topic", "/nope"]),
        &["rec.bag", "/nope", "/camera/depth/image_rect_raw"],
    );
    expect_error(
        import(&bag, &poses, &["--topic", "/camera/infra1/image_rect_raw"]),
        &["rec.bag", "mono8", "not a depth image topic"],
    );
    // A depth image shorter than its header says.
    let cam = ros_driver_cam();
    let mut short = depth_msg(0, cam.w, cam.h, false);
    short.truncate(short.len() - 10);
    let mut msgs = vec![msg(
        "/c/depth/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(T0_NS, &cam),
    )];
    msgs.push(msg("/c/depth/image", "sensor_msgs/Image", T0_NS, short));
    let short_bag = dir.join("short.bag");
    write_bag(&short_bag, &msgs, 10, &[Compression::None]);
    write_pose_file(&poses, &ids(0..1), None, 0);
    expect_error(
        import(&short_bag, &poses, &[]),
        &["short.bag", "/c/depth/image", "message 1", "truncated"],
    );
    // No camera info at all.
    let no_info = dir.join("noinfo.bag");
    write_bag(
        &no_info,
        &[msg(
            "/c/depth/image",
            "sensor_msgs/Image",
            T0_NS,
            depth_msg(0, cam.w, cam.h, false),
        )],
        10,
        &[Compression::None],
    );
    expect_error(import(&no_info, &poses, &[]), &["noinfo.bag", "CameraInfo"]);
    // Camera info of another size than the images.
    let mut msgs = vec![msg(
        "/c/depth/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(
            T0_NS,
            &Cam {
                w: 21,
                ..ros_driver_cam()
            },
        ),
    )];
    msgs.push(msg(
        "/c/depth/image",
        "sensor_msgs/Image",
        T0_NS,
        depth_msg(0, cam.w, cam.h, false),
    ));
    let size_bag = dir.join("size.bag");
    write_bag(&size_bag, &msgs, 10, &[Compression::None]);
    expect_error(
        import(&size_bag, &poses, &[]),
        &["size.bag", "20x15", "21x15"],
    );
    // A new robot without a hand-eye.
    write_pose_file(&poses, &ids(0..4), None, 0);
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "left",
        "--poses",
        s(&poses),
    ]);
    assert_eq!(code, 1);
    assert!(
        err.contains("hand-eye") && err.contains("new to the cell"),
        "{err}"
    );
    assert!(listing(&cell).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[cfg(not(feature = "realsense"))]
#[test]
fn without_the_feature_db3_and_capture_say_what_to_do() {
    let dir = common::scratch("bag-nofeature");
    let db3 = dir.join("rec.db3");
    std::fs::write(&db3, b"SQLite format 3\0").unwrap();
    let (code, _, err) = depthcal(&["import", s(&db3), "--list"]);
    assert_eq!(code, 1);
    assert!(
        err.contains("rec.db3") && err.contains("--features realsense"),
        "{err}"
    );
    let (code, _, err) = depthcal(&[
        "capture",
        s(&dir.join("cell")),
        "--robot",
        "a",
        "--pose",
        "0,0,0,0,0,0",
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("`realsense` feature"), "{err}");
    assert!(!dir.join("cell").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn import_speed_vga() {
    // Measured, not asserted: 30 frames of 640x480 depth + colour through the CLI.
    let dir = common::scratch("bag-speed");
    let cam = Cam {
        w: 640,
        h: 480,
        fx: 615.0,
        fy: 615.5,
        ppx: 319.5,
        ppy: 239.5,
        model: "plumb_bob",
        d: vec![0.0; 5],
    };
    let n = 30u32;
    let mut msgs = vec![msg(
        "/camera/depth/camera_info",
        "sensor_msgs/CameraInfo",
        T0_NS,
        camera_info_msg(T0_NS, &cam),
    )];
    for k in 0..n {
        msgs.push(msg(
            "/camera/depth/image_rect_raw",
            "sensor_msgs/Image",
            frame_time(k),
            depth_msg(k, cam.w, cam.h, false),
        ));
        msgs.push(msg(
            "/camera/color/image_raw",
            "sensor_msgs/Image",
            frame_time(k),
            color_msg(k, cam.w, cam.h),
        ));
    }
    let bag = dir.join("vga.bag");
    write_bag(&bag, &msgs, 16, &[Compression::Lz4]);
    let poses = dir.join("poses.csv");
    let frame_ids = ids(0..n as usize);
    write_pose_file(&poses, &frame_ids, None, 0);
    let cell = dir.join("cell");
    let start = std::time::Instant::now();
    let (code, _, err) = depthcal(&[
        "import",
        s(&bag),
        s(&cell),
        "--robot",
        "r",
        "--poses",
        s(&poses),
        "--hand-eye",
        "identity",
        "--color",
    ]);
    let secs = start.elapsed().as_secs_f64();
    assert_eq!(code, 0, "{err}");
    let mb = std::fs::metadata(&bag).unwrap().len() as f64 / 1e6;
    eprintln!("import of {n} VGA depth+colour frames ({mb:.1} MB LZ4 bag): {secs:.2} s");
    check_frames(&cell, "r", &frame_ids[..2], &[0, 1], 0, true);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn corrupted_bags_give_errors_not_panics() {
    use depthcal::capture::rosbag::{BagImportConfig, BagRecording};
    use depthcal::capture::{import_recording, MatchConfig, PoseRows, RobotSetup};
    let dir = common::scratch("bag-corrupt");
    let bag = dir.join("rec.bag");
    ros_driver_bag(
        &bag,
        4,
        &[Compression::None, Compression::Lz4, Compression::Bz2],
    );
    let poses = dir.join("poses.csv");
    write_pose_file(&poses, &ids(0..4), None, 0);
    let rows = PoseRows::read(&poses, None).unwrap();
    let good = std::fs::read(&bag).unwrap();
    let mut errors = 0;
    // Overwrite 24 bytes at 40 places from the bag header to the index; also cut the file short.
    let n = good.len();
    let mut cases: Vec<Vec<u8>> = (0..40)
        .map(|i| {
            let at = 13 + (n - 40) * i / 40;
            let mut b = good.clone();
            for x in &mut b[at..at + 24] {
                *x = x.wrapping_mul(31).wrapping_add(0x5a);
            }
            b
        })
        .collect();
    cases.extend((1..8).map(|i| good[..n * i / 8].to_vec()));
    for (i, bytes) in cases.iter().enumerate() {
        let path = dir.join(format!("bad{i}.bag"));
        std::fs::write(&path, bytes).unwrap();
        let cell = dir.join(format!("cell{i}"));
        let result = std::panic::catch_unwind(|| {
            BagRecording::open(&path, &BagImportConfig::default()).and_then(|mut b| {
                import_recording(
                    &mut b,
                    &rows,
                    &MatchConfig::default(),
                    &RobotSetup::new("r", Some(nalgebra::Isometry3::identity())),
                    &cell,
                )
            })
        });
        match result {
            Err(_) => panic!("case {i}: the reader panicked on a corrupted bag"),
            Ok(Err(e)) => {
                errors += 1;
                assert!(
                    e.to_string().contains(&format!("bad{i}.bag")),
                    "case {i}: {e}"
                );
                assert!(!cell.exists(), "case {i}: nothing may be written");
            }
            Ok(Ok(_)) => {} // the corruption hit pixel data: imported as recorded
        }
    }
    assert!(
        errors >= 10,
        "only {errors} of {} corruptions were detected",
        cases.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `capture` needs a camera, so its report is built here the way the command builds it: one append per
/// frame taken (`--poses`), the first creating the cell and the robot.
#[test]
fn the_capture_report_covers_every_append_and_is_documented() {
    use depthcal::camera::{DepthImage, Intrinsics};
    use depthcal::capture::{append_frames, NewFrame, RobotSetup};
    use depthcal::report::CaptureReport;
    let dir = common::scratch("capture-report");
    let cell = dir.join("cell");
    let intr = Intrinsics::pinhole(8, 6, 5.0, 5.0, 3.5, 2.5);
    let frame = |id: &str| NewFrame {
        id: id.into(),
        t_base_ee: nalgebra::Isometry3::identity(),
        depth: DepthImage {
            width: 8,
            height: 6,
            data: vec![700; 48],
        },
        color: None,
        source: format!("test frame {id}"),
        pose_origin: "test".into(),
    };
    let setup = RobotSetup {
        name: "left".into(),
        hand_eye: Some(nalgebra::Isometry3::identity()),
        pose_format: PoseFormat::Kuka,
    };
    let appends = vec![
        append_frames(&cell, &setup, &intr, &[frame("a")]).unwrap(),
        append_frames(&cell, &setup, &intr, &[frame("b"), frame("c")]).unwrap(),
    ];
    let r = CaptureReport::new("D435", "0123", &intr, &appends).unwrap();
    let v = serde_json::to_value(&r).unwrap();
    assert_eq!(v["schema"], "depthcal.capture/1");
    common::assert_documented(&v);
    assert_eq!(v["frames"], serde_json::json!(["a", "b", "c"]));
    assert_eq!(v["frames_total"], 3);
    assert_eq!(v["created_cell"], true);
    assert_eq!(v["created_robot"], true);
    assert_eq!(v["intrinsics"]["fx"], 5.0);
    assert_eq!(v["cell_dir"], cell.display().to_string());
    assert!(CaptureReport::new("D435", "0123", &intr, &[]).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}
