//! The report of `compare`: every method side by side (table, transforms, verdicts), the other robot's
//! cloud placed by each method's result (toggles), the residual of each, and the lead method's (the first
//! trusted one, else the first that ran) consistency and ICP convergence.

use super::calibration::{quality_table, reach, robot_lines, summary, OtherAt};
use super::page::{banner, details, esc, grid, section, viewer};
use super::scene::PALETTE;
use super::sections::{
    consistency_section, convergence_section, matrix_table, pose_formats, residual_section,
};
use super::{finish, Placement, PlacementResidual, Report, TwoClouds};
use crate::calibration::robot_to_robot::{Calibration, FusedCell};
use crate::cell::Cell;
use crate::error::Result;
use crate::geometry::transform::pose_error;
use nalgebra::Isometry3;
use serde_json::json;

/// One method of a comparison.
#[derive(Clone, Copy, Debug)]
pub struct MethodRun<'a> {
    /// The method's name (`depth`, `marker`, ...).
    pub method: &'a str,
    /// Its calibration, or why there is none.
    pub outcome: std::result::Result<&'a Calibration, &'a str>,
    /// Skipped because the data does not allow it (rather than failed).
    pub skipped: bool,
    /// Its time (initialiser and refinement), milliseconds.
    pub time_ms: f64,
}

fn err_text(e: Option<(f64, f64)>) -> String {
    e.map_or("-".into(), |(r, t)| format!("{r:.3}° / {:.2} mm", t * 1e3))
}

/// The report of a comparison of `runs` on the fused clouds `fused`.
pub fn comparison_report(cell: &Cell, fused: &FusedCell, runs: &[MethodRun]) -> Result<Report> {
    let (rr, or) = cell.robot_pair()?;
    let ok: Vec<(&str, &Calibration)> = runs
        .iter()
        .filter_map(|r| r.outcome.ok().map(|c| (r.method, c)))
        .collect();
    let lead = ok
        .iter()
        .position(|(_, c)| c.trust.trusted)
        .or((!ok.is_empty()).then_some(0));
    let disagreement = |m: &str, t: &Isometry3<f64>| -> Option<(f64, f64)> {
        ok.iter()
            .filter(|(o, _)| *o != m)
            .map(|(_, c)| pose_error(t, &c.transform))
            .fold(None, |a: Option<(f64, f64)>, (r, tr)| {
                Some(a.map_or((r, tr), |(ar, at)| (ar.max(r), at.max(tr))))
            })
    };
    let placements = placements(&ok, lead);
    let lead_cal = lead.map(|k| ok[k].1);
    let two = TwoClouds {
        reference_name: format!("{} cloud (reference)", rr.name),
        reference: &fused.reference.cloud.points,
        other_name: format!("{} cloud", or.name),
        other: &fused.other.cloud.points,
        placements,
        scale: 1e3,
        unit: "mm",
        reach: lead_cal.map_or(3.0 * fused.reference.stats.voxel_size_m, |c| {
            reach(c, fused)
        }),
    };
    let (mut sc, residuals) = two.scene();
    let other_at = lead_cal.map_or_else(Vec::new, |c| {
        vec![
            OtherAt {
                suffix: format!(" by {}", c.method),
                transform: c.transform,
                visible: true,
                views: vec!["refined"],
            },
            OtherAt {
                suffix: ", initial estimate".into(),
                transform: c.initial.transform,
                visible: false,
                views: vec!["initial"],
            },
        ]
    });
    sc.items
        .extend(robot_lines((rr, or), fused, lead_cal, other_at));
    sc.fit_camera();

    let rows = method_rows(runs, &disagreement);
    let per_method = method_details(&ok);
    let trusted = ok.iter().any(|(_, c)| c.trust.trusted);
    let verdict = verdict(trusted, ok.is_empty(), lead_cal);
    let cell_name = cell
        .dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| cell.dir.display().to_string());
    let entries: Vec<(String, &_, &_)> = residuals
        .iter()
        .map(|p| (p.name.clone(), &p.stats, &p.histogram))
        .collect();
    let body = format!(
        "<h1>depthcal compare: {cell}</h1><p class=\"sub\">cell {dir} · reference {r} · other {o}</p>{verdict}{}{}{}{}{}",
        section(
            "methods",
            "Methods side by side",
            &format!(
                "{}<p>Fusing both robots once: {:.2} s. Errors against ground_truth.json when the cell has one; \
                 disagreement: the largest difference from the other methods' results.</p>{per_method}",
                grid(
                    &[
                        "method",
                        "status",
                        "initial vs truth",
                        "refined vs truth",
                        "max disagreement",
                        "time",
                        "trusted"
                    ],
                    &rows
                ),
                fused.fuse_ms / 1e3
            )
        ),
        section(
            "view",
            "3-D view (reference base frame, metres)",
            &format!(
                "<p>The reference cloud orange; the other robot's cloud as each method places it (one \
                 toggle per method, the lead method on).</p>{}",
                viewer(&sc)
            )
        ),
        section(
            "residual",
            "Residual of the other robot's surface, per method",
            &residual_section(&entries, "mm", two.reach * 1e3)
        ),
        section(
            "consistency",
            "Per-frame consistency",
            &consistency_section(lead_cal.map_or(&[][..], |c| &c.consistency))
        ),
        section(
            "convergence",
            &format!(
                "ICP convergence ({})",
                lead_cal.map_or("no method ran", |c| c.method.as_str())
            ),
            &convergence_section(lead_cal.map_or(&[][..], |c| &c.icp_levels), 1e3, "mm")
        ),
        cell = esc(&cell_name),
        dir = esc(&cell.dir.display().to_string()),
        r = esc(&rr.name),
        o = esc(&or.name),
    );
    let data = page_data(cell, runs, trusted, lead_cal, &residuals);
    Ok(finish(
        &sc,
        &format!("depthcal compare {cell_name}"),
        &body,
        data,
        &format!("COMPARE {cell_name}"),
        trusted,
    ))
}

/// The other robot's cloud as each method places it, the lead's first (it sets the residual colour scale
/// and is the one shown), then the lead's initial estimate.
fn placements(ok: &[(&str, &Calibration)], lead: Option<usize>) -> Vec<Placement> {
    let mut placements = Vec::new();
    // The lead's result first: it sets the residual colour scale.
    let order: Vec<usize> = lead
        .into_iter()
        .chain((0..ok.len()).filter(|k| Some(*k) != lead))
        .collect();
    for &k in &order {
        let (m, c) = ok[k];
        let is_lead = Some(k) == lead;
        placements.push(Placement {
            name: format!(
                "{} cloud by {m}{}",
                c.other,
                if c.refined { " (refined)" } else { "" }
            ),
            transform: c.transform,
            rgb: PALETTE[1 + k % (PALETTE.len() - 1)],
            visible: is_lead,
            views: if is_lead { vec!["refined"] } else { vec![] },
            residual: true,
        });
    }
    if let Some(k) = lead {
        let (m, c) = ok[k];
        placements.push(Placement {
            name: format!("{} cloud by {m}, initial estimate", c.other),
            transform: c.initial.transform,
            rgb: PALETTE[2],
            visible: false,
            views: vec!["initial"],
            residual: false,
        });
    }
    placements
}

/// The largest difference of a method's transform from the other methods' results: `(degrees, metres)`.
type Disagreement<'a> = dyn Fn(&str, &Isometry3<f64>) -> Option<(f64, f64)> + 'a;

/// One table row per method: status, errors against the truth, the largest disagreement with the others,
/// time and trust.
fn method_rows(runs: &[MethodRun], disagreement: &Disagreement) -> Vec<Vec<String>> {
    runs.iter()
        .map(|r| match r.outcome {
            Ok(c) => vec![
                esc(r.method),
                "ok".into(),
                err_text(c.initial_error_vs_truth),
                if c.refined {
                    err_text(c.error_vs_truth)
                } else {
                    "-".into()
                },
                err_text(disagreement(r.method, &c.transform)),
                format!("{:.2} s", r.time_ms / 1e3),
                if c.trust.trusted {
                    "<span class=\"good\">yes</span>".into()
                } else {
                    format!(
                        "<span class=\"bad\">NO</span>: {}",
                        esc(&c.trust.reasons.join("; "))
                    )
                },
            ],
            Err(e) => vec![
                esc(r.method),
                if r.skipped {
                    "skipped"
                } else {
                    "<span class=\"bad\">FAILED</span>"
                }
                .into(),
                esc(e.lines().next().unwrap_or("")),
                String::new(),
                String::new(),
                String::new(),
                String::new(),
            ],
        })
        .collect()
}

/// A folded section per method that ran: its transform in every format and its quality figures.
fn method_details(ok: &[(&str, &Calibration)]) -> String {
    let mut per_method = String::new();
    for (m, c) in ok {
        per_method.push_str(&details(
            &format!(
                "{m}: transform, quality{}",
                if c.trust.trusted {
                    ""
                } else {
                    " (NOT TRUSTED)"
                }
            ),
            &format!(
                "{}{}{}",
                matrix_table(&c.transform, &format!("transform-{m}")),
                pose_formats(&c.transform),
                quality_table(c)
            ),
        ));
    }
    per_method
}

/// The page's verdict: trusted when any method is, with the lead method named.
fn verdict(trusted: bool, none_ran: bool, lead: Option<&Calibration>) -> String {
    let reasons: Vec<String> = if trusted {
        Vec::new()
    } else if none_ran {
        vec!["every method failed or was skipped".into()]
    } else {
        vec!["no method gave a trusted result".into()]
    };
    banner(
        trusted,
        &match lead {
            Some(c) if trusted => format!("{} gives a trusted result (shown first).", c.method),
            _ => "No method gives a trusted result.".to_string(),
        },
        &reasons,
        &[],
    )
}

/// The page's embedded data: every method's summary (the names and forms of `--json`) and the residuals.
fn page_data(
    cell: &Cell,
    runs: &[MethodRun],
    trusted: bool,
    lead: Option<&Calibration>,
    residuals: &[PlacementResidual],
) -> serde_json::Value {
    let methods: Vec<serde_json::Value> = runs
        .iter()
        .map(|r| match r.outcome {
            Ok(c) => {
                let mut v = summary(c);
                v["method"] = json!(r.method);
                v["status"] = json!("ok");
                v["time_ms"] = json!(r.time_ms);
                v
            }
            Err(e) => json!({
                "method": r.method,
                "status": if r.skipped { "skipped" } else { "failed" },
                "reason": e,
            }),
        })
        .collect();
    json!({
        "kind": "compare",
        "cell": cell.dir,
        "summary": {"trusted": trusted, "lead": lead.map(|c| c.method.clone()), "methods": methods},
        "residuals": residuals.iter().map(|p| json!({"name": p.name, "stats": p.stats, "histogram": p.histogram})).collect::<Vec<_>>(),
    })
}
