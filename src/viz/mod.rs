//! The visual report of `calibrate`, `register` and `compare` (`--report DIR`): a self-contained
//! `report.html` (an interactive 3-D view of the clouds, the residual map and histogram, per-frame
//! consistency, ICP convergence, the transform in every format, the verdict) and PNG snapshots of the same
//! views rendered here in Rust (`overview.png`, `initial.png`, `residual.png`).
//!
//! The pages are built from the library's results: [`calibration_report`] from a
//! [`Calibration`](crate::calibration::robot_to_robot::Calibration) and the fused clouds it registered,
//! [`registration_report`] from a [`Registration`](crate::registration::Registration) and its two clouds,
//! [`comparison_report`] from the methods of `compare`, [`robots_report`] from the joint solution of a cell
//! of three or more robots. Frames: the reference robot's base (calibration) or
//! the target's frame (registration); residuals in mm for cells (metres), in cloud units for `register`.
//! Output is deterministic for the same result (the stage timings shown are the result's own).
//! See `docs/report.md`.

mod calibration;
mod comparison;
mod font;
pub mod page;
mod registration;
pub mod render;
pub mod residual;
mod robots;
pub mod scene;
mod sections;
mod svg;

pub use calibration::calibration_report;
pub use comparison::{comparison_report, MethodRun};
pub use registration::registration_report;
pub use robots::robots_report;

use crate::camera::{write_rgb_png, RgbImage};
use crate::error::{Error, Result};
use crate::index::KdIndex;
use nalgebra::Isometry3;
use render::{Canvas, Colouring};
use residual::{nice_ceiling, point_to_plane, Histogram, ResidualStats};
use scene::{Item, PointSet, Residuals, Scene, Shape, MAX_POINTS};
use std::path::Path;

/// The page's file name in the report directory.
pub const REPORT_FILE: &str = "report.html";
/// The snapshot of the final result.
pub const OVERVIEW_FILE: &str = "overview.png";
/// The snapshot of the initial estimate.
pub const INITIAL_FILE: &str = "initial.png";
/// The snapshot of the residual colouring.
pub const RESIDUAL_FILE: &str = "residual.png";
/// Every file a report directory holds.
pub const REPORT_FILES: [&str; 4] = [REPORT_FILE, OVERVIEW_FILE, INITIAL_FILE, RESIDUAL_FILE];
/// Size of the PNG snapshots, pixels.
pub const SNAPSHOT_SIZE: (u32, u32) = (1024, 768);
/// Bins of the residual histograms over the colour scale.
const HISTOGRAM_BINS: usize = 40;

/// One PNG snapshot.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// Its file name in the report directory.
    pub file: &'static str,
    /// The picture.
    pub image: RgbImage,
    /// Points that fell inside the picture.
    pub points_drawn: usize,
}

/// A report ready to be written.
#[derive(Clone, Debug)]
pub struct Report {
    /// The page.
    pub html: String,
    /// The snapshots ([`OVERVIEW_FILE`], [`INITIAL_FILE`], [`RESIDUAL_FILE`]).
    pub snapshots: Vec<Snapshot>,
    /// Points embedded in the page over all point sets.
    pub embedded_points: usize,
    /// Points the page's view shows when it opens.
    pub visible_points: usize,
}

impl Report {
    /// Writes the page and the snapshots into `dir` (created when missing; its parent must exist), each
    /// file atomically.
    pub fn write(&self, dir: &Path) -> Result<()> {
        if !dir.exists() {
            std::fs::create_dir(dir).map_err(|e| Error::io(dir, e))?;
        } else if !dir.is_dir() {
            return Err(Error::InvalidInput(format!(
                "{}: exists and is not a directory",
                dir.display()
            )));
        }
        crate::io::write_atomically(&dir.join(REPORT_FILE), |w| {
            w.write_all(self.html.as_bytes())
        })?;
        for s in &self.snapshots {
            write_rgb_png(dir.join(s.file), &s.image)?;
        }
        Ok(())
    }
}

/// Where a cloud is placed in a report's scene.
#[derive(Clone, Debug)]
struct Placement {
    name: String,
    transform: Isometry3<f64>,
    rgb: [u8; 3],
    visible: bool,
    views: Vec<&'static str>,
    /// Compute its residuals against the reference.
    residual: bool,
}

/// A reference cloud and another cloud under several placements: what every report shows.
struct TwoClouds<'a> {
    reference_name: String,
    reference: &'a [[f32; 3]],
    other_name: String,
    other: &'a [[f32; 3]],
    placements: Vec<Placement>,
    /// Display units per cloud unit (1000 for metres shown in mm).
    scale: f64,
    unit: &'a str,
    /// Beyond this distance (cloud units) a point has no counterpart.
    reach: f64,
}

/// The residuals of one placement: its name, statistics and histogram (display units).
struct PlacementResidual {
    name: String,
    stats: ResidualStats,
    histogram: Histogram,
}

impl TwoClouds<'_> {
    /// The scene (both clouds subsampled to [`MAX_POINTS`] together, the reference item first, then one
    /// item per placement) and the residuals of the placements that ask for them, the first setting the
    /// colour scale (the nice ceiling of its 90th percentile: the few points on edges seen by one side
    /// only would otherwise stretch the scale over the residuals of the shared surfaces).
    fn scene(&self) -> (Scene, Vec<PlacementResidual>) {
        let mut sc = Scene::new(self.unit);
        let (nr, no) = (self.reference.len(), self.other.len());
        let half = MAX_POINTS / 2;
        let max_r = half.max(MAX_POINTS.saturating_sub(no));
        let max_o = half.max(MAX_POINTS.saturating_sub(nr));
        let rs = sc.add_set(PointSet::subsampled(
            &self.reference_name,
            self.reference,
            max_r,
        ));
        let os = sc.add_set(PointSet::subsampled(&self.other_name, self.other, max_o));
        sc.items.push(Item {
            name: self.reference_name.clone(),
            shape: Shape::Points {
                set: rs,
                residual: None,
            },
            transform: Isometry3::identity(),
            rgb: scene::PALETTE[0],
            visible: true,
            views: vec!["refined", "initial"],
        });
        let finite: Vec<[f32; 3]> = self
            .reference
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .copied()
            .collect();
        let index = KdIndex::new(&finite);
        let mut out = Vec::new();
        for p in &self.placements {
            let residual = (p.residual && !finite.is_empty() && !sc.sets[os].points.is_empty())
                .then(|| {
                    let values = point_to_plane(
                        &sc.sets[os].points,
                        &p.transform,
                        &finite,
                        &index,
                        self.reach,
                        self.scale,
                    );
                    sc.residuals.push(Residuals {
                        name: p.name.clone(),
                        values,
                    });
                    sc.residuals.len() - 1
                });
            sc.items.push(Item {
                name: p.name.clone(),
                shape: Shape::Points { set: os, residual },
                transform: p.transform,
                rgb: p.rgb,
                visible: p.visible,
                views: p.views.clone(),
            });
        }
        if let Some(first) = sc.residuals.first() {
            sc.residual_max = nice_ceiling(ResidualStats::new(&first.values).p90);
        }
        for r in &sc.residuals {
            out.push(PlacementResidual {
                name: r.name.clone(),
                stats: ResidualStats::new(&r.values),
                histogram: Histogram::new(&r.values, sc.residual_max, HISTOGRAM_BINS),
            });
        }
        (sc, out)
    }
}

/// The three snapshots of a scene whose camera is fitted: the `refined` items ([`OVERVIEW_FILE`]), the
/// `initial` items ([`INITIAL_FILE`]) and the `refined` items in residual colours ([`RESIDUAL_FILE`]), each
/// labelled with `heading`, the names of its clouds in their colours, and NOT TRUSTED when not `trusted`.
fn snapshots(sc: &Scene, heading: &str, trusted: bool) -> Vec<Snapshot> {
    let (w, h) = SNAPSHOT_SIZE;
    let shots = [
        (OVERVIEW_FILE, "refined", Colouring::ByItem, "RESULT"),
        (
            INITIAL_FILE,
            "initial",
            Colouring::ByItem,
            "INITIAL ESTIMATE",
        ),
        (RESIDUAL_FILE, "refined", Colouring::Residual, "RESIDUAL"),
    ];
    shots
        .into_iter()
        .map(|(file, view, colouring, what)| {
            let mut c = Canvas::new(w, h);
            let drawn = render::draw_scene(&mut c, sc, view, colouring);
            let fg = [235, 235, 235];
            c.text(&format!("{heading}: {what}"), 16, 14, 2, fg);
            let mut y = 40;
            for it in sc.items.iter().filter(|i| i.views.contains(&view)) {
                if let Shape::Points { set, residual } = &it.shape {
                    let rgb = match colouring {
                        Colouring::ByItem => it.rgb,
                        Colouring::Residual if residual.is_some() => render::colormap(0.6),
                        Colouring::Residual => render::REFERENCE_GREY,
                    };
                    c.rect(16, y, 14, 14, rgb);
                    let n = sc.sets[*set].points.len();
                    c.text(&format!("{} ({n} POINTS)", it.name), 38, y, 2, fg);
                    y += 22;
                }
            }
            if !trusted {
                let t = "NOT TRUSTED";
                let tw = font::text_width(t, 4) as i64;
                c.text(t, w as i64 - tw - 16, 14, 4, [255, 70, 70]);
            }
            if colouring == Colouring::Residual {
                if sc.residuals.is_empty() {
                    c.text(
                        "NO RESIDUALS: NO CLOUDS TO COMPARE",
                        16,
                        h as i64 - 40,
                        2,
                        fg,
                    );
                } else {
                    c.colour_bar(
                        16,
                        h as i64 - 74,
                        320,
                        16,
                        sc.residual_max,
                        &sc.residual_unit,
                    );
                }
            }
            Snapshot {
                file,
                image: c.image,
                points_drawn: drawn,
            }
        })
        .collect()
}

/// The finished report from its scene, page body and data.
fn finish(
    sc: &Scene,
    title: &str,
    body: &str,
    mut data: serde_json::Value,
    heading: &str,
    trusted: bool,
) -> Report {
    data["scene"] = page::scene_json(sc);
    Report {
        html: page::document(title, body, &data),
        snapshots: snapshots(sc, heading, trusted),
        embedded_points: sc.sets.iter().map(|s| s.points.len()).sum(),
        visible_points: sc.visible_point_count(),
    }
}
