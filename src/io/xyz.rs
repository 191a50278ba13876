//! Plain text clouds: one point per line, `x y z` separated by whitespace or commas; further columns are
//! ignored; blank lines and lines starting with `#` or `//` are skipped, and so is a first line that is a header.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::io::Write;
use std::path::Path;

pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let text = std::str::from_utf8(bytes).map_err(|_| Error::format(path, "not a text file"))?;
    let mut points = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let mut toks = line
            .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
            .filter(|s| !s.is_empty());
        let mut p = [0f32; 3];
        let mut ok = true;
        for (axis, v) in p.iter_mut().enumerate() {
            match toks.next().map(|t| t.parse::<f32>()) {
                Some(Ok(x)) => *v = x,
                Some(Err(_)) | None => {
                    ok = false;
                    if !(points.is_empty() && k == 0) {
                        return Err(Error::format(
                            path,
                            format!(
                                "line {}: expected x y z numbers, coordinate {} is missing or not a number",
                                k + 1,
                                ["x", "y", "z"][axis]
                            ),
                        ));
                    }
                    break;
                }
            }
        }
        if ok {
            points.push(p);
        }
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
