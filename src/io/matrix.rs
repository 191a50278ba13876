//! 4x4 transform files: 16 numbers (whitespace, comma or bracket separated), row-major.
//!
//! Accepts plain text matrices (as `T_target_source.txt` files carry), a JSON array of 16 numbers or of 4
//! rows, and a JSON object with a `transform` field (so a `register --json` output can be fed back as
//! `--init`).

use crate::error::{Error, Result};
use crate::geometry::transform::{isometry_from_rows, isometry_to_rows};
use nalgebra::Isometry3;
use std::path::Path;

/// Reads a rigid 4x4 transform from `path` (see the module docs for accepted layouts).
pub fn read_matrix_file(path: impl AsRef<Path>) -> Result<Isometry3<f64>> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_matrix(&text, path)
}

/// Parses the text of a transform file (see the module docs); `path` names it in errors.
pub fn parse_matrix(text: &str, path: impl AsRef<Path>) -> Result<Isometry3<f64>> {
    let path = path.as_ref();
    let values = parse_matrix_text(text).map_err(|msg| Error::format(path, msg))?;
    isometry_from_rows(&values, &path.display().to_string())
}

fn parse_matrix_text(text: &str) -> std::result::Result<[f64; 16], String> {
    let trimmed = text.trim_start();
    let numbers: Vec<f64> = if trimmed.starts_with('{') {
        let v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("invalid JSON: {e}"))?;
        let t = v
            .get("transform")
            .ok_or("JSON object has no `transform` field")?;
        return matrix_from_json(t).map_err(|m| format!("`transform`: {m}"));
    } else {
        let mut out = Vec::new();
        for (lineno, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("");
            for tok in line
                .split(|c: char| c.is_whitespace() || c == ',' || c == '[' || c == ']' || c == ';')
                .filter(|s| !s.is_empty())
            {
                out.push(
                    tok.parse::<f64>()
                        .map_err(|_| format!("line {}: `{tok}` is not a number", lineno + 1))?,
                );
                if out.len() > 16 {
                    return Err(format!(
                        "line {}: more than 16 numbers (expected a 4x4 row-major matrix)",
                        lineno + 1
                    ));
                }
            }
        }
        out
    };
    if numbers.len() != 16 {
        return Err(format!(
            "expected 16 numbers (a 4x4 row-major matrix), found {}",
            numbers.len()
        ));
    }
    let mut m = [0.0; 16];
    m.copy_from_slice(&numbers);
    Ok(m)
}

/// The 4x4 row-major matrix of a JSON value: 16 numbers, 4 rows of 4 numbers, or a pose object of the
/// reports (`{"matrix": [[...]], ...}`).
pub fn matrix_from_json(v: &serde_json::Value) -> std::result::Result<[f64; 16], String> {
    let numbers = match v {
        serde_json::Value::Object(o) => match o.get("matrix") {
            Some(m) => return matrix_from_json(m),
            None => return Err("expected a 4x4 matrix or an object with a `matrix` field".into()),
        },
        serde_json::Value::Array(a) if a.len() == 4 && a.iter().all(|r| r.is_array()) => {
            let mut out = Vec::with_capacity(16);
            for row in a {
                let r = row.as_array().filter(|r| r.len() == 4);
                let r = r.ok_or("each of the 4 rows must hold 4 numbers")?;
                out.extend(flatten_json(&serde_json::Value::Array(r.clone()))?);
            }
            out
        }
        serde_json::Value::Array(_) => flatten_json(v)?,
        _ => {
            return Err("expected a 4x4 matrix: 16 numbers row-major or 4 rows of 4 numbers".into())
        }
    };
    if numbers.len() != 16 {
        return Err(format!(
            "expected 16 numbers (a 4x4 row-major matrix), found {}",
            numbers.len()
        ));
    }
    let mut m = [0.0; 16];
    m.copy_from_slice(&numbers);
    Ok(m)
}

fn flatten_json(v: &serde_json::Value) -> std::result::Result<Vec<f64>, String> {
    match v {
        serde_json::Value::Array(items) => {
            let mut out = Vec::new();
            for it in items {
                out.extend(flatten_json(it)?);
            }
            Ok(out)
        }
        serde_json::Value::Number(n) => n
            .as_f64()
            .map(|x| vec![x])
            .ok_or_else(|| "bad number".to_string()),
        other => Err(format!("a non-number: {other}")),
    }
}

/// Writes a transform as a 4x4 text matrix, atomically.
pub fn write_matrix_file(path: impl AsRef<Path>, t: &Isometry3<f64>) -> Result<()> {
    let m = isometry_to_rows(t);
    super::write_atomically(path.as_ref(), |w| {
        for r in 0..4 {
            writeln!(
                w,
                "{:.12} {:.12} {:.12} {:.12}",
                m[r * 4],
                m[r * 4 + 1],
                m[r * 4 + 2],
                m[r * 4 + 3]
            )?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_text_and_json() {
        let t = "1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n";
        assert_eq!(parse_matrix_text(t).unwrap()[3], 1.0);
        let j = r#"{"transform": [[1,0,0,1],[0,1,0,2],[0,0,1,3],[0,0,0,1]], "fitness": 1}"#;
        assert_eq!(parse_matrix_text(j).unwrap()[11], 3.0);
        assert!(parse_matrix_text("1 2 3").is_err());
        assert!(parse_matrix_text("1 2 x").unwrap_err().contains("line 1"));
    }
}
