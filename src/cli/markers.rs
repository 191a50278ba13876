//! `depthcal markers IMAGE... [--dict NAME] [--json] [--annotate DIR]`: square fiducial markers (ArUco,
//! AprilTag) in images, with sub-pixel corners (needs the `vision` feature).

use clap::Args as ClapArgs;
use depthcal::cell::MarkerDictionary;
use std::path::PathBuf;

/// Arguments of `depthcal markers`.
#[derive(ClapArgs)]
pub struct Args {
    /// Images to search (PNG, JPEG, ...).
    #[arg(required = true, num_args = 1..)]
    pub images: Vec<PathBuf>,
    /// Marker dictionary: tag36h11 (default), tag25h9, tag16h5, tag36h10, or an OpenCV ArUco dictionary
    /// such as DICT_4X4_50, 6x6_250, DICT_ARUCO_ORIGINAL (case does not matter).
    #[arg(long, value_name = "NAME")]
    pub dict: Option<MarkerDictionary>,
    /// Detector: auto (default: AprilTag's for AprilTag families, OpenCV's for ArUco), opencv, apriltag.
    #[arg(long, value_name = "NAME")]
    pub detector: Option<String>,
    /// JSON file with any fields of MarkerConfig (see src/vision/markers.rs); the flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print one JSON object on stdout (schema `depthcal.markers/1`): {"images": [{"path", "markers":
    /// [{"id", "corners_px"}]}], ...}.
    #[arg(long)]
    pub json: bool,
    /// Write DIR/<image stem>_markers.png for each image, with the outlines, corner 0 and ids drawn
    /// (DIR is created if missing).
    #[arg(long, value_name = "DIR")]
    pub annotate: Option<PathBuf>,
}

/// Runs `depthcal markers`.
#[cfg(not(feature = "vision"))]
pub fn run(a: Args) -> anyhow::Result<()> {
    let _ = (
        &a.images,
        a.dict,
        &a.detector,
        &a.config,
        a.json,
        &a.annotate,
    );
    anyhow::bail!("depthcal markers: {}", super::vision_args::WITHOUT_VISION)
}

/// The annotation file of each image: `dir/<stem>_markers.png`; errors when two images would share one
/// or when one would overwrite an input image.
#[cfg(feature = "vision")]
fn annotation_paths(images: &[PathBuf], dir: &std::path::Path) -> anyhow::Result<Vec<PathBuf>> {
    let inputs: Vec<PathBuf> = images
        .iter()
        .map(|p| p.canonicalize().unwrap_or_else(|_| p.clone()))
        .collect();
    let dir_abs = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    let mut out: Vec<PathBuf> = Vec::with_capacity(images.len());
    for (img, input) in images.iter().zip(&inputs) {
        let stem = img
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "image".into());
        let name = format!("{stem}_markers.png");
        let path = dir.join(&name);
        if let Some(k) = out.iter().position(|o| *o == path) {
            anyhow::bail!(
                "--annotate: {} and {} would both be annotated as {}; rename one or annotate them \
                 separately",
                images[k].display(),
                img.display(),
                path.display()
            );
        }
        if inputs.contains(&dir_abs.join(&name)) || inputs.contains(&path) || path == *input {
            anyhow::bail!(
                "--annotate: {} is an input image and would be overwritten; choose another DIR",
                path.display()
            );
        }
        out.push(path);
    }
    Ok(out)
}

/// Runs `depthcal markers`.
#[cfg(feature = "vision")]
pub fn run(a: Args) -> anyhow::Result<()> {
    use anyhow::Context;
    use depthcal::report::{MarkerImageReport, MarkersReport};
    use depthcal::vision::markers::{detect_markers, CornerOrder, MarkerConfig};
    use depthcal::vision::{read_grey_image, write_marker_annotation};
    let mut cfg: MarkerConfig =
        super::output::read_config(a.config.as_deref(), "marker configuration")?;
    if let Some(d) = a.dict {
        cfg.dictionary = d;
    }
    if let Some(d) = &a.detector {
        cfg.detector = d.parse()?;
    }
    cfg.validate().with_context(|| {
        super::output::config_source(a.config.as_deref(), "the marker configuration")
    })?;
    // Every image must exist before anything is written.
    for p in &a.images {
        if !p.is_file() {
            anyhow::bail!("{}: no such image file", p.display());
        }
    }
    let annotations = match &a.annotate {
        Some(dir) => {
            let paths = annotation_paths(&a.images, dir)?;
            std::fs::create_dir_all(dir)
                .with_context(|| format!("--annotate: cannot create {}", dir.display()))?;
            Some(paths)
        }
        None => None,
    };
    let detector = cfg.detector.resolve(cfg.dictionary);
    let mut images = Vec::with_capacity(a.images.len());
    for (k, path) in a.images.iter().enumerate() {
        let img = read_grey_image(path)?;
        let found = detect_markers(&img, &cfg)
            .with_context(|| format!("{}: marker detection failed", path.display()))?;
        if let Some(paths) = &annotations {
            write_marker_annotation(&img, &found, &paths[k])?;
            eprintln!("wrote {}", paths[k].display());
        }
        if a.json {
            images.push(MarkerImageReport::new(path, &img, &found));
            continue;
        }
        println!(
            "{}: {} marker{} ({}, {} detector)",
            path.display(),
            found.len(),
            if found.len() == 1 { "" } else { "s" },
            cfg.dictionary,
            detector
        );
        for m in &found {
            let c: Vec<String> = m
                .corners
                .iter()
                .map(|p| format!("({:.3}, {:.3})", p.x, p.y))
                .collect();
            println!("  id {:>4}  {}", m.id, c.join(" "));
        }
    }
    if a.json {
        let v = MarkersReport::new(&cfg, images);
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!(
            "corners: pixels, (0, 0) = centre of the top-left pixel, in the {detector} detector's order \
             ({})",
            if cfg.detector.corner_order(cfg.dictionary) == CornerOrder::AprilTag {
                "apriltag: top-right, top-left, bottom-left, bottom-right of the marker as OpenCV draws it"
            } else {
                "opencv: top-left, top-right, bottom-right, bottom-left as printed"
            }
        );
    }
    Ok(())
}
