//! A printed checkerboard or ChArUco board lying on the table, for the board workflow (hand-eye from
//! images, robot-to-robot by board) with exact ground truth.
//!
//! The board is a sheet of zero thickness on the table top (it changes the colour image, not the depth).
//! Its frame follows [`Checkerboard`] (origin at inner corner 0) or [`CharucoBoard`] (origin at the outer
//! top-left corner, OpenCV 4.6's): `x` along a row, `z` into the board, here straight down into the table,
//! so that a camera above sees the printed side. Objects are kept off the sheet
//! ([`SimBoard::overlaps_disc`]) so that views from above see the whole pattern.
//!
//! A ChArUco board is printed as OpenCV's `CharucoBoard::draw` draws it: top-left square black, a marker
//! of the board's dictionary in each white square, ids row-major, upright (the codes are OpenCV's, from
//! [`super::marker::marker_code`]; a `vision` test compares the rendering with OpenCV's own image).
//!
//! In the colour image a pixel on the sheet gets the mean albedo of `supersample²` sub-pixel rays (each
//! intersected with the table plane exactly), so edges are antialiased by their pixel coverage; the image
//! is then blurred by a Gaussian of `blur_sigma_px` (optics) before the sensor grain of the renderer.

use super::marker::marker_code;
use crate::camera::Intrinsics;
use crate::cell::{Board, CharucoBoard, Checkerboard};
use crate::error::{Error, Result};
use crate::geometry::Rng;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// The ChArUco board `simulate --charuco` prints unless told otherwise: 7x5 squares of 40 mm with 30 mm
/// `DICT_4X4_50` markers (4x4 markers have the largest cells for their size: 5 mm here, about 4 px at
/// 0.75 m in a 640x480 view).
pub const DEFAULT_CHARUCO: CharucoBoard = CharucoBoard {
    squares_x: 7,
    squares_y: 5,
    square_m: 0.04,
    marker_m: 0.03,
    dictionary: crate::cell::MarkerDictionary::Aruco4x4_50,
};

/// Settings of the simulated board (metres, degrees). Every field has a default.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimBoardConfig {
    /// Inner corners along the board x axis (default 9).
    pub cols: u32,
    /// Inner corners along the board y axis (default 6).
    pub rows: u32,
    /// Square edge, metres (default 0.03).
    pub square_m: f64,
    /// Centre of the pattern on the table top, table-frame `[x, y]`, metres (default `[0, 0]`).
    pub center_m: [f64; 2],
    /// The board's yaw is uniform in ± this, degrees (default 180).
    pub yaw_range_deg: f64,
    /// White paper around the pattern, metres (default 0.02).
    pub margin_m: f64,
    /// Linear albedo of the black and the white squares (default `[0.04, 0.85]`).
    pub albedo: [f64; 2],
    /// Sub-pixel rays per axis for the pixel coverage (default 6: 36 rays per pixel).
    pub supersample: u32,
    /// Gaussian blur of the colour image (optics), pixels (default 0.7; 0 = none).
    pub blur_sigma_px: f64,
    /// A ChArUco board instead of the checkerboard (default none): `squares_x`, `squares_y`, `square_m`,
    /// `marker_m`, `dictionary` (one the simulator prints: `DICT_4X4_50`, `DICT_5X5_100`,
    /// `DICT_6X6_250`, `tag36h11`). When given, `cols`, `rows` and `square_m` above are not used.
    pub charuco: Option<CharucoBoard>,
}

impl Default for SimBoardConfig {
    fn default() -> Self {
        SimBoardConfig {
            cols: 9,
            rows: 6,
            square_m: 0.03,
            center_m: [0.0, 0.0],
            yaw_range_deg: 180.0,
            margin_m: 0.02,
            albedo: [0.04, 0.85],
            supersample: 6,
            blur_sigma_px: 0.7,
            charuco: None,
        }
    }
}

impl SimBoardConfig {
    /// The board geometry: the ChArUco board when `charuco` is given, else the checkerboard.
    pub fn board(&self) -> Result<Board> {
        if let Some(c) = &self.charuco {
            c.validate()
                .map_err(|(k, msg)| Error::config(format!("scene.board.charuco.{k}"), msg))?;
            return Ok(Board::Charuco(*c));
        }
        Checkerboard::new(self.cols, self.rows, self.square_m)
            .map(Board::Checkerboard)
            .map_err(|e| match e {
                Error::Config { msg, .. } => Error::Config {
                    field: "scene.board".into(),
                    msg,
                },
                e => e,
            })
    }

    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        self.board()?;
        if let Some(c) = &self.charuco {
            // The simulator prints the markers of its own dictionaries only.
            for id in [0, c.marker_count() - 1] {
                marker_code(&c.dictionary.to_string(), id)
                    .map_err(|e| Error::config("scene.board.charuco.dictionary", e.to_string()))?;
            }
        }
        let bad = |f: &str, msg: String| {
            Err(Error::Config {
                field: format!("scene.board.{f}"),
                msg,
            })
        };
        if !(self.margin_m.is_finite() && self.margin_m >= 0.0) {
            return bad("margin_m", format!("must be ≥ 0, found {}", self.margin_m));
        }
        validate_print_look(
            "scene.board",
            self.albedo,
            self.supersample,
            self.blur_sigma_px,
        )?;
        let finite = self.center_m.iter().all(|v| v.is_finite());
        if !(self.yaw_range_deg.is_finite() && self.yaw_range_deg >= 0.0 && finite) {
            return bad(
                "yaw_range_deg / center_m",
                "must be finite (yaw range ≥ 0)".into(),
            );
        }
        Ok(())
    }
}

/// A board placed on the table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimBoard {
    /// The board geometry.
    pub board: Board,
    /// Pose of the board frame in the world (table) frame, metres (`z` points down into the table).
    pub t_world_board: Isometry3<f64>,
    /// The settings it was made from.
    pub config: SimBoardConfig,
    /// A ChArUco board's marker codes by id ([`marker_code`]'s bits; empty for a checkerboard).
    pub codes: Vec<u64>,
    /// Inner bits per side of the ChArUco markers (0 for a checkerboard).
    pub bits: u32,
}

impl SimBoard {
    /// Places the board of `cfg` on the table top (`z = 0`) with a random yaw drawn from `rng`.
    pub fn place(cfg: &SimBoardConfig, rng: &mut Rng) -> Result<Self> {
        cfg.validate()?;
        let board = cfg.board()?;
        let r = cfg.yaw_range_deg.to_radians();
        let yaw = rng.uniform(-r, r);
        // z down: a half turn about x, then the yaw about the world z.
        let rot = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let [x0, x1, y0, y1] = pattern(&board);
        let half = Vector3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
        let centre = Vector3::new(cfg.center_m[0], cfg.center_m[1], 0.0);
        let origin = centre - rot * half;
        let (codes, bits) = match &board {
            Board::Checkerboard(_) => (Vec::new(), 0),
            Board::Charuco(c) => {
                let name = c.dictionary.to_string();
                let mut codes = Vec::with_capacity(c.marker_count() as usize);
                let mut bits = 0;
                for id in 0..c.marker_count() {
                    let (n, code) = marker_code(&name, id)?;
                    bits = n;
                    codes.push(code);
                }
                (codes, bits)
            }
        };
        Ok(SimBoard {
            board,
            t_world_board: Isometry3::from_parts(Translation3::from(origin), rot),
            config: cfg.clone(),
            codes,
            bits,
        })
    }

    /// The sheet (pattern and margin) in board coordinates: `[x0, x1, y0, y1]`, metres.
    fn sheet(&self) -> [f64; 4] {
        let m = self.config.margin_m;
        let [x0, x1, y0, y1] = pattern(&self.board);
        [x0 - m, x1 + m, y0 - m, y1 + m]
    }

    /// The printed colour at board point `(x, y)` (metres): `Some(true)` black, `Some(false)` white,
    /// `None` off the pattern.
    pub fn is_black(&self, x: f64, y: f64) -> Option<bool> {
        match &self.board {
            Board::Checkerboard(b) => b.is_black(x, y),
            Board::Charuco(b) => charuco_is_black(b, &self.codes, self.bits, x, y),
        }
    }

    /// True when a disc of radius `r` (metres) centred at table point `c` overlaps the sheet.
    pub fn overlaps_disc(&self, c: [f64; 2], r: f64) -> bool {
        let p = self.t_world_board.inverse() * Point3::new(c[0], c[1], 0.0);
        let [x0, x1, y0, y1] = self.sheet();
        let dx = (x0 - p.x).max(p.x - x1).max(0.0);
        let dy = (y0 - p.y).max(p.y - y1).max(0.0);
        dx.hypot(dy) < r
    }

    /// The `[board]` table of `cell.toml`.
    pub fn manifest_table(&self) -> toml::Value {
        self.board.to_toml()
    }
}

/// A print lying on the table top (the board, the markers): its albedo at table points, rendered by pixel
/// coverage ([`footprint_albedo`]).
pub trait TablePrint {
    /// Linear albedo of the table point `(x, y, 0)`: `None` off the print.
    fn albedo_at(&self, x: f64, y: f64) -> Option<f64>;

    /// Sub-pixel rays per axis for the pixel coverage.
    fn supersample(&self) -> u32;

    /// Mean albedo over the footprint of pixel `(u, v)` of a camera at `t_world_cam` (see
    /// [`footprint_albedo`]), or `None` when the pixel centre's ray does not meet the print.
    fn pixel_albedo(
        &self,
        intr: &Intrinsics,
        t_world_cam: &Isometry3<f64>,
        u: f64,
        v: f64,
        table: &dyn Fn(f64, f64) -> f64,
    ) -> Option<f64> {
        footprint_albedo(
            intr,
            t_world_cam,
            u,
            v,
            self.supersample(),
            &|x, y| self.albedo_at(x, y),
            table,
        )
    }
}

impl TablePrint for SimBoard {
    fn albedo_at(&self, x: f64, y: f64) -> Option<f64> {
        let p = self.t_world_board.inverse() * Point3::new(x, y, 0.0);
        let [x0, x1, y0, y1] = self.sheet();
        if p.x < x0 || p.x > x1 || p.y < y0 || p.y > y1 {
            return None;
        }
        let [black, white] = self.config.albedo;
        Some(match self.is_black(p.x, p.y) {
            Some(true) => black,
            _ => white,
        })
    }

    fn supersample(&self) -> u32 {
        self.config.supersample
    }
}

/// The pattern's extent in board coordinates, `[x0, x1, y0, y1]` (metres): a checkerboard's squares run
/// from one square before inner corner 0, a ChArUco board's from its origin.
fn pattern(board: &Board) -> [f64; 4] {
    match board {
        Board::Checkerboard(b) => {
            let s = b.square_m;
            [-s, b.cols as f64 * s, -s, b.rows as f64 * s]
        }
        Board::Charuco(b) => {
            let [w, h] = b.size_m();
            [0.0, w, 0.0, h]
        }
    }
}

/// The colour of a ChArUco board at board point `(x, y)` (metres; see [`CharucoBoard`] for the layout):
/// `codes[id]` are the markers' bits (`bits²` of them, row-major from the top-left inner cell as printed,
/// most significant first, 1 = white). `None` off the pattern.
fn charuco_is_black(b: &CharucoBoard, codes: &[u64], bits: u32, x: f64, y: f64) -> Option<bool> {
    let s = b.square_m;
    let (fi, fj) = ((x / s).floor(), (y / s).floor());
    if fi < 0.0 || fj < 0.0 || fi >= b.squares_x as f64 || fj >= b.squares_y as f64 {
        return None;
    }
    let (i, j) = (fi as u32, fj as u32);
    let Some(id) = b.marker_in_square(i, j) else {
        return Some(true);
    };
    // Inside the square: white paper around a marker of `bits + 2` cells per side (one-cell black border).
    let m = b.marker_m;
    let (mx, my) = (
        x - i as f64 * s - (s - m) / 2.0,
        y - j as f64 * s - (s - m) / 2.0,
    );
    if mx < 0.0 || my < 0.0 || mx >= m || my >= m {
        return Some(false);
    }
    let n = bits as i64;
    let cell = m / (n + 2) as f64;
    // Column from the left, row from the top as printed (board y runs down the print).
    let c = ((mx / cell).floor() as i64).clamp(0, n + 1);
    let r = ((my / cell).floor() as i64).clamp(0, n + 1);
    if c == 0 || r == 0 || c == n + 1 || r == n + 1 {
        return Some(true);
    }
    let k = (r - 1) * n + (c - 1);
    let code = codes.get(id as usize)?;
    Some((code >> (n * n - 1 - k)) & 1 == 0)
}

/// Checks the look of a print on the table (black and white albedo, sub-pixel rays, blur); the error
/// names `prefix.field`.
pub(crate) fn validate_print_look(
    prefix: &str,
    albedo: [f64; 2],
    supersample: u32,
    blur_sigma_px: f64,
) -> Result<()> {
    let bad = |f: &str, msg: String| {
        Err(Error::Config {
            field: format!("{prefix}.{f}"),
            msg,
        })
    };
    if !albedo.iter().all(|a| (0.0..=1.0).contains(a)) || albedo[0] >= albedo[1] {
        return bad(
            "albedo",
            format!("must be [black, white] in [0, 1] with black < white, found {albedo:?}"),
        );
    }
    if !(1..=16).contains(&supersample) {
        return bad("supersample", format!("must be 1–16, found {supersample}"));
    }
    if !(blur_sigma_px.is_finite() && (0.0..=5.0).contains(&blur_sigma_px)) {
        return bad(
            "blur_sigma_px",
            format!("must be in [0, 5] pixels, found {blur_sigma_px}"),
        );
    }
    Ok(())
}

/// Mean albedo over the footprint of pixel `(u, v)` of a camera at `t_world_cam` on a print lying on the
/// table top (`z = 0`): `supersample²` sub-pixel rays, each intersected with the table plane exactly. `print`
/// gives the print's albedo at a table point (`None` off the print), `table` the table's. `None` when the
/// pixel centre's ray does not meet the print.
pub fn footprint_albedo(
    intr: &Intrinsics,
    t_world_cam: &Isometry3<f64>,
    u: f64,
    v: f64,
    supersample: u32,
    print: &dyn Fn(f64, f64) -> Option<f64>,
    table: &dyn Fn(f64, f64) -> f64,
) -> Option<f64> {
    let o = t_world_cam.translation.vector;
    let hit = |pu: f64, pv: f64| -> Option<(f64, f64)> {
        let [x, y] = intr.pixel_ray([pu, pv]);
        let d = t_world_cam.rotation * Vector3::new(x, y, 1.0);
        if d.z >= -1e-12 || o.z <= 0.0 {
            return None;
        }
        let t = -o.z / d.z;
        Some((o.x + t * d.x, o.y + t * d.y))
    };
    let (cx, cy) = hit(u, v)?;
    print(cx, cy)?;
    let n = supersample.max(1);
    let mut sum = 0.0;
    let mut count = 0usize;
    for j in 0..n {
        for i in 0..n {
            let du = (i as f64 + 0.5) / n as f64 - 0.5;
            let dv = (j as f64 + 0.5) / n as f64 - 0.5;
            if let Some((x, y)) = hit(u + du, v + dv) {
                sum += print(x, y).unwrap_or_else(|| table(x, y));
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64)
}

/// Separable Gaussian blur of an interleaved image with `channels` channels (edge pixels repeated).
/// Returns the blurred values as `f32`; `sigma` in pixels (≤ 0: a copy).
pub fn gaussian_blur(
    data: &[u8],
    width: usize,
    height: usize,
    channels: usize,
    sigma: f64,
) -> Vec<f32> {
    let src: Vec<f32> = data.iter().map(|&v| v as f32).collect();
    if sigma <= 0.0 || width == 0 || height == 0 {
        return src;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let (w, h, c) = (width as isize, height as isize, channels);
    let mut tmp = vec![0f32; src.len()];
    for y in 0..h {
        for x in 0..w {
            for ch in 0..c {
                let mut acc = 0.0;
                for (t, kv) in k.iter().enumerate() {
                    let xx = (x + t as isize - r).clamp(0, w - 1);
                    acc += kv * src[((y * w + xx) as usize) * c + ch];
                }
                tmp[((y * w + x) as usize) * c + ch] = acc;
            }
        }
    }
    let mut out = vec![0f32; src.len()];
    for y in 0..h {
        for x in 0..w {
            for ch in 0..c {
                let mut acc = 0.0;
                for (t, kv) in k.iter().enumerate() {
                    let yy = (y + t as isize - r).clamp(0, h - 1);
                    acc += kv * tmp[((yy * w + x) as usize) * c + ch];
                }
                out[((y * w + x) as usize) * c + ch] = acc;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placement_frame_and_colours() {
        let cfg = SimBoardConfig {
            center_m: [0.1, -0.05],
            ..Default::default()
        };
        let b = SimBoard::place(&cfg, &mut Rng::new(3)).unwrap();
        // z points down; the pattern centre is where asked.
        let z = b.t_world_board.rotation * Vector3::z();
        assert!((z - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        let c = b.t_world_board * Point3::new(4.0 * 0.03, 2.5 * 0.03, 0.0);
        assert!((c.x - 0.1).abs() < 1e-12 && (c.y + 0.05).abs() < 1e-12 && c.z.abs() < 1e-12);
        // Square (0, 0) (before corner 0) is black; (1, 0) white; the margin is white paper.
        let at = |x: f64, y: f64| {
            let p = b.t_world_board * Point3::new(x, y, 0.0);
            b.albedo_at(p.x, p.y)
        };
        let near = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-9);
        assert!(near(at(-0.015, -0.015), 0.04));
        assert!(near(at(0.015, -0.015), 0.85));
        assert!(near(at(-0.035, -0.015), 0.85));
        assert_eq!(at(-0.06, 0.0), None);
        assert!(b.overlaps_disc([0.1, -0.05], 0.01));
        assert!(!b.overlaps_disc([0.6, 0.6], 0.05));
    }

    #[test]
    fn pixel_coverage_is_the_area_fraction() {
        // A camera 0.5 m above the board, looking straight down: a pixel straddling an edge gets the
        // coverage-weighted albedo, a pixel inside a square the square's albedo.
        let cfg = SimBoardConfig {
            yaw_range_deg: 0.0,
            supersample: 16,
            ..Default::default()
        };
        let b = SimBoard::place(&cfg, &mut Rng::new(1)).unwrap();
        let intr = Intrinsics::pinhole(640, 480, 500.0, 500.0, 320.0, 240.0);
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let cam = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.5), down);
        let t_cam_board = cam.inverse() * b.t_world_board;
        let proj =
            |x: f64, y: f64| intr.project((t_cam_board * Point3::new(x, y, 0.0)).coords.into());
        let table = |_: f64, _: f64| 0.5;
        // The edge x = 0.03 between squares (1, 1) (black) and (2, 1) (white), in the middle of the edge:
        // a pixel centred 0.25 px right of the edge has 3/4 of its area right of it.
        let [u, v] = proj(0.03, 0.015);
        let g = b.pixel_albedo(&intr, &cam, u + 0.25, v, &table).unwrap();
        let [u_black, _] = proj(0.015, 0.015);
        let expect = if u_black < u {
            0.25 * 0.04 + 0.75 * 0.85
        } else {
            0.25 * 0.85 + 0.75 * 0.04
        };
        assert!((g - expect).abs() < 0.01, "{g} vs {expect}");
        let [u, v] = proj(0.045, 0.045);
        let g = b.pixel_albedo(&intr, &cam, u, v, &table).unwrap();
        assert!((g - 0.04).abs() < 1e-9, "{g}");
    }

    #[test]
    fn charuco_layout_and_errors() {
        let cfg = SimBoardConfig {
            charuco: Some(DEFAULT_CHARUCO),
            yaw_range_deg: 0.0,
            ..Default::default()
        };
        let b = SimBoard::place(&cfg, &mut Rng::new(2)).unwrap();
        let s = DEFAULT_CHARUCO.square_m;
        // The pattern is centred where asked; square (0, 0) black, (1, 0) white with marker 0 in it.
        let c = b.t_world_board * Point3::new(3.5 * s, 2.5 * s, 0.0);
        assert!(c.coords.norm() < 1e-12);
        assert_eq!(b.is_black(0.5 * s, 0.5 * s), Some(true));
        assert_eq!(b.is_black(1.0 * s + 0.002, 0.5 * s), Some(false)); // white paper around the marker
        assert_eq!(b.is_black(-0.001, 0.01), None);
        assert_eq!(b.codes.len(), 17);
        // Marker 0's border is black, its cells follow its code.
        let (n, code) = marker_code("DICT_4X4_50", 0).unwrap();
        let m = DEFAULT_CHARUCO.marker_m;
        let cell = m / (n + 2) as f64;
        let (x0, y0) = (s + (s - m) / 2.0, (s - m) / 2.0);
        assert_eq!(b.is_black(x0 + cell / 2.0, y0 + 3.0 * cell), Some(true));
        for r in 0..n {
            for k in 0..n {
                let bit = (code >> (n * n - 1 - (r * n + k))) & 1;
                let at = b.is_black(x0 + (k as f64 + 1.5) * cell, y0 + (r as f64 + 1.5) * cell);
                assert_eq!(at, Some(bit == 0), "cell {r},{k}");
            }
        }
        // The simulator prints only its own dictionaries; a board too large for its dictionary is refused.
        let bad = SimBoardConfig {
            charuco: Some(CharucoBoard {
                dictionary: crate::cell::MarkerDictionary::Aruco7x7_50,
                ..DEFAULT_CHARUCO
            }),
            ..Default::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("scene.board.charuco.dictionary"), "{e}");
        let bad = SimBoardConfig {
            charuco: Some(CharucoBoard {
                marker_m: 0.05,
                ..DEFAULT_CHARUCO
            }),
            ..Default::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("scene.board.charuco.marker_m"), "{e}");
    }

    /// The simulator prints ChArUco boards as OpenCV 4.6's `CharucoBoard::draw` draws them: every square's
    /// colour and every marker cell compared at its centre, for boards of odd and even rows and the four
    /// dictionaries the simulator has.
    #[cfg(feature = "vision")]
    #[test]
    fn charuco_print_is_opencvs_drawing() {
        use crate::cell::MarkerDictionary as D;
        for (sx, sy, sq, mk, dict) in [
            (5, 7, 0.04, 0.02, D::Aruco6x6_250),
            (4, 6, 0.04, 0.03, D::Aruco4x4_50),
            (7, 5, 0.03, 0.024, D::Aruco5x5_100),
            (3, 4, 0.05, 0.04, D::AprilTag36h11),
        ] {
            let cb = CharucoBoard::new(sx, sy, sq, mk, dict).unwrap();
            let cfg = SimBoardConfig {
                charuco: Some(cb),
                yaw_range_deg: 0.0,
                ..Default::default()
            };
            let b = SimBoard::place(&cfg, &mut Rng::new(1)).unwrap();
            let px = 240u32;
            let img = crate::vision::charuco_image(&cb, px, 0).unwrap();
            let n = dict.bits() as f64;
            let cell = mk / (n + 2.0);
            let mut checked = 0;
            let mut check = |x: f64, y: f64| {
                let (u, v) = ((x / sq * px as f64) as u32, (y / sq * px as f64) as u32);
                let theirs = img.at(u, v) < 128;
                assert_eq!(
                    b.is_black(x, y),
                    Some(theirs),
                    "{cb}: board point ({x}, {y})"
                );
                checked += 1;
            };
            for j in 0..sy {
                for i in 0..sx {
                    let (x0, y0) = (i as f64 * sq, j as f64 * sq);
                    // The square's paper between its edge and the marker, and its centre.
                    check(x0 + 0.25 * (sq - mk), y0 + 0.25 * (sq - mk));
                    if cb.marker_in_square(i, j).is_none() {
                        check(x0 + sq / 2.0, y0 + sq / 2.0);
                        continue;
                    }
                    let (mx, my) = (x0 + (sq - mk) / 2.0, y0 + (sq - mk) / 2.0);
                    for r in 0..(n as u32 + 2) {
                        for c in 0..(n as u32 + 2) {
                            check(mx + (c as f64 + 0.5) * cell, my + (r as f64 + 0.5) * cell);
                        }
                    }
                }
            }
            assert!(checked > (sx * sy) as usize * 10, "{checked}");
        }
    }

    #[test]
    fn blur_keeps_the_mean_and_spreads_an_edge() {
        let (w, h) = (20, 5);
        let data: Vec<u8> = (0..w * h)
            .map(|i| if i % w < 10 { 0 } else { 200 })
            .collect();
        let b = gaussian_blur(&data, w, h, 1, 1.0);
        let mean_in: f32 = data.iter().map(|&v| v as f32).sum::<f32>() / data.len() as f32;
        let mean_out: f32 = b.iter().sum::<f32>() / b.len() as f32;
        assert!((mean_in - mean_out).abs() < 0.5);
        assert!(b[9] > 10.0 && b[9] < 100.0 && b[10] > 100.0 && b[10] < 190.0);
        assert_eq!(gaussian_blur(&data, w, h, 1, 0.0)[10], 200.0);
    }
}
