//! Page sections the three reports share: the transform in every format, the residual histogram and
//! statistics, each robot's per-frame consistency, and the ICP convergence charts.

use super::page::{details, esc, grid, list, num, pre, table};
use super::residual::{Histogram, ResidualStats};
use super::svg::{bar_chart, histogram, line_chart, Series};
use crate::calibration::consistency::RobotConsistency;
use crate::calibration::handeye::depth::check::HandEyeCheck;
use crate::geometry::pose::{
    isometry_to_abb, isometry_to_fanuc, isometry_to_ur, isometry_to_xyzquat, KukaPose,
};
use crate::geometry::robot_formats::{matrix_text, transform_files, Frames};
use crate::registration::IcpLevelTrace;
use nalgebra::{Isometry3, Matrix6};

/// CSS colours of chart series (as the scene's palette).
pub const CHART_COLOURS: [&str; 6] = [
    "#e6781e", "#286ee6", "#af50d2", "#28af5f", "#c8b428", "#1ebec8",
];

/// 1-σ per axis from a covariance of `[rx, ry, rz (rad), tx, ty, tz]`: degrees and the translation unit
/// times `scale`.
pub fn sigma(cov: &Matrix6<f64>, scale: f64) -> ([f64; 3], [f64; 3]) {
    let sd: Vec<f64> = (0..6).map(|k| cov[(k, k)].max(0.0).sqrt()).collect();
    (
        [sd[0].to_degrees(), sd[1].to_degrees(), sd[2].to_degrees()],
        [sd[3] * scale, sd[4] * scale, sd[5] * scale],
    )
}

/// `yes`, or a red `no`.
pub fn yes_no(b: bool) -> String {
    if b {
        "yes"
    } else {
        "<span class=\"bad\">no</span>"
    }
    .to_string()
}

/// `no`, or a red `yes` with the weak directions.
pub fn degeneracy_cell(d: &crate::registration::quality::Degeneracy) -> String {
    if d.is_degenerate() {
        format!("<span class=\"bad\">yes</span>: {}", esc(&d.describe()))
    } else {
        "no".into()
    }
}

/// A line set of the scene (base triads, camera frusta) under `transform`.
pub fn lines_item(
    name: String,
    lines: Vec<super::scene::Segment>,
    transform: Isometry3<f64>,
    visible: bool,
    views: Vec<&'static str>,
) -> super::scene::Item {
    super::scene::Item {
        name,
        shape: super::scene::Shape::Lines(lines),
        transform,
        rgb: [200, 200, 200],
        visible,
        views,
    }
}

/// Three numbers with `dec` decimals, space separated.
pub fn three(v: &[f64; 3], dec: usize) -> String {
    v.iter().map(|x| num(*x, dec)).collect::<Vec<_>>().join(" ")
}

/// The matrix as an HTML table (class `matrix`, one cell per element with `data-r`/`data-c`).
pub fn matrix_table(t: &Isometry3<f64>, id: &str) -> String {
    let m = crate::geometry::transform::isometry_to_nested(t);
    let mut s = format!("<table class=\"grid matrix\" id=\"{}\">", esc(id));
    for (r, row) in m.iter().enumerate() {
        s.push_str("<tr>");
        for (c, v) in row.iter().enumerate() {
            s.push_str(&format!(
                "<td class=\"num\" data-r=\"{r}\" data-c=\"{c}\">{}</td>",
                num(*v, if c == 3 { 6 } else { 8 })
            ));
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

/// The transform as xyz + quaternion, KUKA, UR, ABB and Fanuc values (cells in metres).
pub fn pose_formats(t: &Isometry3<f64>) -> String {
    let q = isometry_to_xyzquat(t);
    let k = KukaPose::from_isometry(t);
    let u = isometry_to_ur(t);
    let a = isometry_to_abb(t);
    let f = isometry_to_fanuc(t);
    let n = |v: &[f64], d: usize| v.iter().map(|x| num(*x, d)).collect::<Vec<_>>().join(" ");
    table(&[
        (
            "xyz (m), quaternion x y z w",
            format!(
                "<span class=\"num\">{} &nbsp; {}</span>",
                n(&q[..3], 6),
                n(&q[3..], 8)
            ),
        ),
        (
            "KUKA X Y Z (mm), A B C (deg)",
            format!(
                "<span class=\"num\">{} &nbsp; {}</span>",
                n(&[k.x_mm, k.y_mm, k.z_mm], 3),
                n(&[k.a_deg, k.b_deg, k.c_deg], 4)
            ),
        ),
        (
            "UR x y z (m), rx ry rz (rad)",
            format!(
                "<span class=\"num\">{} &nbsp; {}</span>",
                n(&u[..3], 6),
                n(&u[3..], 8)
            ),
        ),
        (
            "ABB x y z (mm), q1..q4 (w x y z)",
            format!(
                "<span class=\"num\">{} &nbsp; {}</span>",
                n(&a[..3], 3),
                n(&a[3..], 8)
            ),
        ),
        (
            "Fanuc X Y Z (mm), W P R (deg)",
            format!(
                "<span class=\"num\">{} &nbsp; {}</span>",
                n(&f[..3], 3),
                n(&f[3..], 4)
            ),
        ),
    ])
}

/// Every file `calibrate --output` writes for robots and ROS, each in a collapsible block.
pub fn transform_file_blocks(t: &Isometry3<f64>, frames: &Frames) -> String {
    let mut s = String::from(
        "<h3>Files for robots and ROS (as <code>calibrate --output</code> writes them)</h3>",
    );
    for (name, text) in transform_files(t, frames) {
        s.push_str(&details(name, &pre(&text)));
    }
    s
}

/// The 4x4 matrix as text (12 decimals, as `T_base1_base2.txt`).
pub fn matrix_block(t: &Isometry3<f64>) -> String {
    pre(&matrix_text(t))
}

/// The residual statistics of each placement and their histograms over the colour scale, `unit` the
/// display unit; `reach` the distance beyond which a point has no counterpart (display units).
pub fn residual_section(
    entries: &[(String, &ResidualStats, &Histogram)],
    unit: &str,
    reach: f64,
) -> String {
    if entries.is_empty() {
        return "<p>No clouds: nothing to compare.</p>".into();
    }
    let rows: Vec<Vec<String>> = entries
        .iter()
        .map(|(name, s, h)| {
            let share = if s.matched > 0 {
                100.0 * (s.matched - h.above) as f64 / s.matched as f64
            } else {
                0.0
            };
            vec![
                esc(name),
                format!("<span class=\"num\">{}</span>", num(s.median, 3)),
                format!("<span class=\"num\">{}</span>", num(s.p90, 3)),
                format!("<span class=\"num\">{}</span>", num(s.rms, 3)),
                format!("{} ({:.1}% below {})", s.matched, share, num(h.max, 3)),
                s.unmatched.to_string(),
            ]
        })
        .collect();
    let u = esc(unit);
    let header = [
        "placement",
        &format!("median ({u})"),
        &format!("90th percentile ({u})"),
        &format!("RMS ({u})"),
        "points with a counterpart",
        "without",
    ];
    let header: Vec<&str> = header.iter().map(|s| s.as_ref()).collect();
    let hists: Vec<(&str, &str, &[usize])> = entries
        .iter()
        .enumerate()
        .map(|(k, (name, _, h))| {
            (
                name.as_str(),
                CHART_COLOURS[(k + 1) % CHART_COLOURS.len()],
                h.bins.as_slice(),
            )
        })
        .collect();
    format!(
        "<p>Per point of the other cloud: its distance to the plane through the nearest points of the \
         reference cloud (point-to-plane, {u}). Points whose nearest reference point is farther than {} {u} \
         (the final ICP correspondence distance) have no counterpart: the surfaces do not overlap there.</p>{}{}",
        num(reach, 3),
        grid(&header, &rows),
        histogram(
            "residual histogram",
            &format!("residual ({unit}); the last bin's end is the colour scale's maximum"),
            entries[0].2.max,
            &hists
        )
    )
}

/// Each robot's stated hand-eye against its own depth frames: a row per robot with the change the depth
/// asks for, its distance in σ and the verdict.
pub fn hand_eye_check_section(checks: &[HandEyeCheck]) -> String {
    if checks.is_empty() {
        return "<p>Not checked (the clouds were not fused, <code>--refine-hand-eye</code> replaced the \
                hand-eyes, or <code>hand_eye_check.enabled</code> is off).</p>"
            .into();
    }
    let rows: Vec<Vec<String>> = checks
        .iter()
        .map(|h| {
            let verdict = match (h.checked, h.consistent) {
                (false, _) => format!("not checked: {}", esc(h.note.as_deref().unwrap_or(""))),
                (true, true) => "<span class=\"good\">agrees</span>".into(),
                (true, false) => "<span class=\"bad\">DISAGREES</span>".into(),
            };
            let verdict = if h.checked && h.determined.len() < 6 {
                format!("{verdict} (determined: {})", h.determined.join(" "))
            } else {
                verdict
            };
            vec![
                esc(&h.robot),
                num(h.change_deg, 3),
                num(h.change_mm, 2),
                format!(
                    "{} / {}",
                    num(h.distance_sigmas, 1),
                    num(h.max_distance_sigmas, 1)
                ),
                format!(
                    "{}° / {} mm ({})",
                    num(h.sigma_deg, 3),
                    num(h.sigma_mm, 2),
                    if h.sigma_stated { "stated" } else { "default" }
                ),
                format!(
                    "{} → {}",
                    num(h.median_residual_mm, 2),
                    num(h.median_residual_changed_mm, 2)
                ),
                verdict,
            ]
        })
        .collect();
    format!(
        "<p>Each robot's hand-eye refined briefly from its own depth frames: the change the frames ask for, \
         over the hand-eye's 1-σ and the fit's covariance (Mahalanobis, six parameters). A hand-eye beyond \
         the limit makes the result untrusted; the refined one is not adopted (that is \
         <code>--refine-hand-eye</code>).</p>{}",
        grid(
            &[
                "robot",
                "change (°)",
                "change (mm)",
                "distance / limit (σ)",
                "hand-eye 1-σ",
                "median residual (mm)",
                "verdict",
            ],
            &rows
        )
    )
}

/// Each robot's frames against its other frames: a chart of the per-frame median and 90th-percentile
/// residuals (mm) and a table with the free-space fractions; flagged frames in red.
pub fn consistency_section(robots: &[RobotConsistency]) -> String {
    if robots.is_empty() {
        return "<p>Not checked (the clouds were not fused, or carry no depth views).</p>".into();
    }
    let mut s = String::from(
        "<p>Each frame's depth against the robot's other frames (the trust check of <code>calibrate</code>): \
         a frame whose pose, hand-eye or intrinsics disagree stands out. Residuals in mm; free space: the \
         share of the frame's tests that lie where another frame saw through.</p>",
    );
    for r in robots {
        let ids: Vec<String> = r.frames.iter().map(|f| f.id.clone()).collect();
        let med: Vec<f64> = r.frames.iter().map(|f| f.median_residual_m * 1e3).collect();
        let p90: Vec<f64> = r.frames.iter().map(|f| f.p90_residual_m * 1e3).collect();
        let bad: Vec<bool> = r.frames.iter().map(|f| !f.consistent).collect();
        s.push_str(&format!(
            "<h3>{} — {} (median {} mm)</h3>",
            esc(&r.robot),
            if r.consistent {
                "<span class=\"good\">consistent</span>"
            } else {
                "<span class=\"bad\">NOT consistent</span>"
            },
            num(r.median_residual_m * 1e3, 3)
        ));
        s.push_str(&list(&r.findings));
        s.push_str(&bar_chart(
            &format!("{}: per-frame residual against the other frames", r.robot),
            "mm",
            &ids,
            &[
                ("median", CHART_COLOURS[1], med),
                ("90th percentile", CHART_COLOURS[2], p90),
            ],
            &bad,
        ));
        let rows: Vec<Vec<String>> = r
            .frames
            .iter()
            .map(|f| {
                vec![
                    if f.consistent {
                        esc(&f.id)
                    } else {
                        format!("<span class=\"bad\">{}</span>", esc(&f.id))
                    },
                    f.pose_line.to_string(),
                    num(f.median_residual_m * 1e3, 3),
                    num(f.p90_residual_m * 1e3, 3),
                    format!("{:.1}%", f.free_space_fraction * 1e2),
                    f.points.to_string(),
                    if f.consistent { "yes" } else { "NO" }.into(),
                ]
            })
            .collect();
        s.push_str(&details(
            &format!("{}: every frame", r.robot),
            &grid(
                &[
                    "frame",
                    "pose line",
                    "median (mm)",
                    "p90 (mm)",
                    "free space",
                    "tests",
                    "consistent",
                ],
                &rows,
            ),
        ));
    }
    s
}

/// The ICP convergence: RMS distance of the pairs and the inlier pairs per iteration, the levels one
/// after the other (distances times `scale` in `unit`), and a table per level.
pub fn convergence_section(levels: &[IcpLevelTrace], scale: f64, unit: &str) -> String {
    if levels.is_empty() {
        return "<p>Not refined: no ICP ran.</p>".into();
    }
    let mut rmse = Vec::new();
    let mut sigma = Vec::new();
    let mut pairs = Vec::new();
    let mut kept = Vec::new();
    let mut marks = Vec::new();
    let mut x = 0.0;
    for (l, lev) in levels.iter().enumerate() {
        marks.push((x, format!("level {l}")));
        for it in &lev.iterations {
            rmse.push((x, it.rmse * scale));
            sigma.push((x, it.residual_sigma * scale));
            pairs.push((x, it.pairs as f64));
            kept.push((x, it.kept as f64));
            x += 1.0;
        }
        // A break between levels.
        for s in [&mut rmse, &mut sigma, &mut pairs, &mut kept] {
            s.push((x - 0.5, f64::NAN));
        }
    }
    let rows: Vec<Vec<String>> = levels
        .iter()
        .enumerate()
        .map(|(l, lev)| {
            let last = lev.iterations.last();
            vec![
                l.to_string(),
                num(lev.voxel * scale, 3),
                num(lev.max_correspondence_distance * scale, 3),
                format!("{} / {}", lev.source_points, lev.target_points),
                (lev.iterations.len().saturating_sub(1)).to_string(),
                if lev.converged { "yes" } else { "NO" }.into(),
                last.map_or("-".into(), |i| num(i.rmse * scale, 4)),
                last.map_or("-".into(), |i| num(i.residual_sigma * scale, 4)),
                last.map_or("-".into(), |i| format!("{} / {}", i.kept, i.pairs)),
                last.map_or("-".into(), |i| num(i.fitness, 3)),
            ]
        })
        .collect();
    let u = esc(unit);
    let h = [
        "level".to_string(),
        format!("voxel ({u})"),
        format!("pair distance ({u})"),
        "source / target points".into(),
        "iterations".into(),
        "converged".into(),
        format!("pair RMS ({u})"),
        format!("residual σ ({u})"),
        "kept / pairs".into(),
        "fitness".into(),
    ];
    let h: Vec<&str> = h.iter().map(|s| s.as_str()).collect();
    format!(
        "<p>Each iteration's correspondences (source points with a target point within the level's pair \
         distance), the pairs the trimming kept, their RMS distance and the RMS residual the step \
         minimised. Coarse to fine, left to right.</p>{}{}{}",
        line_chart(
            "residual per iteration",
            "iteration (all levels)",
            unit,
            &[
                Series {
                    name: "pair RMS distance",
                    colour: CHART_COLOURS[1],
                    points: rmse,
                },
                Series {
                    name: "residual σ (kept pairs)",
                    colour: CHART_COLOURS[0],
                    points: sigma,
                },
            ],
            &marks
        ),
        line_chart(
            "inliers per iteration",
            "iteration (all levels)",
            "pairs",
            &[
                Series {
                    name: "pairs within distance",
                    colour: CHART_COLOURS[1],
                    points: pairs,
                },
                Series {
                    name: "kept by the trimming",
                    colour: CHART_COLOURS[3],
                    points: kept,
                },
            ],
            &marks
        ),
        grid(&h, &rows)
    )
}

/// The warnings and the stage timings.
pub fn log_section(warnings: &[String], timings_ms: &[(String, f64)]) -> String {
    let times: Vec<String> = timings_ms
        .iter()
        .map(|(k, v)| format!("{} {:.0} ms", esc(k), v))
        .collect();
    format!(
        "{}<p>Stage times: {}</p>",
        if warnings.is_empty() {
            "<p>No warnings.</p>".to_string()
        } else {
            format!("<h3>Warnings</h3>{}", list(warnings))
        },
        times.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::IcpIteration;

    #[test]
    fn sigma_from_a_covariance() {
        let mut c = Matrix6::zeros();
        c[(0, 0)] = 1e-6;
        c[(5, 5)] = 4e-6;
        let (r, t) = sigma(&c, 1e3);
        assert!((r[0] - 1e-3f64.to_degrees()).abs() < 1e-12);
        assert!((t[2] - 2.0).abs() < 1e-12);
    }

    #[test]
    fn convergence_has_both_charts_and_a_row_per_level() {
        let it = |r: f64| IcpIteration {
            pairs: 100,
            kept: 90,
            fitness: 0.9,
            rmse: r,
            residual_sigma: r / 2.0,
            step_rotation: None,
            step_translation: None,
            time_ms: 1.0,
        };
        let lev = IcpLevelTrace {
            voxel: 0.01,
            max_correspondence_distance: 0.03,
            source_points: 100,
            target_points: 120,
            converged: true,
            prepare_ms: 0.0,
            iterations: vec![it(0.004), it(0.002)],
        };
        let s = convergence_section(&[lev.clone(), lev], 1e3, "mm");
        assert_eq!(s.matches("<svg").count(), 2);
        assert_eq!(s.matches("<tr>").count(), 3);
        assert!(s.contains("level 1"));
    }
}
