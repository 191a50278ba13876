//! `depthcal match IMAGE1 IMAGE2`: keypoint matches between two images and the homography mapping
//! IMAGE1 pixels to IMAGE2 pixels (needs the `vision` feature).

use clap::{Args as ClapArgs, ValueEnum};
use std::path::PathBuf;

/// The keypoint detector on the command line.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Detector {
    /// SIFT: float descriptors (L2), the most repeatable.
    Sift,
    /// ORB: binary descriptors (Hamming), the fastest.
    Orb,
    /// AKAZE: binary descriptors (Hamming).
    Akaze,
}

/// Arguments of `depthcal match`.
///
/// When no homography fits (too few matches or inliers) the command still succeeds: it says so, and the
/// JSON has `"homography": null` and `"inliers": 0`.
#[derive(ClapArgs)]
pub struct Args {
    /// The first image (PNG, JPEG, ...; colour is converted to grey).
    pub image1: PathBuf,
    /// The second image.
    pub image2: PathBuf,
    /// Keypoint detector and descriptor.
    #[arg(long, value_enum, default_value_t = Detector::Sift)]
    pub detector: Detector,
    /// Lowe ratio test: keep a match closer than R times the second-nearest descriptor, in (0, 1].
    #[arg(long, value_name = "R", default_value_t = 0.8)]
    pub ratio: f64,
    /// Strongest keypoints kept per image (0 = all).
    #[arg(long, value_name = "N", default_value_t = 2000)]
    pub max_features: usize,
    /// Keep matches that are not mutual best matches too.
    #[arg(long)]
    pub no_cross_check: bool,
    /// Inlier threshold of the homography: transfer error in IMAGE2, pixels.
    #[arg(long, value_name = "PX", default_value_t = 3.0)]
    pub threshold: f64,
    /// Print one JSON object on stdout (schema `depthcal.match/1`): {"matches", "inliers", "homography"
    /// (3x3, h22 = 1, or null), "pairs": [{"p1_px", "p2_px", "distance", "inlier"}], ...}.
    #[arg(long)]
    pub json: bool,
    /// Write the two images side by side with the matches (inliers green, outliers red) to this PNG.
    #[arg(long, value_name = "OUT.png")]
    pub annotate: Option<PathBuf>,
}

/// Runs `depthcal match`.
#[cfg(not(feature = "vision"))]
pub fn run(a: Args) -> anyhow::Result<()> {
    let _ = (
        &a.image1,
        &a.image2,
        a.detector,
        a.ratio,
        a.max_features,
        a.no_cross_check,
        a.threshold,
        a.json,
        a.annotate,
    );
    anyhow::bail!("depthcal match: {}", super::vision_args::WITHOUT_VISION)
}

/// Runs `depthcal match`.
#[cfg(feature = "vision")]
pub fn run(a: Args) -> anyhow::Result<()> {
    use depthcal::vision::features::{
        detect_features, draw_matches, fit_homography, match_features, FeatureConfig, FeatureKind,
        HomographyConfig,
    };
    use depthcal::vision::read_grey_image;
    let kind = match a.detector {
        Detector::Sift => FeatureKind::Sift,
        Detector::Orb => FeatureKind::Orb,
        Detector::Akaze => FeatureKind::Akaze,
    };
    let cfg = FeatureConfig {
        kind,
        max_features: a.max_features,
        ratio: a.ratio,
        cross_check: !a.no_cross_check,
        ..Default::default()
    };
    cfg.validate()?;
    let hcfg = HomographyConfig {
        threshold_px: a.threshold,
        ..Default::default()
    };
    hcfg.validate()?;
    if let Some(out) = &a.annotate {
        check_annotate_path(out, &[&a.image1, &a.image2])?;
    }
    let img1 = read_grey_image(&a.image1)?;
    let img2 = read_grey_image(&a.image2)?;
    let f1 = detect_features(&img1, &cfg)?;
    let f2 = detect_features(&img2, &cfg)?;
    let matches = match_features(&f1, &f2, &cfg)?;
    let pairs: Vec<_> = matches
        .iter()
        .map(|m| (f1.keypoints[m.query].pt, f2.keypoints[m.train].pt))
        .collect();
    let (p1, p2): (Vec<_>, Vec<_>) = pairs.iter().copied().unzip();
    let fit = fit_homography(&p1, &p2, &hcfg)?;
    let inliers = fit
        .as_ref()
        .map_or_else(|| vec![false; pairs.len()], |h| h.inliers.clone());
    let n_in = inliers.iter().filter(|&&b| b).count();
    if let Some(out) = &a.annotate {
        let picture = draw_matches(&img1, &img2, &pairs, &inliers)?;
        depthcal::sim::write_rgb_png(out, &picture)?;
        eprintln!("wrote {}", out.display());
    }
    if a.json {
        let v = depthcal::report::MatchReport::new(
            (a.image1.as_path(), a.image2.as_path()),
            (&f1, &f2),
            &matches,
            fit.as_ref(),
            &cfg,
            &hcfg,
        )?;
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "{}: {} {kind} keypoints; {}: {} keypoints",
        a.image1.display(),
        f1.len(),
        a.image2.display(),
        f2.len()
    );
    println!(
        "{} matches (ratio {}, cross-check {}), {n_in} inliers within {} px",
        matches.len(),
        cfg.ratio,
        if cfg.cross_check { "on" } else { "off" },
        hcfg.threshold_px
    );
    match &fit {
        Some(h) => {
            println!("homography (IMAGE1 pixels to IMAGE2 pixels, h22 = 1):");
            for r in 0..3 {
                println!(
                    "  {:>16.9e} {:>16.9e} {:>16.9e}",
                    h.h[(r, 0)],
                    h.h[(r, 1)],
                    h.h[(r, 2)]
                );
            }
        }
        None => println!(
            "no homography: fewer than {} of the {} matches agree on one",
            hcfg.min_inliers,
            matches.len()
        ),
    }
    println!();
    println!(
        "{:>10} {:>10} {:>10} {:>10} {:>10}  inlier",
        "x1", "y1", "x2", "y2", "distance"
    );
    for ((m, (p, q)), inl) in matches.iter().zip(&pairs).zip(&inliers) {
        println!(
            "{:>10.2} {:>10.2} {:>10.2} {:>10.2} {:>10.2}  {}",
            p.x,
            p.y,
            q.x,
            q.y,
            m.distance,
            if *inl { "yes" } else { "no" }
        );
    }
    Ok(())
}

/// Refuses an annotation file that is one of the input images or not a `.png`.
#[cfg(feature = "vision")]
fn check_annotate_path(out: &std::path::Path, inputs: &[&PathBuf]) -> anyhow::Result<()> {
    let png = out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        anyhow::bail!(
            "--annotate {}: the match image is written as PNG; give a .png file name",
            out.display()
        );
    }
    let same = |a: &std::path::Path, b: &std::path::Path| match (a.canonicalize(), b.canonicalize())
    {
        (Ok(x), Ok(y)) => x == y,
        _ => a == b,
    };
    for i in inputs {
        if same(out, i) {
            anyhow::bail!(
                "--annotate {}: refusing to overwrite the input image",
                out.display()
            );
        }
    }
    Ok(())
}
