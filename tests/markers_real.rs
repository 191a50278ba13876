#![cfg(feature = "vision")]
//! Square markers on real photographs: AprilTag's regression images (47 small tag36h11 tags, 13–45 px, in
//! three 799×533 JPEGs; the reference corners are AprilTag 3's own detector's with `quad_decimate = 1` and
//! `refine_edges = false`, see the data's SOURCE.md), and the `depthcal markers` command on them.
//!
//! Requirement: the default detector finds at least 95% of the tags (45 of 47) with every corner within
//! 1.5 px of the reference. Corners are compared in one well-defined order: the printed top-left,
//! top-right, bottom-right, bottom-left ([`MarkerDetection::canonical_corners`]); the reference is brought
//! into it by [`CornerOrder::AprilTag`] and into OpenCV's pixel convention by `x − 0.5`, `y − 0.5`.
//! `cargo test --release --features vision --test markers_real -- --nocapture` prints the figures.

mod common;
use depthcal::camera::{DistortionModel, Intrinsics};
use depthcal::cell::MarkerDictionary;
use depthcal::vision::markers::{
    detect_markers, CornerOrder, MarkerConfig, MarkerDetection, MarkerDetector,
};
use depthcal::vision::pnp::pose_of_points;
use depthcal::vision::{read_grey_image, ArucoRefinement, SubpixMethod};
use nalgebra::Point2;
use std::path::{Path, PathBuf};
use std::time::Instant;

const DATA: &str = "apriltag-detection-regression";
const STEMS: [&str; 3] = [
    "33369213973_9d9bb4cc96_c",
    "34085369442_304b6bafd9_c",
    "34139872896_defdb2f8d9_c",
];

/// The reference tags of one image: id and canonical corners (OpenCV pixel convention).
fn reference(txt: &Path) -> Vec<(u32, [Point2<f64>; 4])> {
    let idx = CornerOrder::AprilTag.canonical_indices();
    std::fs::read_to_string(txt)
        .unwrap()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let (id, rest) = l.split_once(',').unwrap();
            let v: Vec<f64> = rest
                .replace(['(', ')', ','], " ")
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            assert_eq!(v.len(), 8, "{l}");
            let p = |k: usize| Point2::new(v[2 * k] - 0.5, v[2 * k + 1] - 0.5);
            (id.trim().parse().unwrap(), idx.map(p))
        })
        .collect()
}

/// The detection of `id` nearest to `corners` (by the mean corner distance, canonical order).
fn nearest<'a>(
    found: &'a [MarkerDetection],
    id: u32,
    corners: &[Point2<f64>; 4],
) -> Option<(&'a MarkerDetection, [f64; 4])> {
    found
        .iter()
        .filter(|m| m.id == id)
        .map(|m| {
            let c = m.canonical_corners();
            (m, [0, 1, 2, 3].map(|k| (c[k] - corners[k]).norm()))
        })
        .min_by(|a, b| a.1.iter().sum::<f64>().total_cmp(&b.1.iter().sum()))
}

struct Figures {
    within: usize,
    total: usize,
    median: f64,
    max: f64,
    ms_per_image: f64,
    /// Median signed offset (x, y) of matched corners, detection − reference, pixels.
    offset: (f64, f64),
}

/// Runs `cfg` on the three images and compares with the reference (corners of a tag within 1.5 px of
/// its reference count it as found; errors are over the tags whose detection is within 5 px).
fn measure(dir: &Path, cfg: &MarkerConfig) -> Figures {
    let (mut within, mut total, mut secs) = (0, 0, 0.0);
    let (mut errs, mut dx, mut dy) = (vec![], vec![], vec![]);
    for stem in STEMS {
        let img = read_grey_image(dir.join(format!("{stem}.jpg"))).unwrap();
        // Warm up the detector's per-thread decode table, as a long run would have.
        detect_markers(&img, cfg).unwrap();
        let t0 = Instant::now();
        let found = detect_markers(&img, cfg).unwrap();
        secs += t0.elapsed().as_secs_f64();
        for (id, r) in reference(&dir.join(format!("{stem}.txt"))) {
            total += 1;
            let Some((m, e)) = nearest(&found, id, &r) else {
                continue;
            };
            let worst = e.iter().cloned().fold(0.0, f64::max);
            if worst <= 1.5 {
                within += 1;
            }
            if worst <= 5.0 {
                errs.extend(e);
                let c = m.canonical_corners();
                for k in 0..4 {
                    dx.push(c[k].x - r[k].x);
                    dy.push(c[k].y - r[k].y);
                }
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            f64::NAN
        } else {
            v[v.len() / 2]
        }
    };
    Figures {
        within,
        total,
        median: median(&mut errs),
        max: errs.iter().cloned().fold(0.0, f64::max),
        ms_per_image: secs / STEMS.len() as f64 * 1000.0,
        offset: (median(&mut dx), median(&mut dy)),
    }
}

fn print_row(name: &str, f: &Figures) {
    println!(
        "| {name:<44} | {:>2}/{} | {:>6.3} | {:>6.3} | {:>6.1} |",
        f.within, f.total, f.median, f.max, f.ms_per_image
    );
}

#[test]
fn regression_images_meet_the_requirement_and_the_detectors_compare() {
    let Some(dir) = common::data(DATA) else {
        return;
    };
    let auto = MarkerConfig::default();
    assert_eq!(auto.dictionary, MarkerDictionary::AprilTag36h11);
    println!("| detector | within 1.5 px | median px | max px | ms/image |");
    let a = measure(&dir, &auto);
    print_row("auto (= apriltag, refine_edges)", &a);
    assert_eq!(a.total, 47);
    assert!(
        a.within >= 45,
        "default detector: {}/47 tags with every corner within 1.5 px (need 45)",
        a.within
    );
    assert!(a.median < 0.5, "median corner error {} px", a.median);

    // OpenCV's ArUco detector on the same images, for the record (it is the default for ArUco only).
    let mut ocv = MarkerConfig {
        detector: MarkerDetector::OpenCv,
        ..MarkerConfig::default()
    };
    let o = measure(&dir, &ocv);
    print_row("opencv 4.6 aruco + edge fit (default)", &o);
    ocv.subpix.method = SubpixMethod::CornerSubPix;
    print_row("opencv 4.6 aruco + cornerSubPix", &measure(&dir, &ocv));
    ocv.subpix.opencv = false;
    print_row("opencv 4.6 aruco, no refinement", &measure(&dir, &ocv));
    ocv.opencv.corner_refinement = ArucoRefinement::Contour;
    let contour = measure(&dir, &ocv);
    print_row("opencv 4.6 aruco, CORNER_REFINE_CONTOUR", &contour);
    assert!(
        o.within < a.within,
        "OpenCV now finds {} tags, the default detector {}: revisit MarkerDetector::Auto",
        o.within,
        a.within
    );
    // AprilTag's half-pixel convention, measured against OpenCV's (least biased) corners: after the
    // conversion x − 0.5 the two agree to a small fraction of the half pixel.
    println!(
        "median offset OpenCV (contour) − AprilTag reference converted: ({:.3}, {:.3}) px",
        contour.offset.0, contour.offset.1
    );
    assert!(
        contour.offset.0.abs() < 0.2 && contour.offset.1.abs() < 0.2,
        "{:?}",
        contour.offset
    );
}

fn image(stem: &str) -> Option<PathBuf> {
    common::data(DATA).map(|d| d.join(format!("{stem}.jpg")))
}

#[test]
fn cli_json_and_annotation() {
    let Some(img) = image(STEMS[0]) else {
        return;
    };
    let out = common::scratch("markers-cli");
    let ann = out.join("annotated"); // created by the command
    let (code, stdout, stderr) = common::depthcal(&[
        "markers",
        img.to_str().unwrap(),
        "--json",
        "--annotate",
        ann.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(v["schema"], "depthcal.markers/1");
    common::assert_documented(&v);
    assert_eq!(v["dictionary"], "tag36h11");
    assert_eq!(v["detector"], "apriltag");
    assert_eq!(v["corner_order"], "apriltag");
    let images = v["images"].as_array().unwrap();
    assert_eq!(images.len(), 1);
    assert_eq!(images[0]["path"], img.to_str().unwrap());
    let markers = images[0]["markers"].as_array().unwrap();
    let expected = reference(&img.with_extension("txt"));
    assert!(
        markers.len() + 1 >= expected.len(),
        "{} markers",
        markers.len()
    );
    for m in markers {
        assert!(m["id"].is_u64(), "{m}");
        let c = m["corners_px"].as_array().unwrap();
        assert_eq!(c.len(), 4);
        for p in c {
            let p = p.as_array().unwrap();
            assert_eq!(p.len(), 2);
            assert!(p.iter().all(|x| x.as_f64().is_some_and(|x| x.is_finite())));
        }
    }
    // JSON corners are the library's, in the detector's order.
    let lib = detect_markers(&read_grey_image(&img).unwrap(), &MarkerConfig::default()).unwrap();
    assert_eq!(lib.len(), markers.len());
    let c0 = &markers[0]["corners_px"][0];
    assert!((c0[0].as_f64().unwrap() - lib[0].corners[0].x).abs() < 1e-3);
    assert!((c0[1].as_f64().unwrap() - lib[0].corners[0].y).abs() < 1e-3);
    let png = ann.join(format!("{}_markers.png", STEMS[0]));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let a = read_grey_image(&png).unwrap();
    let i = read_grey_image(&img).unwrap();
    assert_eq!((a.width, a.height), (i.width, i.height));
    assert_ne!(a.data, i.data, "nothing drawn");

    // Text output: one line per marker.
    let (code, stdout, stderr) = common::depthcal(&["markers", img.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(
        stdout
            .lines()
            .filter(|l| l.trim_start().starts_with("id "))
            .count(),
        markers.len(),
        "{stdout}"
    );
}

#[test]
fn cli_errors_name_the_file_and_write_nothing() {
    let dir = common::scratch("markers-cli-errors");
    let missing = dir.join("no-such-image.png");
    let ann = dir.join("ann");
    let (code, _, stderr) = common::depthcal(&[
        "markers",
        missing.to_str().unwrap(),
        "--annotate",
        ann.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(stderr.contains("no-such-image.png"), "{stderr}");
    assert!(!ann.exists(), "annotation folder created for a failed run");

    let garbage = dir.join("garbage.png");
    std::fs::write(&garbage, b"not an image").unwrap();
    let (code, _, stderr) = common::depthcal(&["markers", garbage.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(stderr.contains("garbage.png"), "{stderr}");

    let (code, _, stderr) = common::depthcal(&["markers", "x.png", "--dict", "9x9_50"]);
    assert_eq!(code, 2);
    assert!(
        stderr.contains("9x9_50") && stderr.contains("tag36h11"),
        "{stderr}"
    );

    // An annotation that would overwrite an input image is refused before anything is written.
    if let Some(img) = image(STEMS[2]) {
        let a = dir.join("a.jpg");
        let b = dir.join("a_markers.png");
        std::fs::copy(&img, &a).unwrap();
        std::fs::copy(&img, &b).unwrap();
        let before = common::listing(&dir);
        let (code, _, stderr) = common::depthcal(&[
            "markers",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--annotate",
            dir.to_str().unwrap(),
        ]);
        assert_eq!(code, 1);
        assert!(stderr.contains("would be overwritten"), "{stderr}");
        assert_eq!(common::listing(&dir), before);
    }
}

/// OpenCV's ChArUco tutorial photos (640×480, DICT_6X6_250, 17 markers of 20 mm per image, reference
/// intrinsics): every marker is found, and its corners fit a 20 mm square seen through the reference
/// camera (per-marker PnP residual; 2 degrees of freedom per marker, so it measures corner consistency,
/// not absolute accuracy).
#[test]
fn charuco_tutorial_markers_through_opencv() {
    let Some(dir) = common::data("opencv-charuco-tutorial") else {
        return;
    };
    let intr = Intrinsics {
        model: DistortionModel::BrownConrady,
        coeffs: [0.121369, -1.085466, 0.000118, -0.000462, 2.954259],
        ..Intrinsics::pinhole(640, 480, 452.5107, 456.7671, 317.7030, 277.7516)
    };
    let base = MarkerConfig {
        dictionary: "DICT_6X6_250".parse().unwrap(),
        ..MarkerConfig::default()
    };
    let mut variants = vec![("edge fit (default)", base.clone())];
    let mut c = base.clone();
    c.subpix.method = SubpixMethod::CornerSubPix;
    variants.push(("cornerSubPix", c));
    let mut c = base.clone();
    c.subpix.opencv = false;
    variants.push(("none", c));
    let mut c = base.clone();
    c.subpix.opencv = false;
    c.opencv.corner_refinement = ArucoRefinement::Contour;
    variants.push(("CORNER_REFINE_CONTOUR", c));
    let mut medians = vec![];
    for (name, cfg) in &variants {
        let (mut res, mut count) = (vec![], 0);
        for k in 0..4 {
            let img = read_grey_image(dir.join(format!("img_0{k}.jpg"))).unwrap();
            let found = detect_markers(&img, cfg).unwrap();
            let mut ids: Vec<u32> = found.iter().map(|m| m.id).collect();
            ids.dedup();
            // OpenCV 4.6 with default parameters misses marker 0 in img_02 (OpenCV 5's ChArUco detector
            // recovers it from the board layout).
            assert!(
                ids.len() == found.len() && ids.len() >= 16 && ids.iter().all(|&i| i < 17),
                "img_0{k} {name}: {ids:?}"
            );
            count += found.len();
            for m in &found {
                let p = pose_of_points(&m.corners, &m.object_corners(0.02), &intr).unwrap();
                res.push(p.rms_px);
            }
        }
        res.sort_by(f64::total_cmp);
        let med = res[res.len() / 2];
        println!(
            "charuco {name:<24} {count}/68 markers, per-marker PnP RMS: median {med:.3} px, max {:.3} px",
            res.last().unwrap()
        );
        assert!(count >= 67, "{name}: {count}/68");
        medians.push(med);
    }
    // The edge fit (default) makes the corners more consistent than cornerSubPix (0.084 vs 0.153 px
    // measured) or none.
    assert!(
        medians[0] < 0.12 && medians[0] < medians[1] && medians[0] < medians[2],
        "{medians:?}"
    );
}
