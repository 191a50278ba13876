//! Small inline SVG charts for the report page: line charts (ICP convergence), grouped bars (per-frame
//! consistency) and histograms (residuals). Plain text, no script: they show with JavaScript off.

use super::page::esc;
use std::fmt::Write;

/// Chart size in CSS pixels and the margins of the plot area (left, right, top, bottom).
const W: f64 = 760.0;
const H: f64 = 260.0;
const M: (f64, f64, f64, f64) = (64.0, 16.0, 28.0, 44.0);

/// About `n` round tick values covering `[lo, hi]`.
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let p = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * p);
    let mut v = Vec::new();
    let mut t = (lo / step).ceil() * step;
    while t <= hi + step * 1e-9 {
        v.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    v
}

/// A tick label: as few decimals as the step needs.
fn label(v: f64, step: f64) -> String {
    let dec = if step >= 1.0 {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    format!("{v:.dec$}")
}

/// The frame of a chart: axes, ticks, labels and a title; returns the SVG so far and the mapping of data
/// to pixels.
struct Frame {
    out: String,
    x: (f64, f64),
    y: (f64, f64),
}

impl Frame {
    fn new(
        title: &str,
        x: (f64, f64),
        y: (f64, f64),
        x_label: &str,
        y_label: &str,
        x_ticks: bool,
    ) -> Self {
        let mut out = String::new();
        let _ = write!(
            out,
            r#"<svg class="chart" viewBox="0 0 {W} {H}" width="{W}" height="{H}" role="img" aria-label="{t}"><text x="{M0}" y="16" class="title">{t}</text>"#,
            t = esc(title),
            M0 = M.0
        );
        let mut f = Frame { out, x, y };
        let (x0, x1, y0, y1) = (M.0, W - M.1, H - M.3, M.2);
        let _ = write!(
            f.out,
            r#"<rect x="{x0}" y="{y1}" width="{}" height="{}" class="plot"/>"#,
            x1 - x0,
            y0 - y1
        );
        let yt = ticks(y.0, y.1, 5);
        let ys = yt.get(1).map_or(1.0, |b| b - yt[0]);
        for t in &yt {
            let py = f.py(*t);
            let _ = write!(
                f.out,
                r#"<line x1="{x0}" x2="{x1}" y1="{py:.1}" y2="{py:.1}" class="grid"/><text x="{}" y="{:.1}" class="tick" text-anchor="end">{}</text>"#,
                x0 - 6.0,
                py + 4.0,
                label(*t, ys)
            );
        }
        let xt = if x_ticks {
            ticks(x.0, x.1, 8)
        } else {
            Vec::new()
        };
        let xs = xt.get(1).map_or(1.0, |b| b - xt[0]);
        for t in &xt {
            let px = f.px(*t);
            let _ = write!(
                f.out,
                r#"<text x="{px:.1}" y="{}" class="tick" text-anchor="middle">{}</text>"#,
                y0 + 16.0,
                label(*t, xs)
            );
        }
        let _ = write!(
            f.out,
            r#"<text x="{:.1}" y="{}" class="axis" text-anchor="middle">{}</text><text x="14" y="{:.1}" class="axis" text-anchor="middle" transform="rotate(-90 14 {:.1})">{}</text>"#,
            (x0 + x1) / 2.0,
            H - 6.0,
            esc(x_label),
            (y0 + y1) / 2.0,
            (y0 + y1) / 2.0,
            esc(y_label)
        );
        f
    }

    fn px(&self, v: f64) -> f64 {
        let (a, b) = self.x;
        M.0 + (v - a) / (b - a).max(1e-300) * (W - M.1 - M.0)
    }

    fn py(&self, v: f64) -> f64 {
        let (a, b) = self.y;
        (H - M.3) - (v - a) / (b - a).max(1e-300) * (H - M.3 - M.2)
    }

    fn legend(&mut self, entries: &[(&str, &str)]) {
        let mut x = W - M.1 - 8.0;
        for (name, colour) in entries.iter().rev() {
            let w = 7.0 * name.chars().count() as f64 + 22.0;
            x -= w;
            let _ = write!(
                self.out,
                r#"<rect x="{x:.1}" y="8" width="12" height="10" fill="{colour}"/><text x="{:.1}" y="17" class="tick">{}</text>"#,
                x + 16.0,
                esc(name)
            );
        }
    }

    fn finish(mut self) -> String {
        self.out.push_str("</svg>");
        self.out
    }
}

/// A line series: name, CSS colour, points (x, y).
pub struct Series<'a> {
    /// The legend's name.
    pub name: &'a str,
    /// CSS colour.
    pub colour: &'a str,
    /// The points; a NaN y breaks the line.
    pub points: Vec<(f64, f64)>,
}

/// A line chart with vertical markers `marks` (x, label), e.g. the start of each ICP level.
pub fn line_chart(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    marks: &[(f64, String)],
) -> String {
    let all = || {
        series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| p.1.is_finite())
    };
    let x1 = all().map(|p| p.0).fold(1.0, f64::max);
    let y1 = all().map(|p| p.1).fold(0.0, f64::max);
    let y1 = if y1 > 0.0 { y1 * 1.08 } else { 1.0 };
    let mut f = Frame::new(title, (0.0, x1), (0.0, y1), x_label, y_label, true);
    for (x, text) in marks {
        let px = f.px(*x);
        let _ = write!(
            f.out,
            r#"<line x1="{px:.1}" x2="{px:.1}" y1="{}" y2="{}" class="mark"/><text x="{:.1}" y="{}" class="tick">{}</text>"#,
            M.2,
            H - M.3,
            px + 3.0,
            M.2 + 12.0,
            esc(text)
        );
    }
    for s in series {
        let mut d = String::new();
        let mut pen = false;
        for &(x, y) in &s.points {
            if !y.is_finite() {
                pen = false;
                continue;
            }
            let _ = write!(
                d,
                "{}{:.1},{:.1} ",
                if pen { "L" } else { "M" },
                f.px(x),
                f.py(y)
            );
            pen = true;
        }
        let _ = write!(
            f.out,
            r#"<path d="{}" fill="none" stroke="{}" stroke-width="1.6"/>"#,
            d.trim_end(),
            s.colour
        );
    }
    let entries: Vec<(&str, &str)> = series.iter().map(|s| (s.name, s.colour)).collect();
    f.legend(&entries);
    f.finish()
}

/// Grouped bars: one group per category, one bar per series; flagged categories are labelled in red.
pub fn bar_chart(
    title: &str,
    y_label: &str,
    categories: &[String],
    series: &[(&str, &str, Vec<f64>)],
    flagged: &[bool],
) -> String {
    let y1 = series
        .iter()
        .flat_map(|s| s.2.iter())
        .filter(|v| v.is_finite())
        .fold(0.0, |a: f64, &b| a.max(b));
    let y1 = if y1 > 0.0 { y1 * 1.1 } else { 1.0 };
    let n = categories.len().max(1) as f64;
    let mut f = Frame::new(title, (0.0, n), (0.0, y1), "frame", y_label, false);
    let group = (W - M.1 - M.0) / n;
    let bw = (group * 0.8 / series.len().max(1) as f64).max(1.0);
    for (i, c) in categories.iter().enumerate() {
        let gx = M.0 + group * i as f64 + group * 0.1;
        for (k, (_, colour, values)) in series.iter().enumerate() {
            let v = values.get(i).copied().unwrap_or(f64::NAN);
            if !v.is_finite() {
                continue;
            }
            let top = f.py(v);
            let _ = write!(
                f.out,
                r#"<rect x="{:.1}" y="{top:.1}" width="{bw:.1}" height="{:.1}" fill="{colour}"><title>{}: {v:.3}</title></rect>"#,
                gx + bw * k as f64,
                (H - M.3) - top,
                esc(c)
            );
        }
        let bad = flagged.get(i).copied().unwrap_or(false);
        let every = (categories.len() / 30).max(1);
        if bad || i % every == 0 {
            let _ = write!(
                f.out,
                r#"<text x="{:.1}" y="{}" class="{}" text-anchor="middle">{}</text>"#,
                gx + group * 0.4,
                H - M.3 + 15.0,
                if bad { "tick bad" } else { "tick" },
                esc(c)
            );
        }
    }
    let entries: Vec<(&str, &str)> = series.iter().map(|s| (s.0, s.1)).collect();
    f.legend(&entries);
    f.finish()
}

/// Histograms drawn as outlined step curves over the same bins: `(name, colour, counts)`, bins spanning
/// `[0, max]`.
pub fn histogram(title: &str, x_label: &str, max: f64, hists: &[(&str, &str, &[usize])]) -> String {
    let bins = hists.iter().map(|h| h.2.len()).max().unwrap_or(1).max(1);
    let y1 = hists
        .iter()
        .flat_map(|h| h.2.iter())
        .copied()
        .max()
        .unwrap_or(0) as f64;
    let y1 = if y1 > 0.0 { y1 * 1.08 } else { 1.0 };
    let mut f = Frame::new(title, (0.0, max), (0.0, y1), x_label, "points", true);
    let bw = max / bins as f64;
    for (_, colour, counts) in hists {
        let mut d = format!("M{:.1},{:.1} ", f.px(0.0), f.py(0.0));
        for (k, &c) in counts.iter().enumerate() {
            let (a, b) = (bw * k as f64, bw * (k + 1) as f64);
            let _ = write!(
                d,
                "L{:.1},{:.1} L{:.1},{:.1} ",
                f.px(a),
                f.py(c as f64),
                f.px(b),
                f.py(c as f64)
            );
        }
        let _ = write!(d, "L{:.1},{:.1}", f.px(max), f.py(0.0));
        let _ = write!(
            f.out,
            r#"<path d="{d}" fill="{colour}" fill-opacity="0.25" stroke="{colour}" stroke-width="1.5"/>"#
        );
    }
    let entries: Vec<(&str, &str)> = hists.iter().map(|h| (h.0, h.1)).collect();
    f.legend(&entries);
    f.finish()
}

/// A node of [`graph_top_view`]: its name, where it stands (x, y in metres, `None`: no position) and its
/// CSS colour.
pub struct GraphNode {
    /// The label.
    pub name: String,
    /// Position seen from above, metres.
    pub at: Option<[f64; 2]>,
    /// CSS colour.
    pub colour: String,
}

/// An edge of [`graph_top_view`] between two nodes (indices), drawn in a CSS colour, dashed or not, with a
/// label at its middle.
pub struct GraphEdgeMark {
    /// One end.
    pub from: usize,
    /// The other end.
    pub to: usize,
    /// CSS colour.
    pub colour: String,
    /// Dashed (an edge the solution does not use).
    pub dashed: bool,
    /// Text at the middle (empty: none).
    pub label: String,
}

/// A graph seen from above at true scale (equal x and y units, y up): nodes with a position where they
/// stand, nodes without one in a row below the plot, edges as lines between them.
pub fn graph_top_view(title: &str, nodes: &[GraphNode], edges: &[GraphEdgeMark]) -> String {
    const GH: f64 = 380.0;
    const ROW: f64 = 40.0;
    let placed: Vec<[f64; 2]> = nodes.iter().filter_map(|n| n.at).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &placed {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if placed.is_empty() {
        lo = [-1.0, -1.0];
        hi = [1.0, 1.0];
    }
    let has_row = nodes.iter().any(|n| n.at.is_none());
    let (x0, x1) = (M.0 + 20.0, W - M.1 - 60.0);
    let (y_top, y_bottom) = (M.2 + 20.0, GH - 30.0 - if has_row { ROW } else { 0.0 });
    let (dx, dy) = ((hi[0] - lo[0]).max(1e-3), (hi[1] - lo[1]).max(1e-3));
    let scale = ((x1 - x0) / dx).min((y_bottom - y_top) / dy);
    let (cx, cy) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
    let mut unplaced = 0usize;
    let pos: Vec<(f64, f64)> = nodes
        .iter()
        .map(|n| match n.at {
            Some(p) => (
                (x0 + x1) / 2.0 + (p[0] - cx) * scale,
                (y_top + y_bottom) / 2.0 - (p[1] - cy) * scale,
            ),
            None => {
                unplaced += 1;
                (x0 + 110.0 * (unplaced - 1) as f64, GH - 24.0)
            }
        })
        .collect();
    let mut out = String::new();
    let _ = write!(
        out,
        r#"<svg class="chart" viewBox="0 0 {W} {GH}" width="{W}" height="{GH}" role="img" aria-label="{t}"><text x="{M0}" y="16" class="title">{t}</text><rect x="{M0}" y="{M2}" width="{}" height="{}" class="plot"/>"#,
        W - M.1 - M.0,
        GH - 30.0 - M.2 - if has_row { ROW } else { 0.0 } + 10.0,
        t = esc(title),
        M0 = M.0,
        M2 = M.2,
    );
    if has_row {
        let _ = write!(
            out,
            r#"<text x="{}" y="{:.1}" class="tick">no pose:</text>"#,
            M.0 - 56.0,
            GH - 20.0
        );
    }
    for e in edges {
        let (Some(a), Some(b)) = (pos.get(e.from), pos.get(e.to)) else {
            continue;
        };
        let _ = write!(
            out,
            r#"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{}" stroke-width="2.5"{}/>"#,
            a.0,
            a.1,
            b.0,
            b.1,
            esc(&e.colour),
            if e.dashed {
                r#" stroke-dasharray="6 4""#
            } else {
                ""
            }
        );
        if !e.label.is_empty() {
            let _ = write!(
                out,
                r#"<text x="{:.1}" y="{:.1}" class="tick" text-anchor="middle">{}</text>"#,
                (a.0 + b.0) / 2.0,
                (a.1 + b.1) / 2.0 - 4.0,
                esc(&e.label)
            );
        }
    }
    for (n, p) in nodes.iter().zip(&pos) {
        let _ = write!(
            out,
            r#"<circle cx="{:.1}" cy="{:.1}" r="7" fill="{c}" stroke="black"/><text x="{:.1}" y="{:.1}" class="axis">{}</text>"#,
            p.0,
            p.1,
            p.0 + 10.0,
            p.1 + 4.0,
            esc(&n.name),
            c = esc(&n.colour),
        );
    }
    out.push_str("</svg>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 10.0, 5), vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
        let t = ticks(0.0, 0.37, 4);
        assert_eq!(t.len(), 4);
        assert!((t[1] - 0.1).abs() < 1e-12);
        assert_eq!(label(0.30000000000000004, 0.1), "0.3");
    }

    #[test]
    fn charts_are_well_formed_and_escape_text() {
        let s = line_chart(
            "a <b>",
            "iteration",
            "mm",
            &[Series {
                name: "x&y",
                colour: "#f00",
                points: vec![(0.0, 1.0), (1.0, f64::NAN), (2.0, 0.5)],
            }],
            &[(1.0, "level 1".into())],
        );
        assert!(s.starts_with("<svg") && s.ends_with("</svg>"));
        assert!(s.contains("a &lt;b&gt;") && s.contains("x&amp;y"));
        assert_eq!(s.matches("<path").count(), 1);
        let b = bar_chart(
            "c",
            "mm",
            &["f0".into(), "f1".into()],
            &[("median", "#00f", vec![1.0, 2.0])],
            &[false, true],
        );
        assert_eq!(b.matches("<rect x=").count(), 2 + 1 + 1, "{b}");
        assert!(b.contains("tick bad"));
        let h = histogram("h", "mm", 2.0, &[("a", "#0f0", &[1, 2, 3])]);
        assert!(h.contains("<path"));
        let node = |name: &str, at| GraphNode {
            name: name.into(),
            at,
            colour: "#f80".into(),
        };
        let g = graph_top_view(
            "g",
            &[
                node("a", Some([0.0, 0.0])),
                node("b<", Some([2.0, 0.0])),
                node("c", None),
            ],
            &[
                GraphEdgeMark {
                    from: 0,
                    to: 1,
                    colour: "#0a0".into(),
                    dashed: false,
                    label: "0.01°".into(),
                },
                GraphEdgeMark {
                    from: 1,
                    to: 2,
                    colour: "#aaa".into(),
                    dashed: true,
                    label: String::new(),
                },
            ],
        );
        assert!(g.starts_with("<svg") && g.ends_with("</svg>"));
        assert_eq!(g.matches("<circle").count(), 3);
        assert_eq!(g.matches("<line").count(), 2);
        assert!(g.contains("b&lt;") && g.contains("no pose:") && g.contains("stroke-dasharray"));
        // True scale: a and b stand 2 m apart on one row, their circles on one line.
        let ys: Vec<&str> = g
            .match_indices("cy=\"")
            .map(|(i, _)| &g[i + 4..i + 9])
            .collect();
        assert_eq!(ys[0], ys[1]);
    }
}
