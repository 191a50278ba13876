//! `depthcal intrinsics IMAGES... --board COLSxROWS --square SIZE` (or `--charuco SQUARES_XxSQUARES_Y
//! --square SIZE --charuco-marker SIZE --charuco-dict NAME`): camera intrinsics from checkerboard or
//! ChArUco images (needs the `vision` feature).

use super::vision_args::BoardArgs;
use clap::Args as ClapArgs;
use std::path::PathBuf;

/// Arguments of `depthcal intrinsics`.
#[derive(ClapArgs)]
pub struct Args {
    /// Images of the board from one camera (PNG, JPEG, ...), one view each (a ChArUco board may be partly
    /// in view).
    #[arg(required = true, num_args = 1..)]
    pub images: Vec<PathBuf>,
    #[command(flatten)]
    pub board: BoardArgs,
    /// Keep fx/fy = 1 (square pixels; OpenCV CALIB_FIX_ASPECT_RATIO).
    #[arg(long)]
    pub fix_aspect_ratio: bool,
    /// Do not estimate k3 (k3 = 0; for narrow lenses or few views).
    #[arg(long)]
    pub no_k3: bool,
    /// Do not estimate the tangential terms (p1 = p2 = 0).
    #[arg(long)]
    pub no_tangential: bool,
    /// Keep the principal point at the image centre.
    #[arg(long)]
    pub fix_principal_point: bool,
    /// cornerSubPix half window, pixels (default: checkerboard 40% of the corner spacing, ChArUco 80% of
    /// the gap to the markers; at most 11).
    #[arg(long, value_name = "PX")]
    pub subpix_window: Option<u32>,
    /// Also try OpenCV's sector-based detector where the classic one fails.
    #[arg(long)]
    pub sector_based: bool,
    /// JSON file with any fields of IntrinsicsConfig (see src/vision/intrinsics.rs); the flags override it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write the intrinsics JSON (the cell dataset's format) to this file.
    #[arg(long, short)]
    pub output: Option<PathBuf>,
    /// Print one JSON object on stdout: the intrinsics fields plus per-view residuals and rejected images.
    #[arg(long)]
    pub json: bool,
}

/// Runs `depthcal intrinsics`.
#[cfg(not(feature = "vision"))]
pub fn run(a: Args) -> anyhow::Result<()> {
    let _ = (&a.images, &a.board, a.output, a.config);
    anyhow::bail!(
        "depthcal intrinsics: {}",
        super::vision_args::WITHOUT_VISION
    )
}

/// Runs `depthcal intrinsics`.
#[cfg(feature = "vision")]
pub fn run(a: Args) -> anyhow::Result<()> {
    use anyhow::Context;
    use depthcal::vision::intrinsics::{calibrate_intrinsics, IntrinsicsConfig};
    let board = a.board.board()?;
    if let Some(out) = &a.output {
        super::guard::check_output_file("--output", out, &["json"])?;
        let mut inputs = super::guard::Inputs::default();
        for i in &a.images {
            inputs.add("an input image", i);
        }
        inputs.add_opt("--config", a.config.as_ref());
        inputs.check_output("--output", out)?;
    }
    let mut cfg: IntrinsicsConfig =
        super::output::read_config(a.config.as_deref(), "intrinsics configuration")?;
    cfg.fix_aspect_ratio |= a.fix_aspect_ratio;
    cfg.estimate_k3 &= !a.no_k3;
    cfg.estimate_tangential &= !a.no_tangential;
    cfg.fix_principal_point |= a.fix_principal_point;
    if a.subpix_window.is_some() {
        cfg.corners.subpix_half_window_px = a.subpix_window;
        cfg.charuco.subpix_half_window_px = a.subpix_window;
    }
    cfg.corners.sector_based_fallback |= a.sector_based;
    cfg.validate().with_context(|| {
        super::output::config_source(a.config.as_deref(), "the intrinsics configuration")
    })?;
    let c = calibrate_intrinsics(&a.images, &board, &cfg)?;
    for (name, why) in &c.rejected {
        eprintln!("warning: {name} rejected: {why}");
    }
    if let Some(p) = &a.output {
        c.intrinsics.write_json_file(p)?;
        eprintln!("wrote {}", p.display());
    }
    let i = &c.intrinsics;
    if a.json {
        let out = depthcal::report::IntrinsicsReport::new(&c, &board, &cfg)?;
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "intrinsics from {} of {} images ({board}): RMS reprojection error {:.4} px",
        c.views.len(),
        a.images.len(),
        c.rms_px
    );
    println!(
        "  {}x{}  fx {:.3} ± {:.3}  fy {:.3} ± {:.3}  ppx {:.3} ± {:.3}  ppy {:.3} ± {:.3} px",
        i.width, i.height, i.fx, c.sigma[0], i.fy, c.sigma[1], i.ppx, c.sigma[2], i.ppy, c.sigma[3]
    );
    println!(
        "  {} k1 {:.6} k2 {:.6} p1 {:.6} p2 {:.6} k3 {:.6}",
        i.model, i.coeffs[0], i.coeffs[1], i.coeffs[2], i.coeffs[3], i.coeffs[4]
    );
    println!();
    println!(
        "{:<48} {:>10} {:>10} {:>8}",
        "view", "RMS [px]", "max [px]", "corners"
    );
    for v in &c.views {
        println!(
            "{:<48} {:>10.4} {:>10.4} {:>8}",
            v.name, v.rms_px, v.max_px, v.corners
        );
    }
    for (n, r) in &c.rejected {
        println!("{n:<48} REJECTED: {r}");
    }
    Ok(())
}
