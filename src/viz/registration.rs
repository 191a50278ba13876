//! The report of `register`: the target and the source moved by the result and by the initial (global or
//! given) estimate, in the target's frame; the residual; ICP convergence; the transform; quality and
//! verdict. Lengths are in the clouds' own unit.

use super::page::{banner, details, esc, num, section, table, viewer};
use super::scene::PALETTE;
use super::sections::{
    convergence_section, degeneracy_cell, log_section, matrix_block, matrix_table, pose_formats,
    residual_section, sigma, three, yes_no,
};
use super::{finish, Placement, Report, TwoClouds};
use crate::error::Result;
use crate::registration::Registration;
use crate::report::{PoseReport, SigmaReport};
use crate::PointCloud;
use serde_json::json;

/// The report of a registration of `source` (named `source_name`) onto `target`.
pub fn registration_report(
    source_name: &str,
    source: &PointCloud,
    target_name: &str,
    target: &PointCloud,
    reg: &Registration,
) -> Result<Report> {
    let reach = reg
        .icp_levels
        .last()
        .map(|l| l.max_correspondence_distance)
        .unwrap_or(3.0 * reg.finest_voxel)
        .max(1e-12);
    let initial_what = if reg.global.is_some() {
        "global estimate (FPFH + RANSAC)"
    } else {
        "initial guess (--init)"
    };
    let two = TwoClouds {
        reference_name: format!("target {target_name}"),
        reference: &target.points,
        other_name: format!("source {source_name}"),
        other: &source.points,
        placements: vec![
            Placement {
                name: "source moved by the result".into(),
                transform: reg.transform,
                rgb: PALETTE[1],
                visible: true,
                views: vec!["refined"],
                residual: true,
            },
            Placement {
                name: format!("source at the {initial_what}"),
                transform: reg.initial,
                rgb: PALETTE[2],
                visible: false,
                views: vec!["initial"],
                residual: true,
            },
        ],
        scale: 1.0,
        unit: "cloud units",
        reach,
    };
    let (mut sc, residuals) = two.scene();
    sc.fit_camera();
    let (sr, st) = sigma(&reg.covariance, 1.0);
    let verdict = banner(
        reg.trust.trusted,
        &format!("The transform that moves {source_name} onto {target_name}."),
        &reg.trust.reasons,
        &reg.trust.suggestions,
    );
    let mut q = vec![
        ("fitness", num(reg.fitness, 4)),
        ("inlier RMSE", num(reg.inlier_rmse, 6)),
        ("overlap", num(reg.overlap, 4)),
        ("surface agreement", num(reg.surface_agreement, 4)),
        ("converged", yes_no(reg.converged)),
        ("ICP iterations", reg.iterations.to_string()),
        ("degenerate", degeneracy_cell(&reg.degeneracy)),
        (
            "voxel / spacing",
            format!(
                "{} / {} {}",
                num(reg.voxel, 6),
                num(reg.spacing[0], 6),
                num(reg.spacing[1], 6)
            ),
        ),
        (
            "points",
            format!(
                "source {} ({} downsampled), target {} ({} downsampled)",
                source.len(),
                reg.global_points[0],
                target.len(),
                reg.global_points[1]
            ),
        ),
    ];
    if let Some(g) = &reg.global {
        q.push((
            "global stage",
            format!(
                "{} correspondences, {} inliers, {} RANSAC samples, fitness {}",
                g.correspondences,
                g.inliers,
                g.iterations,
                num(g.fitness, 3)
            ),
        ));
    }
    if let Some(a) = &reg.ambiguity {
        q.push((
            "ambiguity",
            format!(
                "<span class=\"bad\">a runner-up {:.2}° / {} away scores {:.0}% of the best</span>",
                a.rotation_deg,
                num(a.translation, 4),
                a.score_ratio * 1e2
            ),
        ));
    }
    let d = reg.initial.inverse() * reg.transform;
    q.push((
        "initial → final",
        format!(
            "moved {:.3}° / {}",
            d.rotation.angle().to_degrees(),
            num(d.translation.vector.norm(), 6)
        ),
    ));
    let result = format!(
        "<p>The 4x4 matrix maps source points into the target's frame (cloud units).</p>{}{}\
         <p>1-σ: rotation <span class=\"num\" id=\"sigma-rotation\">{}</span> °, translation \
         <span class=\"num\" id=\"sigma-translation\">{}</span> (cloud units, about the target's x, y, z)</p>{}{}",
        matrix_table(&reg.transform, "transform"),
        pose_formats(&reg.transform),
        three(&sr, 4),
        three(&st, 6),
        details("the matrix as text", &matrix_block(&reg.transform)),
        details(
            &format!("the {initial_what}"),
            &matrix_table(&reg.initial, "initial-transform")
        ),
    );
    let entries: Vec<(String, &_, &_)> = residuals
        .iter()
        .map(|p| (p.name.clone(), &p.stats, &p.histogram))
        .collect();
    let body = format!(
        "<h1>depthcal register</h1><p class=\"sub\">source {s} → target {t}</p>{verdict}{}{}{}{}{}{}",
        section("result", "Result", &result),
        section("quality", "Quality", &table(&q)),
        section(
            "view",
            "3-D view (target frame, cloud units)",
            &format!(
                "<p>The target orange, the source moved by the result blue, the source at the {initial_what} \
                 purple (off at first). Colour by residual shows the source's distance to the target \
                 surface.</p>{}",
                viewer(&sc)
            )
        ),
        section(
            "residual",
            "Residual of the source against the target",
            &residual_section(&entries, "cloud units", reach)
        ),
        section(
            "convergence",
            "ICP convergence",
            &convergence_section(&reg.icp_levels, 1.0, "cloud units")
        ),
        section(
            "log",
            "Warnings and timings",
            &log_section(&reg.warnings, &reg.timings_ms)
        ),
        s = esc(source_name),
        t = esc(target_name),
    );
    let data = json!({
        "kind": "register",
        "summary": {
            "source": source_name,
            "target": target_name,
            "transform": PoseReport::new(&reg.transform),
            "initial": {"transform": PoseReport::new(&reg.initial)},
            "fitness": reg.fitness,
            "inlier_rmse_m": reg.inlier_rmse,
            "overlap": reg.overlap,
            "converged": reg.converged,
            "iterations": reg.iterations,
            "sigma": SigmaReport::from_covariance(&reg.covariance),
            "trusted": reg.trust.trusted,
            "reasons": reg.trust.reasons,
            "suggestions": reg.trust.suggestions,
            "warnings": reg.warnings,
        },
        "residuals": residuals.iter().map(|p| json!({"name": p.name, "stats": p.stats, "histogram": p.histogram})).collect::<Vec<_>>(),
        "icp_levels": reg.icp_levels,
    });
    Ok(finish(
        &sc,
        &format!("depthcal register {source_name} onto {target_name}"),
        &body,
        data,
        "REGISTER",
        reg.trust.trusted,
    ))
}
