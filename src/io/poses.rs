//! Pose files: one robot (or target) pose per frame, one row each under a header, in the formats of
//! [`PoseFormat`] (KUKA XYZ-ABC, 4x4 matrices, x,y,z + quaternion, UR, ABB, Fanuc). The conversions
//! between each format's numbers and an [`Isometry3`] are [`crate::geometry::pose`].

use crate::error::{Error, Result};
use crate::geometry::pose::*;
use crate::geometry::transform::{isometry_from_rows, isometry_to_rows};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// A pose file format (one row per frame, with a header).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseFormat {
    /// `frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg` — KUKA XYZ-ABC (default).
    #[default]
    Kuka,
    /// `frame,m00,m01,...,m33` — the 4x4 matrix row-major, metres.
    Matrix,
    /// `frame,x,y,z,qx,qy,qz,qw` — position in metres and a unit quaternion.
    Xyzquat,
    /// `frame,x,y,z,rx,ry,rz` — Universal Robots pose vector: metres and a rotation vector in radians.
    Ur,
    /// `frame,x_mm,y_mm,z_mm,q1,q2,q3,q4` — ABB: millimetres and a unit quaternion `q1..q4 = w, x, y, z`.
    Abb,
    /// `frame,x_mm,y_mm,z_mm,w_deg,p_deg,r_deg` — Fanuc XYZ-WPR: millimetres and degrees,
    /// `R = Rz(r)·Ry(p)·Rx(w)`.
    Fanuc,
}

impl PoseFormat {
    /// All formats.
    pub const ALL: [PoseFormat; 6] = [
        PoseFormat::Kuka,
        PoseFormat::Matrix,
        PoseFormat::Xyzquat,
        PoseFormat::Ur,
        PoseFormat::Abb,
        PoseFormat::Fanuc,
    ];

    /// The format's name (`kuka`, `matrix`, `xyzquat`, `ur`, `abb`, `fanuc`).
    pub fn name(self) -> &'static str {
        match self {
            PoseFormat::Kuka => "kuka",
            PoseFormat::Matrix => "matrix",
            PoseFormat::Xyzquat => "xyzquat",
            PoseFormat::Ur => "ur",
            PoseFormat::Abb => "abb",
            PoseFormat::Fanuc => "fanuc",
        }
    }

    /// The header line's column names.
    pub fn columns(self) -> Vec<String> {
        let mut c = vec!["frame".to_string()];
        match self {
            PoseFormat::Kuka => {
                c.extend(["x_mm", "y_mm", "z_mm", "a_deg", "b_deg", "c_deg"].map(String::from))
            }
            PoseFormat::Matrix => {
                for r in 0..4 {
                    for k in 0..4 {
                        c.push(format!("m{r}{k}"));
                    }
                }
            }
            PoseFormat::Xyzquat => {
                c.extend(["x", "y", "z", "qx", "qy", "qz", "qw"].map(String::from))
            }
            PoseFormat::Ur => c.extend(["x", "y", "z", "rx", "ry", "rz"].map(String::from)),
            PoseFormat::Abb => {
                c.extend(["x_mm", "y_mm", "z_mm", "q1", "q2", "q3", "q4"].map(String::from))
            }
            PoseFormat::Fanuc => {
                c.extend(["x_mm", "y_mm", "z_mm", "w_deg", "p_deg", "r_deg"].map(String::from))
            }
        }
        c
    }

    /// The header line (comma separated).
    pub fn header(self) -> String {
        self.columns().join(",")
    }

    /// Number of numeric columns after `frame`.
    pub fn value_count(self) -> usize {
        match self {
            PoseFormat::Kuka | PoseFormat::Ur | PoseFormat::Fanuc => 6,
            PoseFormat::Matrix => 16,
            PoseFormat::Xyzquat | PoseFormat::Abb => 7,
        }
    }

    /// Converts the numeric columns of one row to an isometry (metres).
    pub fn parse_values(self, v: &[f64]) -> std::result::Result<Isometry3<f64>, String> {
        if v.len() != self.value_count() {
            return Err(format!(
                "expected {} numbers, found {}",
                self.value_count(),
                v.len()
            ));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err("a value is NaN or infinite".into());
        }
        match self {
            PoseFormat::Kuka => Ok(KukaPose {
                x_mm: v[0],
                y_mm: v[1],
                z_mm: v[2],
                a_deg: v[3],
                b_deg: v[4],
                c_deg: v[5],
            }
            .to_isometry()),
            PoseFormat::Matrix => {
                let mut m = [0.0; 16];
                m.copy_from_slice(v);
                isometry_from_rows(&m, "pose matrix").map_err(|e| match e {
                    Error::InvalidInput(s) => s,
                    other => other.to_string(),
                })
            }
            PoseFormat::Xyzquat => {
                let mut a = [0.0; 7];
                a.copy_from_slice(v);
                xyzquat_to_isometry(&a)
            }
            PoseFormat::Ur => Ok(ur_to_isometry(&[v[0], v[1], v[2], v[3], v[4], v[5]])),
            PoseFormat::Abb => abb_to_isometry(&[v[0], v[1], v[2], v[3], v[4], v[5], v[6]]),
            PoseFormat::Fanuc => Ok(fanuc_to_isometry(&[v[0], v[1], v[2], v[3], v[4], v[5]])),
        }
    }

    /// The numeric columns of an isometry in this format, formatted for a CSV row (fixed decimals:
    /// KUKA 6 decimals of mm and degrees; ABB 6 of mm and 12 of the quaternion; every other format 9
    /// decimals).
    pub fn format_values(self, t: &Isometry3<f64>) -> String {
        let vals: Vec<f64> = match self {
            PoseFormat::Kuka => {
                let k = KukaPose::from_isometry(t);
                vec![k.x_mm, k.y_mm, k.z_mm, k.a_deg, k.b_deg, k.c_deg]
            }
            PoseFormat::Matrix => isometry_to_rows(t).to_vec(),
            PoseFormat::Xyzquat => isometry_to_xyzquat(t).to_vec(),
            PoseFormat::Ur => isometry_to_ur(t).to_vec(),
            PoseFormat::Abb => isometry_to_abb(t).to_vec(),
            PoseFormat::Fanuc => isometry_to_fanuc(t).to_vec(),
        };
        vals.iter()
            .enumerate()
            .map(|(i, v)| {
                let prec = match self {
                    PoseFormat::Kuka => 6,
                    PoseFormat::Abb if i < 3 => 6,
                    PoseFormat::Abb => 12,
                    _ => 9,
                };
                let s = format!("{v:.prec$}");
                // Avoid "-0.000000".
                if s.trim_start_matches('-')
                    .chars()
                    .all(|c| c == '0' || c == '.')
                {
                    s.trim_start_matches('-').to_string()
                } else {
                    s
                }
            })
            .collect::<Vec<_>>()
            .join(",")
    }
}

impl fmt::Display for PoseFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for PoseFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "kuka" | "xyzabc" => Ok(PoseFormat::Kuka),
            "matrix" | "mat" | "4x4" => Ok(PoseFormat::Matrix),
            "xyzquat" | "quat" | "quaternion" => Ok(PoseFormat::Xyzquat),
            "ur" | "rotvec" => Ok(PoseFormat::Ur),
            "abb" => Ok(PoseFormat::Abb),
            "fanuc" | "xyzwpr" => Ok(PoseFormat::Fanuc),
            _ => Err(format!(
                "unknown pose format {s:?} (expected kuka, matrix, xyzquat, ur, abb or fanuc)"
            )),
        }
    }
}

/// One row of a pose file: a frame id and the pose `T_base_ee` (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseRecord {
    /// The frame id (substituted for `{frame}` in a cell's image path pattern).
    pub frame: String,
    /// The pose, metres.
    pub pose: Isometry3<f64>,
    /// 1-based line number in the file it was read from (0 when not read from a file).
    pub line: usize,
}

fn split_row(line: &str) -> Vec<&str> {
    line.split(',').map(|s| s.trim()).collect()
}

fn is_skippable(line: &str) -> bool {
    let t = line.trim();
    t.is_empty() || t.starts_with('#')
}

/// Finds the pose format from a header line (`None` when it matches no format).
pub fn format_from_header(header: &str) -> Option<PoseFormat> {
    let cols: Vec<String> = split_row(header)
        .iter()
        .map(|s| s.to_ascii_lowercase())
        .collect();
    PoseFormat::ALL.into_iter().find(|f| f.columns() == cols)
}

/// A piece of a pose file as an error shows it: quoted when it looks like pose-file text (at most 120
/// characters of letters, digits, `_ , . + -` and spaces), else only its length, so that an error never
/// echoes the content of a file that is not a pose file.
fn shown(s: &str) -> String {
    let s = s.trim();
    let plausible = s.chars().count() <= 120
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || " _,.+-".contains(c));
    if plausible {
        format!("{s:?}")
    } else {
        format!(
            "({} characters, not shown: not pose-file text)",
            s.chars().count()
        )
    }
}

/// Parses pose CSV text. With `format = None` the format is taken from the header. Blank lines and lines
/// starting with `#` are skipped. Frame ids must be non-empty and unique. Errors name `path` and the line.
pub fn parse_poses(
    text: &str,
    format: Option<PoseFormat>,
    path: &Path,
) -> Result<(PoseFormat, Vec<PoseRecord>)> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !is_skippable(l));
    let Some((hline, header)) = lines.next() else {
        return Err(Error::format(
            path,
            "the pose file is empty (expected a header line and one row per frame)",
        ));
    };
    let found = format_from_header(header);
    let format = match (format, found) {
        (Some(f), Some(g)) if f == g => f,
        (None, Some(g)) => g,
        (Some(f), _) => {
            return Err(Error::format(
                path,
                format!(
                    "line {}: header {} does not match pose format {f}; expected \"{}\"",
                    hline + 1,
                    shown(header),
                    f.header()
                ),
            ))
        }
        (None, None) => {
            return Err(Error::format(
                path,
                format!(
                    "line {}: header {} names no known pose format; expected one of {}",
                    hline + 1,
                    shown(header),
                    PoseFormat::ALL
                        .map(|f| format!("{:?}", f.header()))
                        .join(", ")
                ),
            ))
        }
    };
    let mut out: Vec<PoseRecord> = Vec::new();
    let mut seen = std::collections::HashMap::new();
    for (i, line) in lines {
        let lineno = i + 1;
        let cols = split_row(line);
        let err = |msg: String| Error::format(path, format!("line {lineno}: {msg}"));
        if cols.len() != format.value_count() + 1 {
            return Err(err(format!(
                "expected {} comma-separated columns ({}), found {}",
                format.value_count() + 1,
                format.header(),
                cols.len()
            )));
        }
        let frame = cols[0].to_string();
        if frame.is_empty() {
            return Err(err("the frame id is empty".into()));
        }
        if frame.contains(['/', '\\']) || frame == ".." {
            return Err(err(format!(
                "frame id {} must not contain a path separator",
                shown(&frame)
            )));
        }
        let mut vals = Vec::with_capacity(format.value_count());
        for (name, s) in format.columns()[1..].iter().zip(&cols[1..]) {
            let v: f64 = s
                .parse()
                .map_err(|_| err(format!("column {name}: {} is not a number", shown(s))))?;
            vals.push(v);
        }
        let pose = format
            .parse_values(&vals)
            .map_err(|m| err(format!("frame {frame}: {m}")))?;
        if let Some(prev) = seen.insert(frame.clone(), lineno) {
            return Err(err(format!(
                "frame {frame} repeats the frame of line {prev}"
            )));
        }
        out.push(PoseRecord {
            frame,
            pose,
            line: lineno,
        });
    }
    if out.is_empty() {
        return Err(Error::format(
            path,
            "the pose file has a header but no pose rows",
        ));
    }
    Ok((format, out))
}

/// Reads a pose CSV file (see [`parse_poses`]).
pub fn read_poses(
    path: impl AsRef<Path>,
    format: Option<PoseFormat>,
) -> Result<(PoseFormat, Vec<PoseRecord>)> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_poses(&text, format, path)
}

/// The CSV text of `records` in `format` (header, then one row per record).
pub fn format_poses(records: &[PoseRecord], format: PoseFormat) -> String {
    let mut s = format.header();
    s.push('\n');
    for r in records {
        s.push_str(&r.frame);
        s.push(',');
        s.push_str(&format.format_values(&r.pose));
        s.push('\n');
    }
    s
}

/// Writes a pose CSV file atomically.
pub fn write_poses(
    path: impl AsRef<Path>,
    records: &[PoseRecord],
    format: PoseFormat,
) -> Result<()> {
    let text = format_poses(records, format);
    crate::io::write_atomically(path.as_ref(), |w| w.write_all(text.as_bytes()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transform::{pose_error, random_isometry};
    use crate::geometry::Rng;

    #[test]
    fn every_format_round_trips() {
        let mut rng = Rng::new(9);
        let recs: Vec<PoseRecord> = (0..50)
            .map(|i| PoseRecord {
                frame: format!("{i:04}"),
                pose: random_isometry(&mut rng, std::f64::consts::PI, 2.0),
                line: 0,
            })
            .collect();
        for f in PoseFormat::ALL {
            let text = format_poses(&recs, f);
            let (g, back) = parse_poses(&text, None, Path::new("p.csv")).unwrap();
            assert_eq!(g, f);
            for (a, b) in recs.iter().zip(&back) {
                assert_eq!(a.frame, b.frame);
                let (r, d) = pose_error(&a.pose, &b.pose);
                assert!(r < 1e-5 && d < 2e-9, "{f}: {r} deg {d} m");
            }
        }
        let q = isometry_to_xyzquat(&recs[3].pose);
        let t = xyzquat_to_isometry(&q).unwrap();
        assert!(pose_error(&t, &recs[3].pose).0 < 1e-9);
    }

    /// Half turns about any axis, angles within 1e-9 rad of one, and the axis-aligned half turns
    /// (including KUKA's B = ±90°) read back as themselves in every format.
    #[test]
    fn every_format_round_trips_half_turns() {
        let mut rng = Rng::new(36);
        let pi = std::f64::consts::PI;
        let mut recs: Vec<PoseRecord> = (0..300)
            .map(|i| {
                let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(
                    rng.normal(),
                    rng.normal(),
                    rng.normal(),
                ));
                let angle = match i % 3 {
                    0 => pi,
                    1 => pi - 1e-9,
                    _ => pi - rng.uniform(0.0, 1e-3),
                };
                PoseRecord {
                    frame: format!("{i:04}"),
                    pose: Isometry3::from_parts(
                        nalgebra::Translation3::new(rng.normal(), rng.normal(), rng.normal()),
                        nalgebra::UnitQuaternion::from_axis_angle(&axis, angle),
                    ),
                    line: 0,
                }
            })
            .collect();
        let axes = [
            nalgebra::Vector3::x_axis(),
            nalgebra::Vector3::y_axis(),
            nalgebra::Vector3::z_axis(),
        ];
        for (k, axis) in axes.iter().enumerate() {
            for angle in [pi, pi / 2.0, -pi / 2.0] {
                recs.push(PoseRecord {
                    frame: format!("axis{k}_{angle:.3}"),
                    pose: Isometry3::from_parts(
                        nalgebra::Translation3::new(0.1, -0.2, 0.3),
                        nalgebra::UnitQuaternion::from_axis_angle(axis, angle),
                    ),
                    line: 0,
                });
            }
        }
        for f in PoseFormat::ALL {
            let text = format_poses(&recs, f);
            let (_, back) = parse_poses(&text, None, Path::new("p.csv")).unwrap();
            for (a, b) in recs.iter().zip(&back) {
                let (r, d) = pose_error(&a.pose, &b.pose);
                assert!(
                    r < 1e-5 && d < 2e-9,
                    "{f} {}: {r} deg {d} m (angle {})",
                    a.frame,
                    a.pose.rotation.angle()
                );
            }
            // Written again from what was read and read once more, nothing drifts.
            let (_, again) =
                parse_poses(&format_poses(&back, f), None, Path::new("p.csv")).unwrap();
            for (a, b) in back.iter().zip(&again) {
                let (r, d) = pose_error(&a.pose, &b.pose);
                assert!(r < 1e-5 && d < 2e-9, "{f} {} again: {r} deg {d} m", a.frame);
            }
        }
    }

    #[test]
    fn bad_rows_name_file_and_line() {
        let p = Path::new("robot1/poses.csv");
        let h = PoseFormat::Kuka.header();
        let cases = [
            (format!("{h}\n0,1,2,3,4,5,6\n1,1,2,x,4,5,6\n"), "line 3"),
            (format!("{h}\n0,1,2,3,4,5\n"), "line 2"),
            (format!("{h}\n0,1,2,3,4,5,6\n0,1,2,3,4,5,6\n"), "repeats"),
            ("frame,x,y\n0,1,2\n".to_string(), "line 1"),
            (String::new(), "empty"),
            (format!("{h}\n"), "no pose rows"),
            (format!("{h}\n0,1,2,NaN,4,5,6\n"), "NaN"),
        ];
        for (text, want) in cases {
            let e = parse_poses(&text, None, p).unwrap_err().to_string();
            assert!(e.contains("robot1/poses.csv") && e.contains(want), "{e}");
        }
        let m = format!(
            "{}\n0,2,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1\n",
            PoseFormat::Matrix.header()
        );
        let e = parse_poses(&m, Some(PoseFormat::Matrix), p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("rotation"), "{e}");
        let q = format!("{}\n0,0,0,0,0,0,0,2\n", PoseFormat::Xyzquat.header());
        let e = parse_poses(&q, None, p).unwrap_err().to_string();
        assert!(e.contains("norm"), "{e}");
        let e = parse_poses(
            &format!("{h}\n0,1,2,3,4,5,6\n"),
            Some(PoseFormat::Matrix),
            p,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("does not match pose format matrix"), "{e}");
    }
}
