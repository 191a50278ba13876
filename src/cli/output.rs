//! Shared output helpers for the commands: JSON shapes of transforms and matrices, progress spinners.

use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::{Isometry3, Matrix6};
use std::time::Duration;

/// Reads a JSON configuration file of type `T` (missing fields take their defaults), or the defaults when
/// no file is given; errors name the file.
pub fn read_config<T: serde::de::DeserializeOwned + Default>(
    path: Option<&std::path::Path>,
    what: &str,
) -> anyhow::Result<T> {
    use anyhow::Context;
    let Some(p) = path else {
        return Ok(T::default());
    };
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not a valid {what}", p.display()))
}

/// An ambiguity (runner-up transform, score ratio, distance) as JSON; the translation under `key`, scaled by
/// `scale` (e.g. `translation_mm`, 1e3 for a cell in metres).
pub fn ambiguity_json(
    a: &depthcal::registration::pipeline::Ambiguity,
    key: &str,
    scale: f64,
) -> serde_json::Value {
    let mut v = serde_json::json!({
        "runner_up": matrix4_json(&a.runner_up),
        "score_ratio": a.score_ratio,
        "rotation_deg": a.rotation_deg,
    });
    v[key] = (a.translation * scale).into();
    v
}

/// A 4x4 row-major nested array.
pub fn matrix4_json(t: &Isometry3<f64>) -> serde_json::Value {
    serde_json::json!(depthcal::geometry::transform::isometry_to_nested(t))
}

/// A 6x6 nested array.
pub fn matrix6_json(m: &Matrix6<f64>) -> serde_json::Value {
    let rows: Vec<Vec<f64>> = (0..6)
        .map(|r| (0..6).map(|c| m[(r, c)]).collect())
        .collect();
    serde_json::json!(rows)
}

/// Stage timings as an ordered JSON object.
pub fn timings_json(t: &[(String, f64)]) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for (k, v) in t {
        m.insert(k.clone(), serde_json::json!((v * 1000.0).round() / 1000.0));
    }
    serde_json::Value::Object(m)
}

/// A spinner on stderr (drawn only when stderr is a terminal).
pub fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(Duration::from_millis(120));
    pb
}

/// The rows of a 4x4 matrix as text lines.
pub fn matrix4_text(t: &Isometry3<f64>) -> String {
    let m = depthcal::geometry::transform::isometry_to_nested(t);
    m.iter()
        .map(|r| {
            format!(
                "  {:>12.8} {:>12.8} {:>12.8} {:>12.6}",
                r[0], r[1], r[2], r[3]
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}
