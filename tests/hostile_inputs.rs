//! Hostile input files (issue 15): every reader answers a lying header, a wrapping size, a transposed array or
//! a malformed line with a typed error naming the file and the field or line — never a panic, an abort from a
//! huge allocation, or data silently lost.
//!
//! `cargo test --release --test hostile_inputs -- --ignored write_fuzz_seeds` (re)writes the fuzzers' seed
//! corpora under `fuzz/corpus/`.

mod common;
use common::scratch;
use depthcal::camera::{read_depth_png, write_depth_png, DepthImage, Intrinsics};
use depthcal::capture::rosbag::{BagImportConfig, BagRecording, RosCameraInfo, RosImage};
use depthcal::io::{parse_cloud, parse_matrix, read_cloud};
use depthcal::{Error, PointCloud};
use std::path::{Path, PathBuf};

/// Writes `bytes` to `dir/name`, reads it with `read` inside `catch_unwind`, and returns the error text,
/// failing when the reader panicked or accepted the file.
fn error_of<T: std::fmt::Debug>(
    dir: &Path,
    name: &str,
    bytes: &[u8],
    read: impl Fn(&Path) -> depthcal::Result<T> + std::panic::UnwindSafe,
) -> String {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    let p = path.clone();
    let r = std::panic::catch_unwind(move || read(&p))
        .unwrap_or_else(|_| panic!("{name}: the reader panicked"));
    let e = match r {
        Ok(v) => panic!("{name}: accepted: {v:?}"),
        Err(e) => e,
    };
    let text = e.to_string();
    assert!(
        matches!(e, Error::Format { .. }),
        "{name}: not a format error: {e:?}"
    );
    assert!(
        text.contains(name),
        "{name}: the error does not name the file: {text}"
    );
    text
}

fn cloud_error(dir: &Path, name: &str, bytes: &[u8]) -> String {
    error_of(dir, name, bytes, |p| read_cloud(p))
}

fn has(e: &str, parts: &[&str]) {
    for p in parts {
        assert!(e.contains(p), "`{p}` missing from: {e}");
    }
}

// ---------------------------------------------------------------------------------------------------------
// PCD

#[test]
fn pcd_count_zero_is_an_error() {
    let d = scratch("hostile-pcd-count0");
    let mut b =
        b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 0 0 0\nWIDTH 2\nPOINTS 2\nDATA binary\n"
            .to_vec();
    b.extend([0u8; 24]);
    let e = cloud_error(&d, "count0.pcd", &b);
    has(&e, &["field `x` has COUNT 0", "at least 1"]);
    // ASCII too.
    let e = cloud_error(
        &d,
        "count0a.pcd",
        b"FIELDS x y z\nCOUNT 1 0 1\nPOINTS 1\nDATA ascii\n1 2 3\n",
    );
    has(&e, &["field `y` has COUNT 0"]);
}

#[test]
fn pcd_rgb_of_other_than_4_bytes_is_an_error() {
    let d = scratch("hostile-pcd-rgb");
    for (size, ty) in [(1, "U"), (2, "U"), (8, "F")] {
        let mut b = format!(
            "FIELDS x y z rgb\nSIZE 4 4 4 {size}\nTYPE F F F {ty}\nWIDTH 1\nPOINTS 1\nDATA binary\n"
        )
        .into_bytes();
        b.extend(vec![0u8; 12 + size]);
        let e = cloud_error(&d, &format!("rgb{size}.pcd"), &b);
        has(&e, &[&format!("field `rgb` has SIZE {size}"), "SIZE 4"]);
    }
}

#[test]
fn pcd_point_counts_that_wrap_or_exceed_the_file_are_errors() {
    let d = scratch("hostile-pcd-points");
    // n * fields wraps (2^62 * 4 values).
    let e = cloud_error(
        &d,
        "wrap.pcd",
        b"FIELDS x y z rgb\nPOINTS 4611686018427387904\nDATA ascii\n1 2 3 4\n",
    );
    has(
        &e,
        &["header says 4611686018427387904 points", "bytes of data"],
    );
    // 1e10 points claimed by a 14 kB file: refused before anything is allocated.
    let mut b = b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 10000000000\nDATA ascii\n".to_vec();
    while b.len() < 14_000 {
        b.extend(b"0.125 0.25 0.5\n");
    }
    let t = std::time::Instant::now();
    let e = cloud_error(&d, "1e10.pcd", &b);
    has(&e, &["header says 10000000000 points", "ASCII data"]);
    assert!(t.elapsed().as_secs_f64() < 1.0, "took {:?}", t.elapsed());
    // Binary: POINTS x record wraps.
    let e = cloud_error(
        &d,
        "wrapbin.pcd",
        b"FIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nPOINTS 1537228672809129302\nDATA binary\n\0\0\0\0",
    );
    has(&e, &["binary data is truncated", "too many"]);
    // WIDTH x HEIGHT wraps.
    let e = cloud_error(
        &d,
        "wh.pcd",
        b"FIELDS x y z\nWIDTH 4294967296\nHEIGHT 4294967296\nDATA binary\n",
    );
    has(&e, &["WIDTH 4294967296 x HEIGHT 4294967296 overflows"]);
}

#[test]
fn pcd_field_sizes_and_counts_that_wrap_are_errors() {
    let d = scratch("hostile-pcd-size");
    let e = cloud_error(
        &d,
        "sizewrap.pcd",
        b"FIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 2305843009213693952\nPOINTS 1\nDATA binary\n",
    );
    has(
        &e,
        &["field `z`: SIZE 8 x COUNT 2305843009213693952 overflows"],
    );
    let e = cloud_error(
        &d,
        "countsum.pcd",
        b"FIELDS x y z\nSIZE 1 1 1\nTYPE U U U\nCOUNT 1 18446744073709551615 1\nPOINTS 1\nDATA binary\n",
    );
    has(&e, &["overflows"]);
    // A huge COUNT that does not wrap still needs the data.
    let e = cloud_error(
        &d,
        "bigcount.pcd",
        b"FIELDS x y z\nCOUNT 1 1 100000000000\nPOINTS 1\nDATA ascii\n1 2 3\n",
    );
    has(&e, &["header says 1 points", "bytes of data"]);
}

#[test]
fn pcd_compressed_size_claims_are_checked() {
    let d = scratch("hostile-pcd-lzf");
    let head = |n: u64| {
        format!("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS {n}\nDATA binary_compressed\n")
            .into_bytes()
    };
    // Uncompressed size claims 4 GB-ish from 2 bytes of compressed data.
    let n = 357913941u64; // x 12 bytes = 4294967292
    let mut b = head(n);
    b.extend(2u32.to_le_bytes());
    b.extend(((n * 12) as u32).to_le_bytes());
    b.extend([0u8, 0]);
    let e = cloud_error(&d, "bomb.pcd", &b);
    has(
        &e,
        &["uncompressed size 4294967292 is impossible from 2 bytes"],
    );
    // Compressed size beyond the file.
    let mut b = head(1);
    b.extend(1000u32.to_le_bytes());
    b.extend(12u32.to_le_bytes());
    b.extend([11u8; 12]);
    let e = cloud_error(&d, "csize.pcd", &b);
    has(&e, &["compressed size says 1000 bytes"]);
    // Uncompressed size that disagrees with POINTS.
    let mut b = head(2);
    b.extend(13u32.to_le_bytes());
    b.extend(12u32.to_le_bytes());
    b.push(11);
    b.extend([0u8; 12]);
    let e = cloud_error(&d, "usize.pcd", &b);
    has(
        &e,
        &["uncompressed size 12 does not match 2 points of 12 bytes"],
    );
    // A well-formed literal-only LZF payload reads.
    let mut b = head(1);
    b.extend(13u32.to_le_bytes());
    b.extend(12u32.to_le_bytes());
    b.push(11);
    for v in [1f32, 2., 3.] {
        b.extend(v.to_le_bytes());
    }
    assert_eq!(
        parse_cloud(&b, "ok.pcd").unwrap().points,
        vec![[1., 2., 3.]]
    );
}

// ---------------------------------------------------------------------------------------------------------
// NPY

fn npy(shape: &str, data: &[f32]) -> Vec<u8> {
    let mut h = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    while !(10 + h.len() + 1).is_multiple_of(64) {
        h.push(' ');
    }
    h.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((h.len() as u16).to_le_bytes());
    b.extend(h.as_bytes());
    for v in data {
        b.extend(v.to_le_bytes());
    }
    b
}

#[test]
fn npy_huge_shape_is_an_error_not_a_capacity_overflow() {
    let d = scratch("hostile-npy-huge");
    let e = cloud_error(&d, "huge.npy", &npy("(4611686018427387904, 3)", &[1.0; 6]));
    has(
        &e,
        &[
            "data truncated: shape (4611686018427387904, 3) needs",
            "found 24",
        ],
    );
    let e = cloud_error(&d, "huge2.npy", &npy("(1000000, 3)", &[1.0; 6]));
    has(&e, &["needs 12000000 bytes, found 24"]);
}

#[test]
fn npy_transposed_array_is_refused_with_a_hint() {
    let d = scratch("hostile-npy-t");
    let e = cloud_error(&d, "t.npy", &npy("(3, 5)", &[0.5; 15]));
    has(&e, &["shape (3, 5)", "expected (N, 3)", "transposed"]);
    let e = cloud_error(&d, "flat.npy", &npy("(9,)", &[0.5; 9]));
    has(&e, &["shape [9]", "expected (N, 3)"]);
    // (3, 3) is three points.
    assert_eq!(
        parse_cloud(&npy("(3, 3)", &[0.0; 9]), "sq.npy")
            .unwrap()
            .len(),
        3
    );
}

// ---------------------------------------------------------------------------------------------------------
// PLY

const PLY_ASCII_HEAD: &str =
    "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n";

#[test]
fn ply_understated_vertex_count_is_an_error_in_every_encoding() {
    let d = scratch("hostile-ply-under");
    let b = format!("{PLY_ASCII_HEAD}1 2 3\n4 5 6\n7 8 9\n");
    let e = cloud_error(&d, "under.ply", b.as_bytes());
    has(
        &e,
        &[
            "line 10: data continues after the header's 2 vertices",
            "vertex count",
        ],
    );
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    for v in [1f32, 2., 3., 4., 5., 6.] {
        b.extend(v.to_le_bytes());
    }
    let e = cloud_error(&d, "underbin.ply", &b);
    has(
        &e,
        &[
            "12 bytes of data follow the last of the header's 1 vertices",
            "vertex count",
        ],
    );
    // Overstated: fewer lines than the header says.
    let b = format!("{PLY_ASCII_HEAD}1 2 3\n");
    let e = cloud_error(&d, "over.ply", b.as_bytes());
    has(&e, &["the header says 2 vertices, the data ends after 1"]);
}

#[test]
fn ply_binary_count_beyond_the_file_is_an_error() {
    let d = scratch("hostile-ply-count");
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec();
    b.extend([0u8; 48]);
    let e = cloud_error(&d, "count.ply", &b);
    has(
        &e,
        &[
            "element `vertex`: the header says 1000000000000000 entries of at least 24 bytes",
            "48 bytes",
        ],
    );
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement face 18446744073709551615\nproperty list uchar int vertex_indices\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    b.extend([0u8; 12]);
    let e = cloud_error(&d, "face.ply", &b);
    has(&e, &["element `face`"]);
}

#[test]
fn ply_ascii_nan_reads_and_is_dropped_with_a_warning_count() {
    let d = scratch("hostile-ply-nan");
    let b = format!("{PLY_ASCII_HEAD}1 2 3\nnan 5 -inf\n");
    let p = d.join("nan.ply");
    std::fs::write(&p, b).unwrap();
    let mut c = read_cloud(&p).unwrap();
    assert_eq!(c.len(), 2);
    assert!(c.points[1][0].is_nan() && c.points[1][2] == f32::NEG_INFINITY);
    assert_eq!(c.drop_non_finite(), 1);
    assert_eq!(c.points, vec![[1., 2., 3.]]);
    // The registration pipeline reports the dropped point in its warnings.
    let mut src = common::synthetic_scene(3, 300);
    src.points.push([f32::NAN, 0.0, 0.0]);
    let tgt = common::synthetic_scene(3, 300);
    let r = depthcal::registration::register(
        &src,
        &tgt,
        Some(&nalgebra::Isometry3::identity()),
        &Default::default(),
    )
    .unwrap();
    assert!(
        r.warnings
            .iter()
            .any(|w| w.contains("1 source points with NaN")),
        "{:?}",
        r.warnings
    );
    // Garbage that is not a number names the line and the property.
    let b = format!("{PLY_ASCII_HEAD}1 2 3\n4 five 6\n");
    let e = cloud_error(&d, "bad.ply", b.as_bytes());
    has(
        &e,
        &["line 9: vertex 1: property `y` value `five` is not a number"],
    );
}

// ---------------------------------------------------------------------------------------------------------
// XYZ

#[test]
fn xyz_malformed_first_line_is_an_error_not_a_header() {
    let d = scratch("hostile-xyz");
    let e = cloud_error(&d, "a.xyz", b"1.0 2.0 abc\n4 5 6\n7 8 9\n");
    has(
        &e,
        &["line 1: expected x y z numbers, coordinate z `abc` is not a number"],
    );
    let e = cloud_error(&d, "b.xyz", b"# comment\n\n1 2\n4 5 6\n");
    has(&e, &["line 3:", "coordinate z is missing"]);
    let e = cloud_error(&d, "c.xyz", b"x y z\n1 2 3\n4 5 six\n");
    has(&e, &["line 3:", "`six` is not a number"]);
    // A names-only first line is a header.
    for h in ["x y z", "X,Y,Z,intensity", "//x y z"] {
        let c = parse_cloud(format!("{h}\n1 2 3\n4 5 6\n").as_bytes(), "h.xyz").unwrap();
        assert_eq!(c.points, vec![[1., 2., 3.], [4., 5., 6.]], "{h}");
    }
}

// ---------------------------------------------------------------------------------------------------------
// Depth PNG, intrinsics, camera info

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 {
                (c >> 1) ^ 0xEDB8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let mut body = kind.to_vec();
    body.extend(data);
    out.extend(&body);
    out.extend(crc32(&body).to_be_bytes());
}

/// A 16-bit greyscale PNG whose header says `w x h`, with a few bytes of (not decodable) image data.
fn lying_png(w: u32, h: u32) -> Vec<u8> {
    let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([16, 0, 0, 0, 0]);
    png_chunk(&mut b, b"IHDR", &ihdr);
    png_chunk(
        &mut b,
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    );
    png_chunk(&mut b, b"IEND", &[]);
    b
}

#[test]
fn depth_png_sizes_are_capped_and_checked_against_the_file() {
    let d = scratch("hostile-png");
    let e = error_of(&d, "huge.png", &lying_png(60000, 60000), |p| {
        read_depth_png(p)
    });
    has(
        &e,
        &[
            "PNG header (IHDR width, height)",
            "60000x60000",
            "larger than depthcal accepts",
        ],
    );
    let e = error_of(&d, "huge.png", &lying_png(60000, 60000), |p| {
        depthcal::camera::depth::read_depth_png_header(p)
    });
    has(&e, &["60000x60000"]);
    // Within the cap but far more pixels than the file can hold.
    let e = error_of(&d, "lying.png", &lying_png(8000, 8000), |p| {
        read_depth_png(p)
    });
    has(&e, &["8000x8000", "cannot hold"]);
    // A real image still reads.
    let img = DepthImage {
        width: 3,
        height: 2,
        data: vec![1, 2, 3, 4, 5, 6],
    };
    write_depth_png(d.join("ok.png"), &img).unwrap();
    assert_eq!(read_depth_png(d.join("ok.png")).unwrap(), img);
}

#[test]
fn intrinsics_claiming_huge_images_are_refused_before_the_ray_table() {
    let d = scratch("hostile-intr");
    let j =
        r#"{"fx": 600, "fy": 600, "ppx": 30000, "ppy": 30000, "width": 60000, "height": 60000}"#;
    let e = error_of(&d, "intrinsics.json", j.as_bytes(), |p| {
        Intrinsics::from_json_file(p)
    });
    has(
        &e,
        &[
            "fields `width` and `height`",
            "60000x60000",
            "larger than depthcal accepts",
        ],
    );
    let j = r#"{"width": 60000, "height": 60000, "intrinsic_matrix": [600,0,0,0,600,0,300,300,1]}"#;
    let e = error_of(&d, "o3d.json", j.as_bytes(), |p| {
        Intrinsics::from_json_file(p)
    });
    has(&e, &["60000x60000"]);
    let j = r#"{"fx": 600, "fy": 600, "ppx": 1, "ppy": 1, "width": 4294967295, "height": 1}"#;
    let e = error_of(&d, "wide.json", j.as_bytes(), |p| {
        Intrinsics::from_json_file(p)
    });
    has(&e, &["4294967295x1"]);
    let j = r#"{"fx": 600, "fy": 600, "ppx": 1, "ppy": 1, "width": 1, "height": 1e400}"#;
    let e = error_of(&d, "num.json", j.as_bytes(), |p| {
        Intrinsics::from_json_file(p)
    });
    has(&e, &["not valid JSON"]);
}

fn le32(v: u32) -> [u8; 4] {
    v.to_le_bytes()
}

fn ros_string(s: &str) -> Vec<u8> {
    let mut v = le32(s.len() as u32).to_vec();
    v.extend(s.as_bytes());
    v
}

fn ros_header() -> Vec<u8> {
    let mut v = le32(1).to_vec();
    v.extend(le32(1_700_000_000));
    v.extend(le32(0));
    v.extend(ros_string("cam"));
    v
}

fn camera_info(w: u32, h: u32) -> Vec<u8> {
    let mut v = ros_header();
    v.extend(le32(h));
    v.extend(le32(w));
    v.extend(ros_string("plumb_bob"));
    v.extend(le32(0));
    let k = [
        600.0f64,
        0.0,
        w as f64 / 2.0,
        0.0,
        600.0,
        h as f64 / 2.0,
        0.0,
        0.0,
        1.0,
    ];
    let r = [1.0f64, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let p = [
        600.0f64, 0.0, 1.0, 0.0, 0.0, 600.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    for x in k.iter().chain(&r).chain(&p) {
        v.extend(x.to_le_bytes());
    }
    v.extend([0u8; 8 + 16 + 1]);
    v
}

fn image(w: u32, h: u32, step: u32, encoding: &str, data: &[u8]) -> Vec<u8> {
    let mut v = ros_header();
    v.extend(le32(h));
    v.extend(le32(w));
    v.extend(ros_string(encoding));
    v.push(0);
    v.extend(le32(step));
    v.extend(le32(data.len() as u32));
    v.extend(data);
    v
}

#[test]
fn ros_messages_with_lying_sizes_are_errors() {
    let ci = RosCameraInfo::decode(&camera_info(60000, 60000)).unwrap();
    let e = ci.to_intrinsics(0.001).unwrap_err();
    has(&e, &["fields `width` and `height`", "60000x60000"]);
    // width x height x bpp far beyond the data, and step x height wrapping u32.
    let e = RosImage::decode(&image(60000, 60000, 120000, "16UC1", &[0; 16])).unwrap_err();
    has(
        &e,
        &["data has 16 bytes, fewer than step 120000 x height 60000"],
    );
    let e = RosImage::decode(&image(u32::MAX, 2, u32::MAX, "32FC1", &[0; 16])).unwrap_err();
    has(
        &e,
        &["step 4294967295 is less than width 4294967295 x 4 bytes"],
    );
    // Found by fuzzing: an unknown encoding passed decode and to_depth reserved width x height first.
    let msg = image(60000, 60000, 0, "yuv422", &[]);
    let img = RosImage::decode(&msg).unwrap();
    has(
        &img.to_depth(0.001).unwrap_err(),
        &["encoding \"yuv422\" is not a depth encoding"],
    );
    has(&img.to_rgb().unwrap_err(), &["is not a colour encoding"]);
    let crash = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/hostile/rosbag-image-unknown-encoding.bin"),
    )
    .unwrap();
    if let Ok(img) = RosImage::decode(&crash) {
        assert!(img.to_depth(0.001).is_err());
    }
    // A message built by hand with a lying layout is checked too.
    let forged = RosImage {
        encoding: "16UC1",
        width: 60000,
        height: 60000,
        step: 120000,
        data: &[0; 16],
        ..img
    };
    has(
        &forged.to_depth(0.001).unwrap_err(),
        &["data has 16 bytes, fewer than step 120000 x height 60000"],
    );
    let forged = RosImage {
        encoding: "rgb8",
        step: 1,
        ..forged
    };
    has(
        &forged.to_rgb().unwrap_err(),
        &["step 1 is less than width 60000 x 3 bytes of rgb8"],
    );
    let mut short = image(2, 2, 4, "16UC1", &[0; 8]);
    short.truncate(short.len() - 3);
    let e = RosImage::decode(&short).unwrap_err();
    has(&e, &["truncated message: data needs 8 bytes"]);
}

// ---------------------------------------------------------------------------------------------------------
// A minimal ROS1 bag (format 2.0, one uncompressed chunk) for the bag tests and the fuzz seeds.

fn bag_field(name: &str, value: &[u8]) -> Vec<u8> {
    let mut v = le32((name.len() + 1 + value.len()) as u32).to_vec();
    v.extend(name.as_bytes());
    v.push(b'=');
    v.extend(value);
    v
}

fn bag_record(fields: &[(&str, Vec<u8>)], data: &[u8]) -> Vec<u8> {
    let header: Vec<u8> = fields.iter().flat_map(|(n, v)| bag_field(n, v)).collect();
    let mut v = le32(header.len() as u32).to_vec();
    v.extend(&header);
    v.extend(le32(data.len() as u32));
    v.extend(data);
    v
}

/// A bag with a camera info and `frames` 4x3 depth images; `chunk_size` overrides the chunk's `size` field.
fn small_bag(frames: u32, chunk_size: Option<u32>, compression: &str) -> Vec<u8> {
    let topics = [
        ("/cam/depth/camera_info", "sensor_msgs/CameraInfo"),
        ("/cam/depth/image_rect_raw", "sensor_msgs/Image"),
    ];
    let conn = |id: u32| {
        let (topic, tp) = topics[id as usize];
        let data: Vec<u8> = [
            bag_field("topic", topic.as_bytes()),
            bag_field("type", tp.as_bytes()),
            bag_field("md5sum", b"0123456789abcdef0123456789abcdef"),
            bag_field("message_definition", b"# test\n"),
        ]
        .concat();
        bag_record(
            &[
                ("op", vec![7]),
                ("conn", le32(id).to_vec()),
                ("topic", topic.as_bytes().to_vec()),
            ],
            &data,
        )
    };
    let time = |k: u32| [le32(1_700_000_000 + k), le32(0)].concat();
    let mut inner = conn(0);
    inner.extend(conn(1));
    let mut offsets = vec![(0u32, inner.len() as u32)];
    inner.extend(bag_record(
        &[
            ("op", vec![2]),
            ("conn", le32(0).to_vec()),
            ("time", time(0)),
        ],
        &camera_info(4, 3),
    ));
    for k in 0..frames {
        offsets.push((1, inner.len() as u32));
        let px: Vec<u8> = (0..12u16)
            .flat_map(|i| (500 + 10 * i + k as u16).to_le_bytes())
            .collect();
        inner.extend(bag_record(
            &[
                ("op", vec![2]),
                ("conn", le32(1).to_vec()),
                ("time", time(k)),
            ],
            &image(4, 3, 8, "16UC1", &px),
        ));
    }
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    let header_at = out.len();
    out.extend(vec![0u8; 4096]);
    let chunk_pos = out.len() as u64;
    out.extend(bag_record(
        &[
            ("op", vec![5]),
            ("compression", compression.as_bytes().to_vec()),
            (
                "size",
                le32(chunk_size.unwrap_or(inner.len() as u32)).to_vec(),
            ),
        ],
        &inner,
    ));
    for id in 0..2u32 {
        let mut data = Vec::new();
        let mine: Vec<_> = offsets.iter().filter(|(c, _)| *c == id).collect();
        for (i, (_, off)) in mine.iter().enumerate() {
            data.extend(time(i as u32));
            data.extend(le32(*off));
        }
        out.extend(bag_record(
            &[
                ("op", vec![4]),
                ("ver", le32(1).to_vec()),
                ("conn", le32(id).to_vec()),
                ("count", le32(mine.len() as u32).to_vec()),
            ],
            &data,
        ));
    }
    let index_pos = out.len() as u64;
    out.extend(conn(0));
    out.extend(conn(1));
    let mut data = Vec::new();
    for id in 0..2u32 {
        data.extend(le32(id));
        data.extend(le32(offsets.iter().filter(|(c, _)| *c == id).count() as u32));
    }
    out.extend(bag_record(
        &[
            ("op", vec![6]),
            ("ver", le32(1).to_vec()),
            ("chunk_pos", chunk_pos.to_le_bytes().to_vec()),
            ("start_time", time(0)),
            ("end_time", time(frames)),
            ("count", le32(2).to_vec()),
        ],
        &data,
    ));
    let fields = [
        ("op", vec![3]),
        ("index_pos", index_pos.to_le_bytes().to_vec()),
        ("conn_count", le32(2).to_vec()),
        ("chunk_count", le32(1).to_vec()),
    ];
    let header_len: usize = fields.iter().map(|(n, v)| 4 + n.len() + 1 + v.len()).sum();
    let h = bag_record(&fields, &vec![b' '; 4096 - 8 - header_len]);
    out[header_at..header_at + 4096].copy_from_slice(&h);
    out
}

#[test]
fn bag_with_lying_chunk_size_is_an_error() {
    let d = scratch("hostile-bag");
    let good = d.join("good.bag");
    std::fs::write(&good, small_bag(2, None, "none")).unwrap();
    let b = BagRecording::open(&good, &BagImportConfig::default()).unwrap();
    assert_eq!(b.topics.len(), 2);
    // A chunk claiming 4 GB of decompressed data from a few hundred bytes, in every compression.
    for comp in ["none", "lz4", "bz2"] {
        let name = format!("size-{comp}.bag");
        let e = error_of(&d, &name, &small_bag(2, Some(u32::MAX), comp), |p| {
            BagRecording::open(p, &BagImportConfig::default()).map(|_| ())
        });
        has(
            &e,
            &[
                "not a readable ROS1 bag: record 1 at byte 4109",
                "chunk header field `size` says 4294967295 bytes",
            ],
        );
    }
    let e = error_of(&d, "small.bag", &small_bag(2, Some(5), "none"), |p| {
        BagRecording::open(p, &BagImportConfig::default()).map(|_| ())
    });
    has(&e, &["chunk header field `size` says 5 bytes"]);
    // A record whose data length runs past the end of the file.
    let mut b = small_bag(2, None, "none");
    let hlen = u32::from_le_bytes(b[4109..4113].try_into().unwrap()) as usize;
    let at = 4113 + hlen;
    let len = b.len() as u32;
    b[at..at + 4].copy_from_slice(&len.to_le_bytes());
    let e = error_of(&d, "dlen.bag", &b, |p| {
        BagRecording::open(p, &BagImportConfig::default()).map(|_| ())
    });
    has(
        &e,
        &[
            "record 1 at byte 4109: data length",
            "runs past the end of the file",
        ],
    );
}

// ---------------------------------------------------------------------------------------------------------
// Matrix, poses, manifest

#[test]
fn matrix_reader_refuses_garbage_without_panicking() {
    let p = "T.txt";
    let e = parse_matrix(&"1 ".repeat(100_000), p)
        .unwrap_err()
        .to_string();
    has(&e, &["T.txt", "line 1: more than 16 numbers"]);
    let e = parse_matrix("nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", p)
        .unwrap_err()
        .to_string();
    has(&e, &["T.txt", "NaN"]);
    let deep = format!(
        "{{\"transform\": {}1{}}}",
        "[".repeat(10_000),
        "]".repeat(10_000)
    );
    let e = parse_matrix(&deep, p).unwrap_err().to_string();
    has(&e, &["T.txt", "invalid JSON"]);
}

#[test]
fn pose_csv_and_manifest_refuse_garbage_with_line_or_field() {
    use depthcal::io::poses::parse_poses;
    let p = Path::new("r/poses.csv");
    let e = parse_poses(
        "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n001,1,2,3,nan,0,0\n",
        None,
        p,
    )
    .unwrap_err()
    .to_string();
    has(&e, &["r/poses.csv", "line 2"]);
    let e = parse_poses(
        "frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n001,1,2,3,0,0\n",
        None,
        p,
    )
    .unwrap_err()
    .to_string();
    has(&e, &["r/poses.csv", "line 2", "columns"]);
    let m = Path::new("c/cell.toml");
    let e = depthcal::cell::CellManifest::from_toml_str("format = 3\n[[robot]]\n", m)
        .unwrap_err()
        .to_string();
    has(&e, &["c/cell.toml"]);
}

// ---------------------------------------------------------------------------------------------------------
// Fuzz seeds

fn write_seed(root: &Path, target: &str, name: &str, bytes: &[u8]) {
    let d = root.join(target);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join(name), bytes).unwrap();
}

#[test]
#[ignore = "writes fuzz/corpus; run by hand"]
fn write_fuzz_seeds() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let tmp = scratch("seeds");
    let mut c = PointCloud::from_points(vec![[1., 2., 3.], [4., 5., 6.], [0.5, -1., 2.]]);
    c.normals = Some(vec![[0., 0., 1.]; 3]);
    c.colors = Some(vec![[255, 0, 7]; 3]);
    depthcal::io::write_cloud(tmp.join("b.ply"), &c).unwrap();
    depthcal::io::write_ply_ascii(tmp.join("a.ply"), &c).unwrap();
    depthcal::io::write_ply_big_endian(tmp.join("be.ply"), &c).unwrap();
    for f in ["a.ply", "b.ply", "be.ply"] {
        write_seed(&root, "ply", f, &std::fs::read(tmp.join(f)).unwrap());
    }
    write_seed(&root, "ply", "face.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
    write_seed(&root, "pcd", "a.pcd", b"VERSION .7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 16711680\n4 5 6 255\n");
    let mut b = b"FIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 8 4 4 4\nTYPE F F F F F F\nCOUNT 1 1 1 1 1 1\nWIDTH 2\nPOINTS 2\nDATA binary\n".to_vec();
    for _ in 0..2 {
        b.extend(1f32.to_le_bytes());
        b.extend(2f32.to_le_bytes());
        b.extend(3f64.to_le_bytes());
        for v in [0f32, 0., 1.] {
            b.extend(v.to_le_bytes());
        }
    }
    write_seed(&root, "pcd", "b.pcd", &b);
    let mut b = b"FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary_compressed\n".to_vec();
    // Field-major x x y y z z, literal run of 24 bytes, then a back-reference.
    let mut soa = Vec::new();
    for v in [1f32, 1., 2., 2., 3., 3.] {
        soa.extend(v.to_le_bytes());
    }
    let mut lzf = vec![23u8];
    lzf.extend(&soa);
    b.extend((lzf.len() as u32).to_le_bytes());
    b.extend(24u32.to_le_bytes());
    b.extend(lzf);
    write_seed(&root, "pcd", "c.pcd", &b);
    write_seed(
        &root,
        "xyz",
        "a.xyz",
        b"x y z\n1 2 3\n4,5,6,extra\n\n# c\n7 8 9\n",
    );
    write_seed(&root, "xyz", "b.xyz", b"1;2;3\n-1e-3 2.5e2 nan\n");
    write_seed(
        &root,
        "npy",
        "a.npy",
        &npy("(2, 3)", &[1., 2., 3., 4., 5., 6.]),
    );
    let mut h8 = npy("(1, 3)", &[]);
    let _ = &mut h8;
    let mut b = npy("(1, 3)", &[]);
    b = String::from_utf8_lossy(&b)
        .replace("<f4", "<f8")
        .into_bytes();
    for v in [1f64, 2., 3.] {
        b.extend(v.to_le_bytes());
    }
    write_seed(&root, "npy", "b.npy", &b);
    let img = DepthImage {
        width: 4,
        height: 3,
        data: (0..12).map(|i| 500 + i * 7).collect(),
    };
    write_depth_png(tmp.join("d.png"), &img).unwrap();
    write_seed(
        &root,
        "depth_png",
        "d.png",
        &std::fs::read(tmp.join("d.png")).unwrap(),
    );
    write_seed(&root, "depth_png", "lying.png", &lying_png(64, 64));
    write_seed(
        &root,
        "pose_csv",
        "kuka.csv",
        b"frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n001,100,200,300,10,20,30\n002,1,2,3,0,0,0\n",
    );
    write_seed(
        &root,
        "pose_csv",
        "quat.csv",
        b"# q\nframe,x,y,z,qx,qy,qz,qw\n1,0.1,0.2,0.3,0,0,0,1\n",
    );
    write_seed(&root, "pose_csv", "matrix.csv", b"frame,m00,m01,m02,m03,m10,m11,m12,m13,m20,m21,m22,m23,m30,m31,m32,m33\na,1,0,0,1,0,1,0,2,0,0,1,3,0,0,0,1\n");
    let intr = Intrinsics::pinhole(640, 480, 615.0, 615.0, 320.0, 240.0);
    write_seed(
        &root,
        "intrinsics_json",
        "a.json",
        intr.to_json_string().as_bytes(),
    );
    write_seed(&root, "intrinsics_json", "bc.json", br#"{"fx": 600, "fy": 601, "ppx": 320, "ppy": 240, "coeffs": [0.1, -0.05, 0.001, 0.002, 0.01], "model": "brown_conrady", "width": 640, "height": 480, "depth_scale": 0.001, "rms": 0.2}"#);
    write_seed(&root, "intrinsics_json", "o3d.json", br#"{"width": 640, "height": 480, "intrinsic_matrix": [525.0, 0, 0, 0, 525.0, 0, 319.5, 239.5, 1]}"#);
    let mut m = depthcal::cell::CellManifest::new("left");
    m.robots.push(depthcal::cell::RobotEntry::standard(
        "left",
        nalgebra::Isometry3::identity(),
    ));
    m.robots.push(depthcal::cell::RobotEntry::standard(
        "right",
        nalgebra::Isometry3::identity(),
    ));
    write_seed(
        &root,
        "cell_manifest",
        "cell.toml",
        m.to_toml_string().unwrap().as_bytes(),
    );
    write_seed(
        &root,
        "matrix",
        "t.txt",
        b"1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n",
    );
    write_seed(
        &root,
        "matrix",
        "t.json",
        br#"{"transform": [[1,0,0,1],[0,1,0,2],[0,0,1,3],[0,0,0,1]], "fitness": 1}"#,
    );
    write_seed(&root, "rosbag", "small.bag", &small_bag(2, None, "none"));
    write_seed(
        &root,
        "rosbag",
        "image.msg",
        &image(4, 3, 8, "16UC1", &[1; 24]),
    );
    write_seed(&root, "rosbag", "info.msg", &camera_info(4, 3));
    for k in 0..4u8 {
        let b: Vec<u8> = (0..200u32)
            .map(|i| (i * 37 + k as u32 * 101) as u8)
            .collect();
        write_seed(&root, "register_tiny", &format!("r{k}"), &b);
    }
}
