//! The ChArUco board: a checkerboard with an ArUco marker in every white square (OpenCV's
//! `cv::aruco::CharucoBoard`, in OpenCV 4.6's layout), its frame, and its keys in the `[board]` table of
//! `cell.toml`. Geometry only: no OpenCV is needed here (detection is `vision::charuco`).
//!
//! # Board frame and layout (OpenCV 4.6's `CharucoBoard`)
//!
//! A board of `squares_x × squares_y` squares of edge `square_m`, as OpenCV's `CharucoBoard::draw` draws
//! it: the origin is the board's outer top-left corner, `x` runs to the right along a row of squares, `y`
//! *down* a column, and `z = x × y` points into the board (away from the printed side), as for
//! [`super::Checkerboard`].
//!
//! * Square `(i, j)` (column `i`, row `j` from the top left) covers `x ∈ [i·s, (i+1)·s]`,
//!   `y ∈ [j·s, (j+1)·s]`; it is black when `i + j` is even (the top-left square is black).
//! * Every white square holds a marker of edge `marker_m` (black border included) centred in it, printed
//!   upright (its top row of cells towards `−y`). Marker ids are `0, 1, 2, …` in row-major order of the
//!   white squares; marker corners in OpenCV's order (top-left, top-right, bottom-right, bottom-left) are
//!   `(x0, y0)`, `(x0 + m, y0)`, `(x0 + m, y0 + m)`, `(x0, y0 + m)` with `x0 = i·s + (s − m)/2`,
//!   `y0 = j·s + (s − m)/2`.
//! * The chessboard corners (where four squares meet) are numbered row-major: corner
//!   `k = j·(squares_x − 1) + i`, `i < squares_x − 1`, `j < squares_y − 1`, is at `((i+1)·s, (j+1)·s, 0)`.
//!
//! The markers fix every corner's identity, so unlike a checkerboard a ChArUco board is never ambiguous
//! and a partial view still gives its corners. Boards with an even number of rows printed by OpenCV
//! before 4.6 (OpenCV ≥ 4.8 calls it the *legacy pattern*) have their top-left square white; OpenCV 4.6
//! does not read them, and neither does depthcal.
//!
//! # `cell.toml`
//!
//! ```toml
//! [board]
//! type = "charuco"
//! squares_x = 5              # squares along the board x axis (a row)
//! squares_y = 7              # squares along the board y axis (a column)
//! square_m = 0.04            # square edge, metres
//! marker_m = 0.02            # marker edge (black border included), metres; < square_m
//! dictionary = "DICT_6X6_250"
//! ```

use super::markers::MarkerDictionary;
use crate::error::{Error, Result};
use nalgebra::{Matrix2, Point3};
use serde::{Deserialize, Serialize};
use std::fmt;

/// The keys of a ChArUco `[board]` table besides `type`.
pub const CHARUCO_KEYS: &[&str] = &[
    "squares_x",
    "squares_y",
    "square_m",
    "marker_m",
    "dictionary",
];

/// A ChArUco calibration board (see the module documentation for its frame and layout).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharucoBoard {
    /// Squares along the board x axis (a row), at least 3.
    pub squares_x: u32,
    /// Squares along the board y axis (a column), at least 3.
    pub squares_y: u32,
    /// Square edge, metres.
    pub square_m: f64,
    /// Marker edge (black border included), metres; less than `square_m`.
    pub marker_m: f64,
    /// The markers' dictionary; it must hold at least [`CharucoBoard::marker_count`] markers.
    pub dictionary: MarkerDictionary,
}

/// Why a board's values are wrong: the key and the message.
pub type KeyError = (String, String);

impl CharucoBoard {
    /// A checked board; the error names the field.
    pub fn new(
        squares_x: u32,
        squares_y: u32,
        square_m: f64,
        marker_m: f64,
        dictionary: MarkerDictionary,
    ) -> Result<Self> {
        let b = CharucoBoard {
            squares_x,
            squares_y,
            square_m,
            marker_m,
            dictionary,
        };
        b.validate()
            .map_err(|(k, msg)| Error::config(format!("board.{k}"), msg))?;
        Ok(b)
    }

    /// Checks the values: the key that is wrong and why.
    pub fn validate(&self) -> std::result::Result<(), KeyError> {
        for (k, n) in [("squares_x", self.squares_x), ("squares_y", self.squares_y)] {
            if !(3..=200).contains(&n) {
                return Err((
                    k.into(),
                    format!(
                        "`{k}` counts squares (not inner corners) and must be 3–200, found {n}"
                    ),
                ));
            }
        }
        if !(self.square_m.is_finite() && self.square_m > 0.0 && self.square_m <= 1.0) {
            return Err((
                "square_m".into(),
                format!(
                    "`square_m` must be the square edge in metres (0 < square_m ≤ 1, e.g. 0.04 for 40 mm), \
                     found {}",
                    self.square_m
                ),
            ));
        }
        if !(self.marker_m.is_finite() && self.marker_m > 0.0) {
            return Err((
                "marker_m".into(),
                format!(
                    "`marker_m` must be the marker edge in metres, found {}",
                    self.marker_m
                ),
            ));
        }
        if self.marker_m >= self.square_m {
            return Err((
                "marker_m".into(),
                format!(
                    "`marker_m` = {} m must be smaller than `square_m` = {} m: the marker sits inside a \
                     white square",
                    self.marker_m, self.square_m
                ),
            ));
        }
        let n = self.marker_count();
        if n > self.dictionary.marker_count() {
            return Err((
                "dictionary".into(),
                format!(
                    "a {}x{} board has {n} markers but {} has only {} (ids 0–{}); use a larger dictionary",
                    self.squares_x,
                    self.squares_y,
                    self.dictionary,
                    self.dictionary.marker_count(),
                    self.dictionary.marker_count() - 1
                ),
            ));
        }
        Ok(())
    }

    /// Number of markers (white squares): `⌊squares_x · squares_y / 2⌋`.
    pub fn marker_count(&self) -> u32 {
        self.squares_x * self.squares_y / 2
    }

    /// Number of chessboard corners: `(squares_x − 1)·(squares_y − 1)`.
    pub fn corner_count(&self) -> usize {
        ((self.squares_x - 1) * (self.squares_y - 1)) as usize
    }

    /// Chessboard corner `id` in the board frame (metres, `z = 0`); `None` for an id beyond the board.
    pub fn corner_point(&self, id: u32) -> Option<Point3<f64>> {
        let cols = self.squares_x - 1;
        if id as usize >= self.corner_count() {
            return None;
        }
        let (i, j) = (id % cols, id / cols);
        Some(Point3::new(
            (i + 1) as f64 * self.square_m,
            (j + 1) as f64 * self.square_m,
            0.0,
        ))
    }

    /// Every chessboard corner in the board frame, by id.
    pub fn object_points(&self) -> Vec<Point3<f64>> {
        (0..self.corner_count() as u32)
            .filter_map(|k| self.corner_point(k))
            .collect()
    }

    /// The square `(column, row)` of marker `id`; `None` for an id beyond the board.
    pub fn marker_square(&self, id: u32) -> Option<(u32, u32)> {
        if id >= self.marker_count() {
            return None;
        }
        // White squares have i + j odd; row j holds those with i ≡ j + 1 (mod 2).
        let mut k = id;
        for j in 0..self.squares_y {
            let first = (j + 1) % 2;
            let in_row = (self.squares_x - first).div_ceil(2);
            if k < in_row {
                return Some((first + 2 * k, j));
            }
            k -= in_row;
        }
        None
    }

    /// The marker in square `(column, row)`: its id, or `None` for a black square or one beyond the
    /// board.
    pub fn marker_in_square(&self, i: u32, j: u32) -> Option<u32> {
        if i >= self.squares_x || j >= self.squares_y || (i + j).is_multiple_of(2) {
            return None;
        }
        // White squares before row j, then those before column i in row j.
        let before_rows: u32 = (0..j)
            .map(|r| (self.squares_x - (r + 1) % 2).div_ceil(2))
            .sum();
        Some(before_rows + i / 2)
    }

    /// The four corners of marker `id` in the board frame (metres), in OpenCV's order: top-left,
    /// top-right, bottom-right, bottom-left as printed.
    pub fn marker_corners(&self, id: u32) -> Option<[Point3<f64>; 4]> {
        let (i, j) = self.marker_square(id)?;
        let (s, m) = (self.square_m, self.marker_m);
        let x0 = i as f64 * s + (s - m) / 2.0;
        let y0 = j as f64 * s + (s - m) / 2.0;
        Some([
            Point3::new(x0, y0, 0.0),
            Point3::new(x0 + m, y0, 0.0),
            Point3::new(x0 + m, y0 + m, 0.0),
            Point3::new(x0, y0 + m, 0.0),
        ])
    }

    /// Size of the printed pattern, metres: `[squares_x·s, squares_y·s]`.
    pub fn size_m(&self) -> [f64; 2] {
        [
            self.squares_x as f64 * self.square_m,
            self.squares_y as f64 * self.square_m,
        ]
    }

    /// True when the corners `ids` all lie on one line (or are fewer than three): no board pose follows
    /// from them. Ids beyond the board are ignored.
    pub fn corners_collinear(&self, ids: &[u32]) -> bool {
        let p: Vec<Point3<f64>> = ids.iter().filter_map(|&k| self.corner_point(k)).collect();
        if p.len() < 3 {
            return true;
        }
        let n = p.len() as f64;
        let (mx, my) = (
            p.iter().map(|q| q.x).sum::<f64>() / n,
            p.iter().map(|q| q.y).sum::<f64>() / n,
        );
        let mut c = Matrix2::zeros();
        for q in &p {
            let (dx, dy) = (q.x - mx, q.y - my);
            c += Matrix2::new(dx * dx, dx * dy, dx * dy, dy * dy);
        }
        let e = c.symmetric_eigenvalues();
        let (lo, hi) = (e.min(), e.max());
        // Grid points off one line spread at least (s/2)² / n in the second direction.
        lo <= 1e-9 * hi.max(self.square_m * self.square_m)
    }

    /// Reads the ChArUco keys of a `[board]` table (`type` already checked); the error names the key.
    pub fn from_table(t: &toml::Table) -> std::result::Result<Self, KeyError> {
        for k in t.keys() {
            if k != "type" && !CHARUCO_KEYS.contains(&k.as_str()) {
                let hint = super::near_miss(k, CHARUCO_KEYS)
                    .map(|n| format!(" (did you mean `{n}`?)"))
                    .unwrap_or_default();
                return Err((
                    k.clone(),
                    format!(
                        "unknown key `{k}`{hint}; a ChArUco board has type = \"charuco\", {}",
                        CHARUCO_KEYS.join(", ")
                    ),
                ));
            }
        }
        let count = |k: &'static str| -> std::result::Result<u32, KeyError> {
            match t.get(k) {
                None => Err((
                    k.into(),
                    format!("`{k}` is missing (squares, e.g. {k} = 5)"),
                )),
                Some(toml::Value::Integer(n)) if (0..=u32::MAX as i64).contains(n) => Ok(*n as u32),
                Some(v) => Err((
                    k.into(),
                    format!("`{k}` must be a whole number of squares, found {v}"),
                )),
            }
        };
        let length = |k: &'static str| -> std::result::Result<f64, KeyError> {
            match t.get(k) {
                None => Err((
                    k.into(),
                    format!("`{k}` is missing (an edge in metres, e.g. 0.04)"),
                )),
                Some(toml::Value::Float(x)) => Ok(*x),
                Some(toml::Value::Integer(n)) => Ok(*n as f64),
                Some(v) => Err((
                    k.into(),
                    format!("`{k}` must be a length in metres, found {v}"),
                )),
            }
        };
        let dictionary = match t.get("dictionary") {
            None => {
                return Err((
                    "dictionary".into(),
                    "`dictionary` is missing (e.g. \"DICT_6X6_250\")".into(),
                ))
            }
            Some(toml::Value::String(s)) => s
                .parse::<MarkerDictionary>()
                .map_err(|e| ("dictionary".to_string(), e.to_string()))?,
            Some(v) => {
                return Err((
                    "dictionary".into(),
                    format!("`dictionary` must be a name such as \"DICT_6X6_250\", found {v}"),
                ))
            }
        };
        let b = CharucoBoard {
            squares_x: count("squares_x")?,
            squares_y: count("squares_y")?,
            square_m: length("square_m")?,
            marker_m: length("marker_m")?,
            dictionary,
        };
        b.validate()?;
        Ok(b)
    }

    /// The `[board]` table as it is written to `cell.toml` (with `type = "charuco"`).
    pub fn to_toml(&self) -> toml::Value {
        let mut t = toml::Table::new();
        t.insert("type".into(), "charuco".into());
        t.insert("squares_x".into(), (self.squares_x as i64).into());
        t.insert("squares_y".into(), (self.squares_y as i64).into());
        t.insert("square_m".into(), self.square_m.into());
        t.insert("marker_m".into(), self.marker_m.into());
        t.insert("dictionary".into(), self.dictionary.to_string().into());
        toml::Value::Table(t)
    }
}

impl fmt::Display for CharucoBoard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "ChArUco {}x{} squares of {} mm, {} mm {} markers",
            self.squares_x,
            self.squares_y,
            self.square_m * 1e3,
            self.marker_m * 1e3,
            self.dictionary
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn board() -> CharucoBoard {
        CharucoBoard::new(5, 7, 0.04, 0.02, MarkerDictionary::Aruco6x6_250).unwrap()
    }

    #[test]
    fn layout_is_opencv_4_6s() {
        let b = board();
        assert_eq!((b.marker_count(), b.corner_count()), (17, 24));
        // OpenCV 4.6 (measured): marker 0 at (0.05, 0.01)–(0.07, 0.03), marker 2 in square (0, 1),
        // corner 0 at (0.04, 0.04), corner 4 at (0.04, 0.08).
        let m0 = b.marker_corners(0).unwrap();
        assert!((m0[0] - Point3::new(0.05, 0.01, 0.0)).norm() < 1e-12);
        assert!((m0[2] - Point3::new(0.07, 0.03, 0.0)).norm() < 1e-12);
        assert_eq!(b.marker_square(1), Some((3, 0)));
        assert_eq!(b.marker_square(2), Some((0, 1)));
        assert_eq!(b.marker_square(16), Some((3, 6)));
        assert_eq!(b.marker_square(17), None);
        assert_eq!(b.corner_point(4), Some(Point3::new(0.04, 0.08, 0.0)));
        assert_eq!(b.corner_point(24), None);
        for id in 0..b.marker_count() {
            let (i, j) = b.marker_square(id).unwrap();
            assert_eq!((i + j) % 2, 1, "marker {id} in a black square");
            assert_eq!(b.marker_in_square(i, j), Some(id));
        }
        assert_eq!(b.marker_in_square(0, 0), None);
        assert_eq!(b.marker_in_square(5, 0), None);
        // Even rows and columns.
        let e = CharucoBoard::new(4, 6, 0.04, 0.03, MarkerDictionary::Aruco4x4_50).unwrap();
        assert_eq!(e.marker_count(), 12);
        for id in 0..12 {
            let (i, j) = e.marker_square(id).unwrap();
            assert_eq!(e.marker_in_square(i, j), Some(id));
        }
    }

    #[test]
    fn collinear_corners_are_told() {
        let b = board();
        assert!(b.corners_collinear(&[0, 1, 2, 3]));
        assert!(b.corners_collinear(&[0, 5, 10, 15])); // a diagonal
        assert!(b.corners_collinear(&[0, 1]));
        assert!(!b.corners_collinear(&[0, 1, 4]));
    }

    #[test]
    fn table_round_trip_and_errors_name_the_key() {
        let b = board();
        let t = b.to_toml();
        assert_eq!(CharucoBoard::from_table(t.as_table().unwrap()).unwrap(), b);
        let bad = |text: &str| -> KeyError {
            let t: toml::Table = toml::from_str(text).unwrap();
            CharucoBoard::from_table(&t).unwrap_err()
        };
        let base = "squares_x = 5\nsquares_y = 7\nsquare_m = 0.04\ndictionary = \"6x6_250\"\n";
        let (k, m) = bad(&format!("{base}marker_m = 0.04\n"));
        assert!(
            k == "marker_m" && m.contains("smaller than `square_m`"),
            "{m}"
        );
        let (k, m) = bad(&format!("{base}marker_m = 0.05\n"));
        assert!(k == "marker_m", "{m}");
        let (k, _) = bad(&format!("{base}marker_m = -0.01\n"));
        assert_eq!(k, "marker_m");
        let (k, m) = bad(&format!("{base}marker_m = 0.02\nmarker_size = 1\n"));
        assert!(
            m.contains("`marker_size`") && m.contains("marker_m"),
            "{k}: {m}"
        );
        let (k, m) = bad("squares_x = 5\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.02\n");
        assert!(k == "dictionary" && m.contains("missing"), "{m}");
        let (k, m) = bad(
            "squares_x = 5\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.02\ndictionary = \"7x7\"\n",
        );
        assert!(
            k == "dictionary" && m.contains("unknown marker dictionary"),
            "{m}"
        );
        let (k, m) = bad(
            "squares_x = 12\nsquares_y = 12\nsquare_m = 0.04\nmarker_m = 0.02\ndictionary = \"4x4_50\"\n",
        );
        assert!(k == "dictionary" && m.contains("72 markers"), "{m}");
        let (k, m) = bad(
            "squares_x = 2\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.02\ndictionary = \"4x4_50\"\n",
        );
        assert!(k == "squares_x" && m.contains("3–200"), "{m}");
        let (k, m) = bad(
            "squares_x = \"5\"\nsquares_y = 7\nsquare_m = 0.04\nmarker_m = 0.02\ndictionary = \"4x4_50\"\n",
        );
        assert!(k == "squares_x" && m.contains("whole number"), "{m}");
        let (k, m) = bad(
            "squares_x = 5\nsquares_y = 7\nsquare_m = 40\nmarker_m = 20\ndictionary = \"4x4_50\"\n",
        );
        assert!(k == "square_m" && m.contains("metres"), "{m}");
        let (k, _) =
            bad("squares_x = 5\nsquare_m = 0.04\nmarker_m = 0.02\ndictionary = \"4x4_50\"\n");
        assert_eq!(k, "squares_y");
    }
}
