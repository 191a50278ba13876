//! The calibration boards: the checkerboard ([`Checkerboard`]: its geometry and frame convention), the
//! ChArUco board ([`super::charuco::CharucoBoard`]), either as a [`Board`], and the `[board]` table of
//! `cell.toml` that names one.
//!
//! # Board frame
//!
//! A board of `cols × rows` *inner* corners (squares where four squares meet) has `(cols + 1) × (rows + 1)`
//! squares of edge `square_m`. The board frame has its origin at inner corner 0, `x` along a row of `cols`
//! corners, `y` along a column of `rows` corners, and `z = x × y` pointing *into* the board (away from the
//! printed side, OpenCV's convention): inner corner `(i, j)` is at `(i·square_m, j·square_m, 0)` and is
//! number `j·cols + i` in corner lists (row-major).
//!
//! Square `(a, b)`, `a ∈ 0..=cols`, `b ∈ 0..=rows`, covers `x ∈ [(a−1)·s, a·s]`, `y ∈ [(b−1)·s, b·s]`
//! and is black when `a + b` is even: the outer square diagonally before corner 0 is black. When
//! `cols + rows` is odd (e.g. 9×6) a half turn of the board swaps black and white, so the black-square rule
//! fixes the corner order in every image ([`Checkerboard::is_symmetric`] is false); for `cols + rows` even
//! (e.g. 8×6, 7×7) a half turn maps the board onto itself and the order of the corners is ambiguous.
//!
//! # `cell.toml`
//!
//! ```toml
//! [board]
//! type = "checkerboard"   # optional: the default
//! cols = 9                # inner corners along the board x axis
//! rows = 6                # inner corners along the board y axis
//! square_m = 0.03         # square edge, metres
//! ```
//!
//! or a ChArUco board (`type = "charuco"`, keys in [`super::charuco`]). An unknown `type`, an unknown key
//! and a value out of range are errors naming the key.

use super::charuco::CharucoBoard;
use crate::error::{Error, Result};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;
use std::str::FromStr;

/// A checkerboard calibration target (see the module documentation for its frame).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Checkerboard {
    /// Inner corners along the board x axis (a row), at least 2.
    pub cols: u32,
    /// Inner corners along the board y axis (a column), at least 2.
    pub rows: u32,
    /// Square edge, metres.
    pub square_m: f64,
}

impl Checkerboard {
    /// A board of `cols × rows` inner corners with squares of `square_m` metres; checked.
    pub fn new(cols: u32, rows: u32, square_m: f64) -> Result<Self> {
        let b = Checkerboard {
            cols,
            rows,
            square_m,
        };
        b.validate().map_err(|msg| Error::Config {
            field: "board".into(),
            msg,
        })?;
        Ok(b)
    }

    /// Checks the values; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.cols < 2 || self.rows < 2 {
            return Err(format!(
                "`cols` and `rows` count inner corners and must be at least 2, found {}x{}",
                self.cols, self.rows
            ));
        }
        if self.cols == self.rows {
            return Err(format!(
                "a square {0}x{0} board cannot tell its x axis from its y axis; use a board with \
                 different corner counts (e.g. 9x6)",
                self.cols
            ));
        }
        if !(self.square_m.is_finite() && self.square_m > 0.0) {
            return Err(format!(
                "`square_m` must be a positive length in metres, found {}",
                self.square_m
            ));
        }
        if self.square_m > 1.0 {
            return Err(format!(
                "`square_m` = {} m is implausible for a printed board: give the square edge in metres \
                 (e.g. 0.025 for 25 mm)",
                self.square_m
            ));
        }
        Ok(())
    }

    /// Number of inner corners.
    pub fn corner_count(&self) -> usize {
        (self.cols * self.rows) as usize
    }

    /// The inner corners in the board frame (metres, `z = 0`), row-major: corner `j·cols + i` is
    /// `(i·square_m, j·square_m, 0)`.
    pub fn object_points(&self) -> Vec<Point3<f64>> {
        let s = self.square_m;
        (0..self.rows)
            .flat_map(|j| (0..self.cols).map(move |i| Point3::new(i as f64 * s, j as f64 * s, 0.0)))
            .collect()
    }

    /// True when a half turn maps the board onto itself (`cols + rows` even): the corner order is then
    /// ambiguous and board poses may be off by 180° about the board normal.
    pub fn is_symmetric(&self) -> bool {
        (self.cols + self.rows).is_multiple_of(2)
    }

    /// Size of the printed pattern (all squares), metres: `[(cols + 1)·s, (rows + 1)·s]`.
    pub fn size_m(&self) -> [f64; 2] {
        [
            (self.cols + 1) as f64 * self.square_m,
            (self.rows + 1) as f64 * self.square_m,
        ]
    }

    /// The point's colour on the board: `Some(true)` black, `Some(false)` white, `None` outside the pattern.
    /// `x`, `y` in the board frame, metres.
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        let a = (x / self.square_m).floor() + 1.0;
        let b = (y / self.square_m).floor() + 1.0;
        if a < 0.0 || b < 0.0 || a > self.cols as f64 || b > self.rows as f64 {
            return None;
        }
        Some((a as i64 + b as i64) % 2 == 0)
    }

    /// Reads the checkerboard keys of a `[board]` table (`type` already checked); the message names the
    /// key.
    fn from_table(t: &toml::Table) -> std::result::Result<Self, String> {
        let mut t = t.clone();
        t.remove("type");
        let b: Checkerboard = toml::Value::Table(t)
            .try_into()
            .map_err(|e: toml::de::Error| {
                format!(
                    "{} (a checkerboard has cols, rows: inner corner counts; square_m: metres; \
                     type = \"charuco\" for a ChArUco board)",
                    e.message()
                )
            })?;
        b.validate()?;
        Ok(b)
    }

    /// The `[board]` table as it is written to `cell.toml`.
    pub fn to_toml(&self) -> toml::Value {
        let mut t = toml::Table::new();
        t.insert("cols".into(), (self.cols as i64).into());
        t.insert("rows".into(), (self.rows as i64).into());
        t.insert("square_m".into(), self.square_m.into());
        toml::Value::Table(t)
    }
}

impl fmt::Display for Checkerboard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}x{} inner corners, {} mm squares",
            self.cols,
            self.rows,
            self.square_m * 1e3
        )
    }
}

/// A calibration board: a checkerboard or a ChArUco board.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Board {
    /// A plain checkerboard: every inner corner must be seen ([`Checkerboard`]).
    Checkerboard(Checkerboard),
    /// A ChArUco board: markers in the white squares identify each corner, so partial views count
    /// ([`CharucoBoard`]).
    Charuco(CharucoBoard),
}

/// The values of `type` in a `[board]` table.
pub const BOARD_TYPES: &[&str] = &["checkerboard", "charuco"];

impl Board {
    /// Reads the optional `[board]` table from a manifest's extra keys; `path` names `cell.toml` in
    /// errors, which also name the key. `type` is `"checkerboard"` (the default) or `"charuco"`.
    pub fn from_manifest_extra(extra: &toml::Table, path: &Path) -> Result<Option<Self>> {
        let Some(v) = extra.get("board") else {
            return Ok(None);
        };
        let bad = |m: String| Error::format(path, format!("[board]: {m}"));
        let Some(t) = v.as_table() else {
            return Err(bad(format!("must be a table, found {v}")));
        };
        let kind = match t.get("type") {
            None => "checkerboard",
            Some(toml::Value::String(k)) if BOARD_TYPES.contains(&k.as_str()) => k.as_str(),
            Some(k) => {
                return Err(bad(format!(
                    "`type` = {k} is not a board type; expected \"checkerboard\" (the default) or \"charuco\""
                )))
            }
        };
        Ok(Some(if kind == "charuco" {
            Board::Charuco(CharucoBoard::from_table(t).map_err(|(_, m)| bad(m))?)
        } else {
            Board::Checkerboard(Checkerboard::from_table(t).map_err(bad)?)
        }))
    }

    /// The `[board]` table as it is written to `cell.toml` (a checkerboard without `type`, as before
    /// ChArUco boards).
    pub fn to_toml(&self) -> toml::Value {
        match self {
            Board::Checkerboard(b) => b.to_toml(),
            Board::Charuco(b) => b.to_toml(),
        }
    }

    /// `checkerboard` or `charuco`.
    pub fn kind(&self) -> &'static str {
        match self {
            Board::Checkerboard(_) => "checkerboard",
            Board::Charuco(_) => "charuco",
        }
    }

    /// Square edge, metres.
    pub fn square_m(&self) -> f64 {
        match self {
            Board::Checkerboard(b) => b.square_m,
            Board::Charuco(b) => b.square_m,
        }
    }

    /// Number of corners on the board (a ChArUco view may show fewer).
    pub fn corner_count(&self) -> usize {
        match self {
            Board::Checkerboard(b) => b.corner_count(),
            Board::Charuco(b) => b.corner_count(),
        }
    }

    /// Corner `id` in the board frame (metres, `z = 0`): for a checkerboard the row-major inner corner, for
    /// a ChArUco board OpenCV's chessboard corner id. `None` beyond the board.
    pub fn corner_point(&self, id: u32) -> Option<Point3<f64>> {
        match self {
            Board::Checkerboard(b) => {
                let (i, j) = (id % b.cols, id / b.cols);
                (j < b.rows).then(|| Point3::new(i as f64 * b.square_m, j as f64 * b.square_m, 0.0))
            }
            Board::Charuco(b) => b.corner_point(id),
        }
    }
}

impl From<Checkerboard> for Board {
    fn from(b: Checkerboard) -> Self {
        Board::Checkerboard(b)
    }
}

impl From<CharucoBoard> for Board {
    fn from(b: CharucoBoard) -> Self {
        Board::Charuco(b)
    }
}

impl fmt::Display for Board {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Board::Checkerboard(b) => b.fmt(f),
            Board::Charuco(b) => b.fmt(f),
        }
    }
}

/// Parses `COLSxROWS` (inner corners, e.g. `9x6`) as the command line gives it.
pub fn parse_board_size(s: &str) -> std::result::Result<(u32, u32), String> {
    let t = s.trim().to_ascii_lowercase();
    let parts: Vec<&str> = t.split(['x', '*', ',']).map(str::trim).collect();
    match parts.as_slice() {
        [c, r] => match (u32::from_str(c), u32::from_str(r)) {
            (Ok(c), Ok(r)) => Ok((c, r)),
            _ => Err(format!(
                "board size {s:?}: expected COLSxROWS inner corners, e.g. 9x6"
            )),
        },
        _ => Err(format!(
            "board size {s:?}: expected COLSxROWS inner corners, e.g. 9x6"
        )),
    }
}

/// Parses a length for the command line: metres (`0.025`, `0.025m`) or with a unit suffix `mm` / `cm`.
pub fn parse_length_m(s: &str) -> std::result::Result<f64, String> {
    let t = s.trim().to_ascii_lowercase();
    let (num, scale) = if let Some(n) = t.strip_suffix("mm") {
        (n, 1e-3)
    } else if let Some(n) = t.strip_suffix("cm") {
        (n, 1e-2)
    } else if let Some(n) = t.strip_suffix('m') {
        (n, 1.0)
    } else {
        (t.as_str(), 1.0)
    };
    match f64::from_str(num.trim()) {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v * scale),
        _ => Err(format!(
            "length {s:?}: expected a positive number of metres, or with mm/cm (e.g. 0.025 or 25mm)"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_colours_and_symmetry() {
        let b = Checkerboard::new(9, 6, 0.03).unwrap();
        let p = b.object_points();
        assert_eq!(p.len(), 54);
        assert_eq!(p[1], Point3::new(0.03, 0.0, 0.0));
        assert_eq!(p[9], Point3::new(0.0, 0.03, 0.0));
        assert!(!b.is_symmetric());
        assert!(Checkerboard::new(8, 6, 0.03).unwrap().is_symmetric());
        // The square before corner 0 is black, its neighbours white; the far corner square is white (9+6 odd).
        assert_eq!(b.is_black(-0.015, -0.015), Some(true));
        assert_eq!(b.is_black(0.015, -0.015), Some(false));
        assert_eq!(b.is_black(0.015, 0.015), Some(true));
        assert_eq!(b.is_black(0.255, 0.165), Some(false));
        assert_eq!(b.is_black(-0.031, 0.0), None);
        assert_eq!(b.size_m(), [0.3, 0.21]);
    }

    #[test]
    fn bad_boards_and_sizes_are_refused() {
        assert!(Checkerboard::new(1, 6, 0.03).is_err());
        assert!(Checkerboard::new(7, 7, 0.03).is_err());
        assert!(Checkerboard::new(9, 6, -1.0).is_err());
        let e = Checkerboard::new(9, 6, 25.0).unwrap_err().to_string();
        assert!(e.contains("metres"), "{e}");
        assert_eq!(parse_board_size("9x6"), Ok((9, 6)));
        assert_eq!(parse_board_size(" 9X6 "), Ok((9, 6)));
        assert!(parse_board_size("9").is_err());
        assert!(parse_board_size("ax6").is_err());
        assert_eq!(parse_length_m("25mm"), Ok(0.025));
        assert_eq!(parse_length_m("0.03"), Ok(0.03));
        assert!((parse_length_m("2.5cm").unwrap() - 0.025).abs() < 1e-15);
        assert!(parse_length_m("-1").is_err() && parse_length_m("mm").is_err());
    }

    #[test]
    fn manifest_table_round_trip_and_errors() {
        let p = Path::new("cell.toml");
        let read = |text: &str| Board::from_manifest_extra(&toml::from_str(text).unwrap(), p);
        let b = Board::from(Checkerboard::new(9, 6, 0.025).unwrap());
        let mut extra = toml::Table::new();
        extra.insert("board".into(), b.to_toml());
        assert_eq!(Board::from_manifest_extra(&extra, p).unwrap(), Some(b));
        assert_eq!(
            Board::from_manifest_extra(&toml::Table::new(), p).unwrap(),
            None
        );
        // `type = "checkerboard"` is the default, and may be given.
        assert_eq!(
            read("[board]\ntype = \"checkerboard\"\ncols = 9\nrows = 6\nsquare_m = 0.025\n")
                .unwrap(),
            Some(b)
        );
        let e = read("[board]\ncols = 9\nrows = 6\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("cell.toml") && e.contains("square_m"), "{e}");
        assert!(read("[board]\ncols = 9\nrows = 6\nsquare_m = 30\n").is_err());
        let e = read("[board]\ncols = 9\nrows = 6\nsquare_m = 0.03\nmarker_m = 0.02\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("marker_m") && e.contains("charuco"), "{e}");
        let e = read("[board]\ntype = \"charuko\"\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`type`") && e.contains("\"charuco\""), "{e}");
        // A ChArUco board.
        let c = read(
            "[board]\ntype = \"charuco\"\nsquares_x = 5\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.02\n\
             dictionary = \"DICT_6X6_250\"\n",
        )
        .unwrap()
        .unwrap();
        assert_eq!(c.kind(), "charuco");
        assert_eq!(c.corner_count(), 24);
        let mut extra = toml::Table::new();
        extra.insert("board".into(), c.to_toml());
        assert_eq!(Board::from_manifest_extra(&extra, p).unwrap(), Some(c));
        let e = read(
            "[board]\ntype = \"charuco\"\nsquares_x = 5\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.05\n\
             dictionary = \"DICT_6X6_250\"\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("cell.toml") && e.contains("[board]") && e.contains("`marker_m`"),
            "{e}"
        );
        let e = read("[board]\ntype = \"charuco\"\ncols = 9\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown key `cols`"), "{e}");
        // JSON carries the type.
        let j = serde_json::to_value(c).unwrap();
        assert_eq!(j["type"], "charuco");
        assert_eq!(j["dictionary"], "DICT_6X6_250");
        assert_eq!(serde_json::from_value::<Board>(j).unwrap(), c);
        assert_eq!(serde_json::to_value(b).unwrap()["type"], "checkerboard");
        assert_eq!(b.corner_point(10), Some(Point3::new(0.025, 0.025, 0.0)));
        assert_eq!(b.corner_point(54), None);
    }
}
