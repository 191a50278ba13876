//! The HTML page: one self-contained file (inline CSS, inline script, the scene as inline JSON, charts as
//! inline SVG), with a Content-Security-Policy that forbids every network request, so that it opens the same
//! offline as online.

use super::render::{self, point_size};
use super::scene::{Scene, Shape};
use serde_json::{json, Value};

/// The viewer canvas size, CSS pixels.
pub const VIEWER_SIZE: (u32, u32) = (880, 560);

const CSS: &str = include_str!("report.css");
const VIEWER_JS: &str = include_str!("viewer.js");

/// `s` escaped for HTML text and attribute values.
pub fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut o = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                o.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                o.push('=');
            }
        }
    }
    o
}

/// A number with `dec` decimals (`-` for NaN).
pub fn num(v: f64, dec: usize) -> String {
    if v.is_finite() {
        crate::geometry::robot_formats::fixed(v, dec)
    } else {
        "-".into()
    }
}

/// A two-column table of `(label, value HTML)` rows; values are HTML (escape text with [`esc`]).
pub fn table(rows: &[(&str, String)]) -> String {
    let mut s = String::from("<table class=\"kv\">");
    for (k, v) in rows {
        s.push_str(&format!("<tr><th>{}</th><td>{v}</td></tr>", esc(k)));
    }
    s.push_str("</table>");
    s
}

/// A table with a header row; cells are HTML.
pub fn grid(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table class=\"grid\"><tr>");
    for h in header {
        s.push_str(&format!("<th>{}</th>", esc(h)));
    }
    s.push_str("</tr>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            s.push_str(&format!("<td>{c}</td>"));
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

/// Preformatted text.
pub fn pre(text: &str) -> String {
    format!("<pre>{}</pre>", esc(text.trim_end()))
}

/// A collapsible block.
pub fn details(summary: &str, inner: &str) -> String {
    format!(
        "<details><summary>{}</summary>{inner}</details>",
        esc(summary)
    )
}

/// A list of text items (empty: nothing).
pub fn list(items: &[String]) -> String {
    if items.is_empty() {
        return String::new();
    }
    let li: String = items
        .iter()
        .map(|i| format!("<li>{}</li>", esc(i)))
        .collect();
    format!("<ul>{li}</ul>")
}

/// The verdict at the top of the page: trusted, or NOT TRUSTED with the reasons and what to try.
pub fn banner(trusted: bool, what: &str, reasons: &[String], suggestions: &[String]) -> String {
    if trusted {
        format!(
            "<div class=\"verdict ok\" id=\"verdict\" data-trusted=\"true\"><strong>TRUSTED</strong> {}</div>",
            esc(what)
        )
    } else {
        let tries: Vec<String> = suggestions.iter().map(|s| format!("try: {s}")).collect();
        format!(
            "<div class=\"verdict bad\" id=\"verdict\" data-trusted=\"false\"><strong>NOT TRUSTED</strong> {} \
             Do not use this transform before the reasons below are resolved; the views are shown so that \
             you can see what went wrong.{}{}</div>",
            esc(what),
            list(reasons),
            list(&tries)
        )
    }
}

/// A section with a heading.
pub fn section(id: &str, title: &str, inner: &str) -> String {
    format!(
        "<section id=\"{}\"><h2>{}</h2>{inner}</section>",
        esc(id),
        esc(title)
    )
}

/// The scene as the viewer reads it: each point set quantised to 16 bits per coordinate over its bounding
/// box, each residual array to 16 bits (65535: no counterpart), both base64; items with their row-major
/// 4x4 transforms.
pub fn scene_json(scene: &Scene) -> Value {
    let sets: Vec<Value> = scene
        .sets
        .iter()
        .map(|s| {
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for p in &s.points {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            if s.points.is_empty() {
                lo = [0.0; 3];
                hi = [0.0; 3];
            }
            let scale: [f64; 3] = std::array::from_fn(|k| {
                let e = (hi[k] as f64 - lo[k] as f64) / 65535.0;
                if e > 0.0 {
                    e
                } else {
                    1.0
                }
            });
            let mut bytes = Vec::with_capacity(s.points.len() * 6);
            for p in &s.points {
                for k in 0..3 {
                    let q = ((p[k] as f64 - lo[k] as f64) / scale[k])
                        .round()
                        .clamp(0.0, 65535.0);
                    bytes.extend_from_slice(&(q as u16).to_le_bytes());
                }
            }
            json!({
                "name": s.name,
                "count": s.points.len(),
                "original": s.original,
                "origin": lo.map(|v| v as f64),
                "scale": scale,
                "data": base64(&bytes),
            })
        })
        .collect();
    // Residuals up to 6.5 x the colour scale's maximum keep 1e-4 of it; beyond, they clamp (the colour does).
    let quantum = scene.residual_max / 1e4;
    let residuals: Vec<Value> = scene
        .residuals
        .iter()
        .map(|r| {
            let mut bytes = Vec::with_capacity(r.values.len() * 2);
            for v in &r.values {
                let q = if v.is_nan() {
                    65535
                } else {
                    ((*v as f64 / quantum).round().clamp(0.0, 65534.0)) as u16
                };
                bytes.extend_from_slice(&q.to_le_bytes());
            }
            json!({"name": r.name, "quantum": quantum, "data": base64(&bytes)})
        })
        .collect();
    let items: Vec<Value> = scene
        .items
        .iter()
        .map(|i| {
            let m = crate::geometry::transform::isometry_to_rows(&i.transform);
            let mut v = json!({
                "name": i.name,
                "transform": m.to_vec(),
                "rgb": i.rgb,
                "visible": i.visible,
            });
            match &i.shape {
                Shape::Points { set, residual } => {
                    v["kind"] = json!("points");
                    v["set"] = json!(set);
                    v["residual"] = json!(residual);
                }
                Shape::Lines(seg) => {
                    v["kind"] = json!("lines");
                    let flat: Vec<Value> = seg
                        .iter()
                        .map(|s| {
                            json!([
                                s.a[0], s.a[1], s.a[2], s.b[0], s.b[1], s.b[2], s.rgb[0], s.rgb[1],
                                s.rgb[2]
                            ])
                        })
                        .collect();
                    v["segments"] = json!(flat);
                }
            }
            v
        })
        .collect();
    let visible = scene.visible_point_count();
    json!({
        "camera": scene.camera,
        "width": VIEWER_SIZE.0,
        "height": VIEWER_SIZE.1,
        "fill": render::FILL,
        "depth_bias": render::DEPTH_BIAS,
        "point_size": point_size(visible, VIEWER_SIZE.0, VIEWER_SIZE.1),
        "residual_max": scene.residual_max,
        "residual_unit": scene.residual_unit,
        "colormap": render::COLORMAP,
        "background": render::BACKGROUND,
        "unmatched": render::UNMATCHED,
        "reference_grey": render::REFERENCE_GREY,
        "visible_points": visible,
        "sets": sets,
        "residuals": residuals,
        "items": items,
    })
}

/// The viewer's markup: the canvas, its controls and the residual colour scale.
pub fn viewer(scene: &Scene) -> String {
    let stops: Vec<String> = render::COLORMAP
        .iter()
        .enumerate()
        .map(|(k, c)| {
            format!(
                "rgb({},{},{}) {:.1}%",
                c[0],
                c[1],
                c[2],
                100.0 * k as f64 / (render::COLORMAP.len() - 1) as f64
            )
        })
        .collect();
    let u = render::UNMATCHED;
    let has_residual = !scene.residuals.is_empty();
    format!(
        "<div class=\"viewer\"><canvas id=\"viewer\" width=\"{w}\" height=\"{h}\"></canvas>\
         <div class=\"controls\"><div id=\"viewer-items\"></div>\
         <label>colour <select id=\"colouring\"><option value=\"item\">by cloud</option>{opt}</select></label>\
         <label>point size <input id=\"point-size\" type=\"range\" min=\"1\" max=\"8\" step=\"1\"></label>\
         <button id=\"reset\" type=\"button\">reset view</button>\
         <p class=\"hint\">drag: orbit · shift-drag or right-drag: pan · wheel: zoom · double-click: reset</p>\
         <div class=\"scale\"><div class=\"bar\" style=\"background:linear-gradient(to right,{stops})\"></div>\
         <span>0</span><span class=\"max\">{max} {unit}</span>\
         <p><span class=\"swatch\" style=\"background:rgb({},{},{})\"></span> no counterpart within reach</p></div>\
         <p id=\"viewer-status\">not drawn: the 3-D view needs JavaScript</p>\
         <p>points drawn: <span id=\"points-drawn\">0</span> of <span id=\"points-embedded\">{n}</span> shown \
         ({total} embedded)</p></div></div>",
        u[0],
        u[1],
        u[2],
        w = VIEWER_SIZE.0,
        h = VIEWER_SIZE.1,
        opt = if has_residual {
            "<option value=\"residual\">residual</option>"
        } else {
            ""
        },
        stops = stops.join(","),
        max = render::format_scale(scene.residual_max),
        unit = esc(&scene.residual_unit),
        n = scene.visible_point_count(),
        total = scene.sets.iter().map(|s| s.points.len()).sum::<usize>(),
    )
}

/// JSON text that is safe inside a `<script>` element: `<` is written as `\u003c` (only ever inside
/// strings), so no `</script>` can end the element early.
fn script_json(v: &Value) -> String {
    v.to_string().replace('<', "\\u003c")
}

/// The whole page: `title`, the body sections, and the data the script reads (`scene` for the viewer).
pub fn document(title: &str, body: &str, data: &Value) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; script-src 'unsafe-inline'; \
         style-src 'unsafe-inline'; img-src data:\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{t}</title><style>{CSS}</style></head><body>{body}\
         <footer>Written by depthcal {v}. Self-contained: no network access; the PNG snapshots beside this file \
         (overview.png, initial.png, residual.png) show the same views.</footer>\
         <script type=\"application/json\" id=\"report-data\">{data}</script>\
         <script>{VIEWER_JS}</script></body></html>\n",
        t = esc(title),
        v = env!("CARGO_PKG_VERSION"),
        data = script_json(data),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (a, b) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(a.as_bytes()), b);
        }
    }

    #[test]
    fn escaping() {
        assert_eq!(
            esc("<a href='x'>&\"</a>"),
            "&lt;a href=&#39;x&#39;&gt;&amp;&quot;&lt;/a&gt;"
        );
        let v = json!({"w": "</script><b>"});
        let s = script_json(&v);
        assert!(!s.contains("</script>"));
        let back: Value = serde_json::from_str(&s).unwrap();
        assert_eq!(back, v);
    }
}
