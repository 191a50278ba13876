//! Robot poses: KUKA XYZ-ABC, 4x4 matrices, x,y,z + quaternion, UR pose vectors, ABB x,y,z + q1..q4 and
//! Fanuc XYZ-WPR, and the pose CSV files of a cell.
//!
//! Units are converted exactly once, here: every [`Isometry3`] is in metres and radians; KUKA values are
//! millimetres and degrees (`x_mm`, `a_deg`, ...).
//!
//! KUKA convention: `R = Rz(A) · Ry(B) · Rx(C)` (intrinsic Z-Y'-X''), `t = (x, y, z)`. The conversion
//! back from a rotation returns `A, C ∈ (-180°, 180°]`, `B ∈ [-90°, 90°]`; at gimbal lock (`B = ±90°`)
//! only `A ∓ C` is defined and depthcal returns `C = 0`.
//!
//! UR convention: `x, y, z` in metres and the rotation vector `(rx, ry, rz)` in radians (axis times angle,
//! angle in `[0, π]`). ABB convention: `x, y, z` in millimetres and the unit quaternion `q1..q4 = w, x, y, z`
//! (`q1 ≥ 0`). Fanuc convention: `x, y, z` in millimetres and `W, P, R` in degrees, fixed axes X-Y-Z:
//! `R = Rz(R)·Ry(P)·Rx(W)` (the same matrix as KUKA's `Rz(A)·Ry(B)·Rx(C)` with `W = C, P = B, R = A`).

use crate::error::{Error, Result};
use crate::geometry::transform::{isometry_from_rows, isometry_to_rows};
use nalgebra::{Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// A KUKA pose: position in millimetres and A, B, C Euler angles in degrees (`R = Rz(A)·Ry(B)·Rx(C)`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct KukaPose {
    /// X, millimetres.
    pub x_mm: f64,
    /// Y, millimetres.
    pub y_mm: f64,
    /// Z, millimetres.
    pub z_mm: f64,
    /// A: rotation about Z, degrees (applied first in the intrinsic sequence).
    pub a_deg: f64,
    /// B: rotation about the new Y, degrees.
    pub b_deg: f64,
    /// C: rotation about the newest X, degrees.
    pub c_deg: f64,
}

/// The rotation `Rz(a)·Ry(b)·Rx(c)` for angles in radians.
pub fn rotation_from_zyx(a: f64, b: f64, c: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), a)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), b)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), c)
}

/// The angles `(a, b, c)` in radians with `R = Rz(a)·Ry(b)·Rx(c)`; at gimbal lock `c = 0`.
pub fn zyx_from_rotation(r: &Matrix3<f64>) -> (f64, f64, f64) {
    let cb = (r[(0, 0)] * r[(0, 0)] + r[(1, 0)] * r[(1, 0)]).sqrt();
    let b = (-r[(2, 0)]).atan2(cb);
    if cb < 1e-9 {
        // B = ±90°: R depends only on A − C (B = +90°) or A + C (B = −90°); choose C = 0.
        let a = (-r[(0, 1)]).atan2(r[(1, 1)]);
        (a, b, 0.0)
    } else {
        let a = r[(1, 0)].atan2(r[(0, 0)]);
        let c = r[(2, 1)].atan2(r[(2, 2)]);
        (a, b, c)
    }
}

impl KukaPose {
    /// The pose as an isometry in metres.
    pub fn to_isometry(&self) -> Isometry3<f64> {
        let r = rotation_from_zyx(
            self.a_deg.to_radians(),
            self.b_deg.to_radians(),
            self.c_deg.to_radians(),
        );
        Isometry3::from_parts(
            Translation3::new(self.x_mm * 1e-3, self.y_mm * 1e-3, self.z_mm * 1e-3),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }

    /// The KUKA values of an isometry in metres (angles in `(-180, 180]`, B in `[-90, 90]`, C = 0 at
    /// gimbal lock).
    pub fn from_isometry(t: &Isometry3<f64>) -> Self {
        let m = t.rotation.to_rotation_matrix();
        let (a, b, c) = zyx_from_rotation(m.matrix());
        let v = t.translation.vector * 1e3;
        KukaPose {
            x_mm: v.x,
            y_mm: v.y,
            z_mm: v.z,
            a_deg: a.to_degrees(),
            b_deg: b.to_degrees(),
            c_deg: c.to_degrees(),
        }
    }
}

/// `[x, y, z, qx, qy, qz, qw]` (metres, unit quaternion with `qw ≥ 0`) of an isometry.
pub fn isometry_to_xyzquat(t: &Isometry3<f64>) -> [f64; 7] {
    let mut q = *t.rotation.quaternion();
    if q.w < 0.0 {
        q = -q;
    }
    let v = t.translation.vector;
    [v.x, v.y, v.z, q.i, q.j, q.k, q.w]
}

/// `[x, y, z, rx, ry, rz]` of an isometry: the Universal Robots pose vector (metres, rotation vector in
/// radians, angle in `[0, π]`).
///
/// Near a half turn the axis and its opposite give the same rotation; the axis is then chosen with its
/// first non-zero component positive, so that the written vector reads back to itself.
pub fn isometry_to_ur(t: &Isometry3<f64>) -> [f64; 6] {
    let q = t.rotation.quaternion();
    let (mut w, mut axis) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        axis = -axis;
    }
    let n = axis.norm();
    let r = if n == 0.0 {
        Vector3::zeros()
    } else {
        if w < 1e-9 {
            let first = axis
                .iter()
                .copied()
                .find(|c| c.abs() > 1e-12)
                .unwrap_or(1.0);
            if first < 0.0 {
                axis = -axis;
            }
        }
        axis * (2.0 * n.atan2(w) / n)
    };
    let v = t.translation.vector;
    [v.x, v.y, v.z, r.x, r.y, r.z]
}

/// The isometry of a Universal Robots pose vector `[x, y, z, rx, ry, rz]` (metres, radians).
pub fn ur_to_isometry(v: &[f64; 6]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(v[3], v[4], v[5])),
    )
}

/// `[x_mm, y_mm, z_mm, q1, q2, q3, q4]` of an isometry: an ABB frame (millimetres, unit quaternion
/// `q1..q4 = w, x, y, z` with `q1 ≥ 0`).
pub fn isometry_to_abb(t: &Isometry3<f64>) -> [f64; 7] {
    let q = isometry_to_xyzquat(t);
    [q[0] * 1e3, q[1] * 1e3, q[2] * 1e3, q[6], q[3], q[4], q[5]]
}

/// The isometry of an ABB frame `[x_mm, y_mm, z_mm, q1, q2, q3, q4]` (`q1..q4 = w, x, y, z`, unit norm
/// within [`QUATERNION_NORM_TOLERANCE`]; normalised).
pub fn abb_to_isometry(v: &[f64; 7]) -> std::result::Result<Isometry3<f64>, String> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err("a value is NaN or infinite".into());
    }
    let q = Quaternion::new(v[3], v[4], v[5], v[6]);
    let n = q.norm();
    if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "the quaternion (q1,q2,q3,q4) = ({}, {}, {}, {}) has norm {n:.6}, not 1",
            v[3], v[4], v[5], v[6]
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3),
        UnitQuaternion::new_normalize(q),
    ))
}

/// `[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]` of an isometry: Fanuc XYZ-WPR with `R = Rz(r)·Ry(p)·Rx(w)`
/// (`w, r ∈ (-180, 180]`, `p ∈ [-90, 90]`, `w = 0` at gimbal lock).
pub fn isometry_to_fanuc(t: &Isometry3<f64>) -> [f64; 6] {
    let k = KukaPose::from_isometry(t);
    [k.x_mm, k.y_mm, k.z_mm, k.c_deg, k.b_deg, k.a_deg]
}

/// The isometry of Fanuc XYZ-WPR `[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]`.
pub fn fanuc_to_isometry(v: &[f64; 6]) -> Isometry3<f64> {
    KukaPose {
        x_mm: v[0],
        y_mm: v[1],
        z_mm: v[2],
        a_deg: v[5],
        b_deg: v[4],
        c_deg: v[3],
    }
    .to_isometry()
}

/// Roll, pitch, yaw (radians) of a rotation as URDF defines them: fixed axes X-Y-Z,
/// `R = Rz(yaw)·Ry(pitch)·Rx(roll)` (`roll = 0` at gimbal lock).
pub fn rpy_from_rotation(r: &Matrix3<f64>) -> [f64; 3] {
    let (yaw, pitch, roll) = zyx_from_rotation(r);
    [roll, pitch, yaw]
}

/// Largest accepted deviation of a quaternion's norm from 1 (it is then normalised).
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// The isometry of `[x, y, z, qx, qy, qz, qw]` (metres). The quaternion must have unit norm within
/// [`QUATERNION_NORM_TOLERANCE`]; it is normalised.
pub fn xyzquat_to_isometry(v: &[f64; 7]) -> std::result::Result<Isometry3<f64>, String> {
    if v.iter().any(|x| !x.is_finite()) {
        return Err("a value is NaN or infinite".into());
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    let n = q.norm();
    if (n - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "the quaternion (qx,qy,qz,qw) = ({}, {}, {}, {}) has norm {n:.6}, not 1",
            v[3], v[4], v[5], v[6]
        ));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(v[0], v[1], v[2]),
        UnitQuaternion::new_normalize(q),
    ))
}

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
    fn kuka_matches_the_definition() {
        // A = 90° about Z maps x to y.
        let t = KukaPose {
            x_mm: 100.0,
            y_mm: -20.0,
            z_mm: 5.0,
            a_deg: 90.0,
            b_deg: 0.0,
            c_deg: 0.0,
        }
        .to_isometry();
        let p = t * nalgebra::Point3::new(1.0, 0.0, 0.0);
        assert!(
            (p - nalgebra::Point3::new(0.1, 0.98, 0.005)).norm() < 1e-12,
            "{p}"
        );
        // Intrinsic order: Rz(A) then Ry(B) then Rx(C), i.e. R = Rz·Ry·Rx.
        let (a, b, c) = (30f64, -40f64, 75f64);
        let t = KukaPose {
            x_mm: 0.0,
            y_mm: 0.0,
            z_mm: 0.0,
            a_deg: a,
            b_deg: b,
            c_deg: c,
        }
        .to_isometry();
        let expect = Rotation3::from_euler_angles(c.to_radians(), b.to_radians(), a.to_radians());
        assert!(
            (t.rotation.to_rotation_matrix().matrix() - expect.matrix())
                .abs()
                .max()
                < 1e-12
        );
    }

    #[test]
    fn kuka_round_trips_including_gimbal_lock() {
        let mut rng = Rng::new(5);
        for i in 0..2000 {
            let b = match i % 4 {
                0 => 90.0,
                1 => -90.0,
                _ => rng.uniform(-90.0, 90.0),
            };
            let k = KukaPose {
                x_mm: rng.uniform(-2000.0, 2000.0),
                y_mm: rng.uniform(-2000.0, 2000.0),
                z_mm: rng.uniform(-2000.0, 2000.0),
                a_deg: rng.uniform(-180.0, 180.0),
                b_deg: b,
                c_deg: rng.uniform(-180.0, 180.0),
            };
            let t = k.to_isometry();
            let back = KukaPose::from_isometry(&t);
            let t2 = back.to_isometry();
            let (r, d) = pose_error(&t, &t2);
            assert!(r < 1e-6 && d < 1e-12, "{k:?} -> {back:?}: {r} deg {d} m");
            assert!((back.b_deg - k.b_deg).abs() < 1e-5, "{k:?} -> {back:?}");
            if b.abs() < 89.0 {
                // Away from the lock the angles themselves come back.
                assert!((back.a_deg - k.a_deg).abs() < 1e-8 && (back.c_deg - k.c_deg).abs() < 1e-8);
            } else if b.abs() == 90.0 {
                assert_eq!(back.c_deg, 0.0);
            }
        }
    }

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
