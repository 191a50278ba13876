//! `--report DIR` of calibrate, register and compare: builds the visual report in the library
//! ([`depthcal::viz`]) and writes it, saying so on stderr.

use anyhow::{Context, Result};
use std::path::Path;
use std::time::Instant;

/// Builds the report with `build` and writes it into `dir`; `trusted` adds a reminder when it is not.
pub fn write(
    dir: &Path,
    trusted: bool,
    build: impl FnOnce() -> depthcal::Result<depthcal::viz::Report>,
) -> Result<()> {
    let t0 = Instant::now();
    let report = build().context("building the report")?;
    report
        .write(dir)
        .with_context(|| format!("writing the report into {}", dir.display()))?;
    eprintln!(
        "wrote {} ({:.0} kB, {} points; snapshots {}) in {:.2} s{}",
        dir.join(depthcal::viz::REPORT_FILE).display(),
        report.html.len() as f64 / 1e3,
        report.embedded_points,
        report
            .snapshots
            .iter()
            .map(|s| s.file)
            .collect::<Vec<_>>()
            .join(", "),
        t0.elapsed().as_secs_f64(),
        if trusted {
            ""
        } else {
            "; the result is NOT trusted, and the report says why"
        }
    );
    Ok(())
}
