//! The report of `calibrate` on a cell of three or more robots: every robot's fused cloud in the reference
//! base under the joint solution, one colour per robot, with its base and cameras; each robot's cloud at
//! its own pair's initial estimate; each robot's residual against the reference robot's surface; the pose
//! graph seen from above with every pair's verdict and residual; each robot's pose and 1-σ; each pair's
//! own result; the per-frame consistency and hand-eye checks; warnings and timings.

use super::calibration::{base_and_cameras, extent, reach_with_voxel, triad_length};
use super::page::{banner, details, esc, grid, list, num, section, viewer};
use super::residual::{nice_ceiling, point_to_plane, Histogram, ResidualStats};
use super::scene::{Item, PointSet, Residuals, Scene, Shape, MAX_POINTS, PALETTE};
use super::sections::{
    consistency_section, hand_eye_check_section, lines_item, log_section, matrix_table,
    pose_formats, residual_section, sigma, three, transform_file_blocks,
};
use super::svg::{graph_top_view, GraphEdgeMark, GraphNode};
use super::{finish, Report, HISTOGRAM_BINS};
use crate::calibration::consistency::RobotConsistency;
use crate::calibration::multi_robot::CellCalibration;
use crate::calibration::pose_graph::EdgeVerdict;
use crate::calibration::robot_to_robot::FusedRobots;
use crate::cell::Cell;
use crate::error::{Error, Result};
use crate::geometry::robot_formats::Frames;
use crate::index::KdIndex;
use crate::report::CalibrationReport;
use nalgebra::Isometry3;
use serde_json::json;

/// Robot `k`'s colour (solving order: the reference first).
fn colour(k: usize) -> [u8; 3] {
    PALETTE[k % PALETTE.len()]
}

/// CSS of a colour.
fn css(rgb: [u8; 3]) -> String {
    format!("rgb({},{},{})", rgb[0], rgb[1], rgb[2])
}

/// How the graph view and the tables draw a pair's verdict: CSS colour, dashed, words.
fn verdict_style(v: EdgeVerdict) -> (&'static str, bool, &'static str) {
    match v {
        EdgeVerdict::Agrees => ("#2b8a3e", false, "used; its loops agree"),
        EdgeVerdict::Unchecked => ("#1c7ed6", false, "used; no loop checks it"),
        EdgeVerdict::NotUsable => ("#adb5bd", true, "not trusted on its own"),
        EdgeVerdict::Disagrees => ("#e03131", true, "dropped: it disagrees with its loops"),
        EdgeVerdict::Ambiguous => (
            "#f08c00",
            true,
            "dropped: in a loop that disagrees, which pair is wrong cannot be told",
        ),
    }
}

/// The report of a cell of three or more robots. `fused` holds every robot's cloud in solving order (the
/// reference first, as [`crate::calibration::multi_robot::calibrate_robots`] returns it), `report` the
/// JSON of the same result (its `robots` and `pairs` are embedded), `frames` the ROS frame ids
/// (`frames.parent` the reference base; each other robot's from `report.robots`).
pub fn robots_report(
    cell: &Cell,
    c: &CellCalibration,
    fused: &FusedRobots,
    report: &CalibrationReport,
    frames: &Frames,
) -> Result<Report> {
    let n = fused.clouds.len();
    let bases = report.robots.as_deref().unwrap_or(&[]);
    let pair_reports = report.pairs.as_deref().unwrap_or(&[]);
    if n < 2
        || fused.robots.len() != n
        || c.robots.len() + 1 != n
        || bases.len() != c.robots.len()
        || pair_reports.len() != c.pairs.len()
        || c.pairs.len() < n - 1
    {
        return Err(Error::InvalidInput(format!(
            "the report of a cell of robots needs one fused cloud per robot and the pairs of the result ({n} clouds, {} robots, {} pairs)",
            c.robots.len() + 1,
            c.pairs.len()
        )));
    }
    let names: Vec<&str> = fused.robots.iter().map(|r| r.name.as_str()).collect();
    // The transform of robot k (solving order) in the joint solution, and at its pair with the reference's
    // initial estimate (the pairs run (0,1), (0,2), … first).
    let joint = |k: usize| -> Option<Isometry3<f64>> {
        if k == 0 {
            Some(Isometry3::identity())
        } else {
            c.robots[k - 1].transform
        }
    };
    let initial = |k: usize| -> Isometry3<f64> {
        if k == 0 {
            Isometry3::identity()
        } else {
            c.pairs[k - 1].calibration.initial.transform
        }
    };

    // The scene: each cloud subsampled to an equal share of the budget.
    let mut sc = Scene::new("mm");
    let share = MAX_POINTS / n;
    let sets: Vec<usize> = fused
        .clouds
        .iter()
        .enumerate()
        .map(|(k, f)| {
            sc.add_set(PointSet::subsampled(
                &format!("{} cloud", names[k]),
                &f.cloud.points,
                share,
            ))
        })
        .collect();
    let finite: Vec<[f32; 3]> = fused.clouds[0]
        .cloud
        .points
        .iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .copied()
        .collect();
    let index = KdIndex::new(&finite);
    sc.items.push(Item {
        name: format!("{} cloud (reference)", names[0]),
        shape: Shape::Points {
            set: sets[0],
            residual: None,
        },
        transform: Isometry3::identity(),
        rgb: colour(0),
        visible: true,
        views: vec!["refined", "initial"],
    });
    let mut reaches = Vec::new();
    for k in 1..n {
        let pair = &c.pairs[k - 1].calibration;
        let reach = reach_with_voxel(pair, fused.clouds[0].stats.voxel_size_m);
        reaches.push(reach);
        if let Some(t) = joint(k) {
            let residual = (!finite.is_empty() && !sc.sets[sets[k]].points.is_empty()).then(|| {
                let values =
                    point_to_plane(&sc.sets[sets[k]].points, &t, &finite, &index, reach, 1e3);
                sc.residuals.push(Residuals {
                    name: format!("{} cloud, joint solution", names[k]),
                    values,
                });
                sc.residuals.len() - 1
            });
            sc.items.push(Item {
                name: format!("{} cloud, joint solution", names[k]),
                shape: Shape::Points {
                    set: sets[k],
                    residual,
                },
                transform: t,
                rgb: colour(k),
                visible: true,
                views: vec!["refined"],
            });
        }
        sc.items.push(Item {
            name: format!(
                "{} cloud, initial estimate of pair {} - {}",
                names[k], names[0], names[k]
            ),
            shape: Shape::Points {
                set: sets[k],
                residual: None,
            },
            transform: initial(k),
            rgb: colour(k),
            visible: false,
            views: vec!["initial"],
        });
    }
    // The colour scale: the nice ceiling of the 90th percentile of every robot's residuals together.
    let pooled: Vec<f32> = sc
        .residuals
        .iter()
        .flat_map(|r| r.values.iter().copied())
        .collect();
    if !pooled.is_empty() {
        sc.residual_max = nice_ceiling(ResidualStats::new(&pooled).p90);
    }
    let residuals: Vec<(String, ResidualStats, Histogram)> = sc
        .residuals
        .iter()
        .map(|r| {
            (
                r.name.clone(),
                ResidualStats::new(&r.values),
                Histogram::new(&r.values, sc.residual_max, HISTOGRAM_BINS),
            )
        })
        .collect();

    // Bases and cameras, each robot's frames flagged by its own consistency check.
    let consistency = robots_consistency(c);
    let len = triad_length(
        fused
            .clouds
            .iter()
            .map(|f| extent(&f.cloud.points))
            .fold(0.0, f64::max),
    );
    for (k, robot) in fused.robots.iter().enumerate() {
        let cons = consistency.iter().find(|r| r.robot == names[k]);
        let lines = base_and_cameras(robot, cons, len, colour(k));
        if let Some(t) = joint(k) {
            sc.items.push(lines_item(
                format!("{} base and cameras", names[k]),
                lines.clone(),
                t,
                true,
                if k == 0 {
                    vec!["refined", "initial"]
                } else {
                    vec!["refined"]
                },
            ));
        }
        if k > 0 {
            sc.items.push(lines_item(
                format!("{} base and cameras, initial estimate", names[k]),
                lines,
                initial(k),
                false,
                vec!["initial"],
            ));
        }
    }
    sc.fit_camera();

    let cell_name = cell
        .dir
        .file_name()
        .map(|x| x.to_string_lossy().into_owned())
        .unwrap_or_else(|| cell.dir.display().to_string());
    let verdict = banner(
        c.trust.trusted,
        &format!(
            "The bases of {} robots in {}'s base frame (depth method, joint solution of {} pairs).",
            n,
            c.reference,
            c.pairs.len()
        ),
        &c.trust.reasons,
        &c.trust.suggestions,
    );
    let body = format!(
        "<h1>depthcal calibrate: {cell}</h1><p class=\"sub\">cell {dir} · {n} robots · reference {r} · \
         method depth</p>{verdict}{}{}{}{}{}{}{}{}",
        section("robots", "Every robot's base", &robots_section(c, report, frames)),
        section("graph", "The pose graph", &graph_section(c, &names)),
        section("pairs", "Every pair's own calibration", &pairs_section(c)),
        section(
            "view",
            "3-D view (reference base frame, metres)",
            &format!(
                "<p>Every robot's fused cloud in {r}'s base frame under the joint solution, one colour per \
                 robot ({legend}). The initial view places each robot at its own pair with {r}'s initial \
                 estimate. Triads: each base (x red, y green, z blue); frusta: every camera pose, in red when \
                 the robot's own consistency check flags the frame. Colour by residual shows each robot's \
                 distance to {r}'s surface (points seen by {r} nowhere near have no counterpart).</p>{}",
                viewer(&sc),
                r = esc(&c.reference),
                legend = names
                    .iter()
                    .enumerate()
                    .map(|(k, x)| format!(
                        "<span style=\"color:{}\">■</span> {}",
                        css(colour(k)),
                        esc(x)
                    ))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        ),
        section(
            "residual",
            "Residual of each robot's surface against the reference",
            &residual_section(
                &residuals
                    .iter()
                    .map(|(name, s, h)| (name.clone(), s, h))
                    .collect::<Vec<_>>(),
                "mm",
                reaches.iter().copied().fold(0.0, f64::max) * 1e3
            )
        ),
        section(
            "consistency",
            "Per-frame consistency",
            &consistency_section(&consistency)
        ),
        section(
            "hand-eyes",
            "Hand-eyes against the depth",
            &hand_eye_check_section(&fused.hand_eye_checks)
        ),
        section(
            "log",
            "Warnings and timings",
            &log_section(&c.warnings, &c.timings_ms)
        ),
        cell = esc(&cell_name),
        dir = esc(&cell.dir.display().to_string()),
        r = esc(&c.reference),
    );
    let data = json!({
        "kind": "calibrate_robots",
        "cell": cell.dir,
        "reference": c.reference,
        "trusted": c.trust.trusted,
        "reasons": c.trust.reasons,
        "robots": bases,
        "pairs": pair_reports,
        "frame_ids": {"parent": frames.parent},
        "residuals": residuals.iter().map(|(name, s, h)| json!({"name": name, "stats": s, "histogram": h})).collect::<Vec<_>>(),
        "consistency": consistency,
        "hand_eye_check": fused.hand_eye_checks,
    });
    Ok(finish(
        &sc,
        &format!("depthcal calibrate {cell_name}"),
        &body,
        data,
        &format!("CALIBRATE {cell_name} ({n} ROBOTS)"),
        c.trust.trusted,
    ))
}

/// Each robot's own consistency check, once per robot (every pair repeats it on the same frames), in the
/// order the pairs meet the robots.
fn robots_consistency(c: &CellCalibration) -> Vec<RobotConsistency> {
    let mut out: Vec<RobotConsistency> = Vec::new();
    for p in &c.pairs {
        for r in &p.calibration.consistency {
            if !out.iter().any(|x| x.robot == r.robot) {
                out.push(r.clone());
            }
        }
    }
    out
}

/// Each robot's pose in the joint solution with its 1-σ, trust and pairs; the matrix and every format in
/// a collapsible block.
fn robots_section(c: &CellCalibration, report: &CalibrationReport, frames: &Frames) -> String {
    let bases = report.robots.as_deref().unwrap_or(&[]);
    let mut rows = Vec::new();
    let mut blocks = String::new();
    for (k, (r, rr)) in c.robots.iter().zip(bases).enumerate() {
        let swatch = format!(
            "<span style=\"color:{}\">■</span> {}",
            css(colour(k + 1)),
            esc(&r.name)
        );
        let truth = r.error_vs_truth.map_or("-".to_string(), |(d, m)| {
            format!("{} ° / {} mm", num(d, 4), num(m * 1e3, 3))
        });
        match (&r.transform, &r.covariance) {
            (Some(t), Some(cov)) => {
                let (sr, st) = sigma(cov, 1e3);
                let (roll, pitch, yaw) = t.rotation.euler_angles();
                rows.push(vec![
                    swatch,
                    format!(
                        "{} / {} / {}",
                        num(t.translation.x, 4),
                        num(t.translation.y, 4),
                        num(t.translation.z, 4)
                    ),
                    format!(
                        "{} / {} / {}",
                        num(roll.to_degrees(), 3),
                        num(pitch.to_degrees(), 3),
                        num(yaw.to_degrees(), 3)
                    ),
                    format!("{} ° · {} mm", three(&sr, 4), three(&st, 3)),
                    rr.pairs_used
                        .iter()
                        .map(|p| esc(p))
                        .collect::<Vec<_>>()
                        .join(", "),
                    truth,
                    if r.trust.trusted {
                        "<span class=\"good\">trusted</span>".into()
                    } else {
                        format!(
                            "<span class=\"bad\">NOT trusted</span>{}",
                            list(&r.trust.reasons)
                        )
                    },
                ]);
                let f = Frames {
                    parent: frames.parent.clone(),
                    child: rr.frame_id.clone(),
                };
                blocks.push_str(&details(
                    &format!("T_{}_{}: the matrix and every format", c.reference, r.name),
                    &format!(
                        "{}{}{}",
                        matrix_table(t, &format!("transform-{}", r.name)),
                        pose_formats(t),
                        transform_file_blocks(t, &f)
                    ),
                ));
            }
            _ => rows.push(vec![
                swatch,
                "-".into(),
                "-".into(),
                "-".into(),
                "-".into(),
                truth,
                format!(
                    "<span class=\"bad\">NOT calibrated</span>{}",
                    list(&r.trust.reasons)
                ),
            ]),
        }
    }
    format!(
        "<p><code>T_{r}_&lt;robot&gt;</code> maps the robot's base coordinates into {r}'s (the reference): \
         <code>p_{r} = T · p_robot</code>; metres, roll / pitch / yaw in degrees (about x, y, z of the \
         reference base, applied z-y-x). The 1-σ is the joint solution's: every pair's covariance, inputs \
         included, combined by the pose graph.</p>{}{blocks}",
        grid(
            &[
                "robot",
                "x / y / z (m)",
                "roll / pitch / yaw (°)",
                "1-σ rotation · translation",
                "from pairs",
                "vs ground truth",
                "verdict"
            ],
            &rows
        ),
        r = esc(&c.reference),
    )
}

/// The graph from above: the bases where the joint solution puts them, each pair a line coloured by its
/// verdict and labelled with its residual against the joint solution.
fn graph_section(c: &CellCalibration, names: &[&str]) -> String {
    let nodes: Vec<GraphNode> = names
        .iter()
        .enumerate()
        .map(|(k, name)| GraphNode {
            name: name.to_string(),
            at: if k == 0 {
                Some([0.0, 0.0])
            } else {
                c.robots[k - 1]
                    .transform
                    .map(|t| [t.translation.x, t.translation.y])
            },
            colour: css(colour(k)),
        })
        .collect();
    let index = |name: &str| names.iter().position(|x| *x == name).unwrap_or(0);
    let edges: Vec<GraphEdgeMark> = c
        .pairs
        .iter()
        .map(|p| {
            let (stroke, dashed, _) = verdict_style(p.check.verdict);
            GraphEdgeMark {
                from: index(&p.calibration.reference),
                to: index(&p.calibration.other),
                colour: stroke.to_string(),
                dashed,
                label: p.check.residual.map_or(String::new(), |(d, m)| {
                    format!("{d:.3}° / {:.2} mm", m * 1e3)
                }),
            }
        })
        .collect();
    let key: Vec<String> = [
        EdgeVerdict::Agrees,
        EdgeVerdict::Unchecked,
        EdgeVerdict::NotUsable,
        EdgeVerdict::Disagrees,
        EdgeVerdict::Ambiguous,
    ]
    .into_iter()
    .map(|v| {
        let (stroke, dashed, words) = verdict_style(v);
        format!(
            "<span style=\"color:{stroke}\">{}</span> {} ({words})",
            if dashed { "╌╌" } else { "──" },
            v.name()
        )
    })
    .collect();
    format!(
        "<p>Each robot's base seen from above (x right, y up, metres) where the joint solution puts it; each \
         pair of robots is a line coloured by its verdict and labelled with its own result's distance from \
         the joint solution. Robots with no pose stand in the row below the plot.</p>{}<p>{}</p>",
        graph_top_view("robot bases and pairs (top view)", &nodes, &edges),
        key.join(" · ")
    )
}

/// Every pair's own two-robot result against the joint solution.
fn pairs_section(c: &CellCalibration) -> String {
    let rows: Vec<Vec<String>> = c
        .pairs
        .iter()
        .map(|p| {
            let q = &p.calibration;
            let (stroke, _, words) = verdict_style(p.check.verdict);
            let opt = |x: Option<f64>| x.map_or("-".to_string(), |v| num(v, 3));
            vec![
                format!("{} - {}", esc(&q.reference), esc(&q.other)),
                if q.trust.trusted {
                    "<span class=\"good\">trusted</span>".into()
                } else {
                    format!(
                        "<span class=\"bad\">not trusted</span>{}",
                        list(&q.trust.reasons)
                    )
                },
                format!("{} / {}", opt(q.fitness), opt(q.overlap)),
                format!(
                    "<span style=\"color:{stroke}\">{}</span> ({words})",
                    p.check.verdict.name()
                ),
                p.check.residual.map_or("-".to_string(), |(d, m)| {
                    format!("{} ° / {} mm", num(d, 3), num(m * 1e3, 2))
                }),
                p.check.loop_error.map_or("-".to_string(), |z| num(z, 2)),
                q.error_vs_truth.map_or("-".to_string(), |(d, m)| {
                    format!("{} ° / {} mm", num(d, 4), num(m * 1e3, 3))
                }),
            ]
        })
        .collect();
    format!(
        "<p>Each pair is calibrated on its own as a two-robot cell (the same global stage, refinement and \
         trust checks), its first robot the pair's reference. The residual is the pair's own transform \
         against the joint solution; the loop error compares it with the solution without it, normalised \
         by both covariances (above <code>pose_graph.max_loop_error</code> the pair is dropped).</p>{}",
        grid(
            &[
                "pair",
                "own result",
                "fitness / overlap",
                "in the graph",
                "residual",
                "loop error",
                "own result vs ground truth"
            ],
            &rows
        )
    )
}
