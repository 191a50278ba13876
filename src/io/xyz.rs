//! Plain text clouds: one point per line, `x y z` separated by whitespace or commas; further columns are
//! ignored; blank lines and lines starting with `#` or `//` are skipped, and so is a first line
//! that is a header (names only, no number); any other line that is not x y z numbers is an error naming it.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::io::Write;
use std::path::Path;

pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let text = std::str::from_utf8(bytes).map_err(|_| Error::format(path, "not a text file"))?;
    let mut points = Vec::new();
    let mut first = true;
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let toks: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|s| !s.is_empty())
            .collect();
        let is_first = std::mem::replace(&mut first, false);
        let mut p = [0f32; 3];
        let mut bad = None;
        for (axis, v) in p.iter_mut().enumerate() {
            match toks.get(axis).map(|t| t.parse::<f32>()) {
                Some(Ok(x)) => *v = x,
                Some(Err(_)) | None => {
                    bad = Some(axis);
                    break;
                }
            }
        }
        let Some(axis) = bad else {
            points.push(p);
            continue;
        };
        // Only a first line made of names alone (`x y z`, `X,Y,Z,intensity`) is a header.
        if is_first && toks.iter().all(|t| t.parse::<f64>().is_err()) {
            continue;
        }
        let what = match toks.get(axis) {
            Some(t) => format!("`{t}` is not a number"),
            None => "is missing".to_string(),
        };
        return Err(Error::format(
            path,
            format!(
                "line {}: expected x y z numbers, coordinate {} {what}",
                k + 1,
                ["x", "y", "z"][axis]
            ),
        ));
    }
    if points.is_empty() {
        return Err(Error::format(path, "no points found"));
    }
    Ok(PointCloud::from_points(points))
}

pub(super) fn write(w: &mut dyn Write, cloud: &PointCloud) -> std::io::Result<()> {
    for p in &cloud.points {
        writeln!(w, "{} {} {}", p[0], p[1], p[2])?;
    }
    Ok(())
}
