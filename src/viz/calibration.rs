//! The report of `calibrate`: both robots' fused clouds in the reference base, before and after
//! refinement, with the bases and the cameras; the residual; each robot's consistency; ICP convergence; the
//! transform in every format; quality and verdict.

use super::page::{banner, details, esc, list, num, section, table, viewer};
use super::scene::{frustum, triad, Item, Segment, FLAGGED, PALETTE};
use super::sections::{
    consistency_section, convergence_section, degeneracy_cell, hand_eye_check_section, lines_item,
    log_section, matrix_block, matrix_table, pose_formats, residual_section, sigma, three,
    transform_file_blocks, yes_no,
};
use super::{finish, Placement, Report, TwoClouds};
use crate::calibration::consistency::RobotConsistency;
use crate::calibration::robot_to_robot::{Calibration, FusedCell};
use crate::cell::{Cell, CellRobot};
use crate::error::Result;
use crate::geometry::robot_formats::Frames;
use crate::report::{PoseReport, SigmaReport};
use nalgebra::Isometry3;
use serde_json::json;

/// Length of the base triads for a scene of `extent` (bounding-box diagonal, metres): 12% of it, within
/// 5 cm and 50 cm.
pub(super) fn triad_length(extent: f64) -> f64 {
    if extent.is_finite() && extent > 0.0 {
        (0.12 * extent).clamp(0.05, 0.5)
    } else {
        0.2
    }
}

/// A robot's base triad and its cameras' frusta (in its base frame); frames its own consistency check
/// flagged in red.
pub(super) fn base_and_cameras(
    robot: &CellRobot,
    consistency: Option<&RobotConsistency>,
    length: f64,
    rgb: [u8; 3],
) -> Vec<Segment> {
    let mut s = triad(length);
    for (i, f) in robot.frames.iter().enumerate() {
        let flagged = consistency
            .and_then(|c| c.frames.iter().find(|x| x.id == f.id))
            .is_some_and(|x| !x.consistent);
        s.extend(frustum(
            &robot.t_base_cam(i),
            &robot.intrinsics,
            0.4 * length,
            if flagged { FLAGGED } else { rgb },
        ));
    }
    s
}

/// Where [`robot_lines`] draws the other robot's base and cameras.
pub(super) struct OtherAt {
    /// Appended to `<robot> base and cameras` in the item's name.
    pub suffix: String,
    /// `T_base1_base2` it is drawn under.
    pub transform: Isometry3<f64>,
    /// Shown when the page opens.
    pub visible: bool,
    /// The views that show it.
    pub views: Vec<&'static str>,
}

/// The line items of both robots' base triads and camera frusta: the reference robot's in place (every
/// view), then the other robot's under each of `other_at`. Triads are sized to the fused clouds; frames the
/// consistency check of `cal` flagged are red.
pub(super) fn robot_lines(
    (rr, or): (&CellRobot, &CellRobot),
    fused: &FusedCell,
    cal: Option<&Calibration>,
    other_at: Vec<OtherAt>,
) -> Vec<Item> {
    let len =
        triad_length(extent(&fused.reference.cloud.points).max(extent(&fused.other.cloud.points)));
    let cons = |name: &str| cal.and_then(|c| c.consistency.iter().find(|r| r.robot == name));
    let mut items = vec![lines_item(
        format!("{} base and cameras", rr.name),
        base_and_cameras(rr, cons(&rr.name), len, PALETTE[0]),
        Isometry3::identity(),
        true,
        vec!["refined", "initial"],
    )];
    let lines = base_and_cameras(or, cons(&or.name), len, PALETTE[1]);
    items.extend(other_at.into_iter().map(|at| {
        lines_item(
            format!("{} base and cameras{}", or.name, at.suffix),
            lines.clone(),
            at.transform,
            at.visible,
            at.views,
        )
    }));
    items
}

/// The diagonal of the bounding box of some points (0 for none).
pub(super) fn extent(points: &[[f32; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    let d: f64 = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    if d.is_finite() {
        d
    } else {
        0.0
    }
}

/// The distance beyond which a point of the other cloud has no counterpart: the finest ICP level's
/// correspondence distance, else three voxels of the reference's fusion (metres).
pub(super) fn reach(c: &Calibration, fused: &FusedCell) -> f64 {
    reach_with_voxel(c, fused.reference.stats.voxel_size_m)
}

/// [`reach`] given the reference's fusion voxel (metres).
pub(super) fn reach_with_voxel(c: &Calibration, voxel_m: f64) -> f64 {
    c.icp_levels
        .last()
        .map(|l| l.max_correspondence_distance)
        .unwrap_or(3.0 * voxel_m)
        .max(1e-6)
}

/// The key figures of a calibration as the page embeds them, with the names and forms of `--json`
/// ([`crate::report::CalibrationReport`]): `transform` (a [`PoseReport`]), `sigma` (`rotation_deg`,
/// `translation_m`), `fitness`, `inlier_rmse_m`, `overlap`, `converged`, `trusted`, `reasons`,
/// `suggestions`, `warnings`, `initial.transform`.
pub(super) fn summary(c: &Calibration) -> serde_json::Value {
    json!({
        "reference": c.reference,
        "other": c.other,
        "method": c.method,
        "refined": c.refined,
        "transform": PoseReport::new(&c.transform),
        "sigma": SigmaReport::from_covariance(&c.covariance),
        "fitness": c.fitness,
        "inlier_rmse_m": c.inlier_rmse,
        "overlap": c.overlap,
        "converged": c.converged,
        "degenerate": c.degeneracy.is_degenerate(),
        "trusted": c.trust.trusted,
        "reasons": c.trust.reasons,
        "suggestions": c.trust.suggestions,
        "warnings": c.warnings,
        "initial": {"transform": PoseReport::new(&c.initial.transform)},
        "fused_points": {"reference": c.fused_points[0], "other": c.fused_points[1]},
    })
}

/// The quality figures of a calibration as a table.
pub(super) fn quality_table(c: &Calibration) -> String {
    let mut rows = vec![];
    if c.refined {
        let opt =
            |x: Option<f64>, scale: f64, digits| x.map_or("-".into(), |v| num(v * scale, digits));
        rows.push(("fitness", opt(c.fitness, 1.0, 4)));
        rows.push(("inlier RMSE (mm)", opt(c.inlier_rmse, 1e3, 3)));
        rows.push(("overlap", opt(c.overlap, 1.0, 4)));
        rows.push(("converged", yes_no(c.converged)));
    } else {
        rows.push((
            "quality",
            "not refined (--no-refine): the initialiser's estimate and its 1-σ".into(),
        ));
    }
    rows.push(("degenerate", degeneracy_cell(&c.degeneracy)));
    if let Some(f) = &c.free_space {
        rows.push((
            "free space",
            format!(
                "{:.1}% of the surfaces violate the other robot's views (own frames {:.1}%, margin {:.0} mm)",
                f.violation * 1e2,
                f.own_violation * 1e2,
                f.margin_m * 1e3
            ),
        ));
    }
    if let Some(a) = &c.ambiguity {
        rows.push((
            "ambiguity",
            format!(
                "<span class=\"bad\">a runner-up {:.2}° / {:.1} mm away scores {:.0}% of the best</span>",
                a.rotation_deg,
                a.translation * 1e3,
                a.score_ratio * 1e2
            ),
        ));
    }
    rows.push((
        "priors",
        esc(&if c.priors_used.is_empty() {
            "none".to_string()
        } else {
            c.priors_used.join(", ")
        }),
    ));
    rows.push(("initial estimate", esc(&c.initial.detail)));
    let d = c.initial.transform.inverse() * c.transform;
    rows.push((
        "initial → final",
        format!(
            "moved {:.3}° / {:.2} mm (initial 1-σ {:.3}° / {:.2} mm)",
            d.rotation.angle().to_degrees(),
            d.translation.vector.norm() * 1e3,
            c.initial.sigma_rotation_deg,
            c.initial.sigma_translation_m * 1e3
        ),
    ));
    if let Some((r, t)) = c.error_vs_truth {
        rows.push((
            "error vs ground truth",
            format!("{r:.4}° / {:.3} mm", t * 1e3),
        ));
    }
    if let Some((r, t)) = c.initial_error_vs_truth {
        rows.push((
            "initial error vs ground truth",
            format!("{r:.4}° / {:.3} mm", t * 1e3),
        ));
    }
    if let Some(n) = &c.normalised_error {
        rows.push((
            "normalised error",
            format!(
                "rotation {:.2}, translation {:.2}, pose {:.2} (~1 when the 1-σ is honest)",
                n.rotation, n.translation, n.pose
            ),
        ));
    }
    rows.push((
        "frames / fused points",
        format!(
            "{}: {} / {}; {}: {} / {}",
            esc(&c.reference),
            c.frames[0],
            c.fused_points[0],
            esc(&c.other),
            c.frames[1],
            c.fused_points[1]
        ),
    ));
    table(&rows)
}

/// The report of a calibration: `fused` the clouds it registered (each in its own base frame; empty when
/// an image initialiser ran without refinement), `frames` the ROS frame ids of the transform files.
pub fn calibration_report(
    cell: &Cell,
    c: &Calibration,
    fused: &FusedCell,
    frames: &Frames,
) -> Result<Report> {
    let (rr, or) = cell.robot_pair()?;
    let other_at = |what: &str| format!("{} cloud, {what}", c.other);
    let mut placements = Vec::new();
    if c.refined {
        placements.push(Placement {
            name: other_at("refined"),
            transform: c.transform,
            rgb: PALETTE[1],
            visible: true,
            views: vec!["refined"],
            residual: true,
        });
    }
    placements.push(Placement {
        name: other_at(&format!("initial estimate ({})", c.method)),
        transform: c.initial.transform,
        rgb: if c.refined { PALETTE[2] } else { PALETTE[1] },
        visible: !c.refined,
        views: if c.refined {
            vec!["initial"]
        } else {
            vec!["refined", "initial"]
        },
        residual: true,
    });
    let two = TwoClouds {
        reference_name: format!("{} cloud (reference)", c.reference),
        reference: &fused.reference.cloud.points,
        other_name: format!("{} cloud", c.other),
        other: &fused.other.cloud.points,
        placements,
        scale: 1e3,
        unit: "mm",
        reach: reach(c, fused),
    };
    let (mut sc, residuals) = two.scene();
    let mut other_at = Vec::new();
    if c.refined {
        other_at.push(OtherAt {
            suffix: ", refined".into(),
            transform: c.transform,
            visible: true,
            views: vec!["refined"],
        });
    }
    other_at.push(OtherAt {
        suffix: ", initial estimate".into(),
        transform: c.initial.transform,
        visible: !c.refined,
        views: if c.refined {
            vec!["initial"]
        } else {
            vec!["refined", "initial"]
        },
    });
    sc.items
        .extend(robot_lines((rr, or), fused, Some(c), other_at));
    sc.fit_camera();

    let cell_name = cell
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| cell.dir.display().to_string());
    let (sr, st) = sigma(&c.covariance, 1e3);
    let verdict = banner(
        c.trust.trusted,
        &format!(
            "T_base1_base2 of {} in {} ({} method{}).",
            c.other,
            c.reference,
            c.method,
            if c.refined {
                ", refined"
            } else {
                ", not refined"
            }
        ),
        &c.trust.reasons,
        &c.trust.suggestions,
    );
    let result = format!(
        "<p><code>T_base1_base2</code> maps {o}'s base coordinates into {r}'s (the reference): \
         <code>p_{r} = T · p_{o}</code>; metres.</p>{}{}\
         <p>1-σ: rotation <span class=\"num\" id=\"sigma-rotation\">{}</span> °, translation \
         <span class=\"num\" id=\"sigma-translation\">{}</span> mm (about the reference base's x, y, z)</p>{}{}{}",
        matrix_table(&c.transform, "transform"),
        pose_formats(&c.transform),
        three(&sr, 4),
        three(&st, 3),
        details("the matrix as text (T_base1_base2.txt)", &matrix_block(&c.transform)),
        transform_file_blocks(&c.transform, frames),
        details(
            "the initial estimate",
            &format!(
                "{}<p>{}</p>",
                matrix_table(&c.initial.transform, "initial-transform"),
                esc(&c.initial.detail)
            )
        ),
        o = esc(&c.other),
        r = esc(&c.reference),
    );
    let (r, o) = (esc(&c.reference), esc(&c.other));
    let residual_entries: Vec<(String, &_, &_)> = residuals
        .iter()
        .map(|p| (p.name.clone(), &p.stats, &p.histogram))
        .collect();
    let body = format!(
        "<h1>depthcal calibrate: {cell}</h1><p class=\"sub\">cell {dir} · reference {r} · other {o} · method \
         {m}</p>{verdict}{}{}{}{}{}{}{}{}",
        section("result", "Result", &result),
        section("quality", "Quality", &quality_table(c)),
        section(
            "view",
            "3-D view (reference base frame, metres)",
            &format!(
                "<p>Both fused clouds in {r}'s base frame: {r} orange, {o} after refinement blue, {o} at the \
                 initial estimate purple (off at first). Triads: each base (x red, y green, z blue); frusta: \
                 every camera pose, in red when the robot's own consistency check flags the frame. Colour \
                 by residual shows the other cloud's distance to the reference surface.</p>{}",
                viewer(&sc)
            )
        ),
        section(
            "residual",
            "Residual of the other robot's surface",
            &residual_section(&residual_entries, "mm", two.reach * 1e3)
        ),
        section(
            "consistency",
            "Per-frame consistency",
            &consistency_section(&c.consistency)
        ),
        section(
            "hand-eyes",
            "Hand-eyes against the depth",
            &hand_eye_check_section(&c.hand_eye_checks)
        ),
        section(
            "convergence",
            "ICP convergence",
            &convergence_section(&c.icp_levels, 1e3, "mm")
        ),
        section(
            "log",
            "Warnings and timings",
            &format!(
                "{}{}",
                log_section(&c.warnings, &c.timings_ms),
                list(&c.priors_used.iter().map(|p| format!("prior: {p}")).collect::<Vec<_>>())
            )
        ),
        cell = esc(&cell_name),
        dir = esc(&cell.dir.display().to_string()),
        m = esc(&c.method),
    );
    let data = json!({
        "kind": "calibrate",
        "cell": cell.dir,
        "summary": summary(c),
        "frame_ids": {"parent": frames.parent, "child": frames.child},
        "residuals": residuals.iter().map(|p| json!({"name": p.name, "stats": p.stats, "histogram": p.histogram})).collect::<Vec<_>>(),
        "icp_levels": c.icp_levels,
        "consistency": c.consistency,
        "hand_eye_check": c.hand_eye_checks,
    });
    Ok(finish(
        &sc,
        &format!("depthcal calibrate {cell_name}"),
        &body,
        data,
        &format!("CALIBRATE {cell_name}"),
        c.trust.trusted,
    ))
}
