//! Command-line pieces shared by the commands of the board workflow (`intrinsics`, `handeye --images`,
//! `simulate`), and the message of a build without the `vision` feature.

use clap::Args as ClapArgs;
use depthcal::cell::board::{parse_board_size, parse_length_m};
use depthcal::cell::{Board, CharucoBoard, Checkerboard, MarkerDictionary};

/// What a command that needs OpenCV says in a build without the `vision` feature.
#[cfg_attr(feature = "vision", allow(dead_code))]
pub const WITHOUT_VISION: &str = "this depthcal was built without the `vision` feature (OpenCV), which \
    this needs; rebuild with `cargo build --release --features vision` on a machine with OpenCV 4 and \
    libclang (Debian: `source .ci/setup-vision.sh` installs them)";

/// The calibration board on the command line: a checkerboard (`--board`) or a ChArUco board
/// (`--charuco`), with `--square` for either.
#[derive(ClapArgs, Clone, Debug, Default)]
pub struct BoardArgs {
    /// Checkerboard inner corners COLSxROWS, e.g. 9x6 (corners where four squares meet, not squares).
    #[arg(long, value_name = "COLSxROWS", value_parser = parse_board_size, conflicts_with = "charuco")]
    pub board: Option<(u32, u32)>,
    /// ChArUco board of SQUARES_XxSQUARES_Y squares (OpenCV's CharucoBoard size, e.g. 5x7); with
    /// --square, --charuco-marker and --charuco-dict.
    #[arg(long, value_name = "SQUARES_XxSQUARES_Y", value_parser = parse_squares)]
    pub charuco: Option<(u32, u32)>,
    /// Square edge: metres, or with a unit (0.025, 25mm, 2.5cm).
    #[arg(long, value_name = "SIZE", value_parser = parse_length_m)]
    pub square: Option<f64>,
    /// ChArUco marker edge (black border included): metres or with a unit; smaller than --square.
    #[arg(long, value_name = "SIZE", value_parser = parse_length_m, requires = "charuco")]
    pub charuco_marker: Option<f64>,
    /// ChArUco marker dictionary, e.g. 6x6_250 (DICT_6X6_250), 5x5_100, 4x4_50.
    #[arg(long, value_name = "NAME", requires = "charuco")]
    pub charuco_dict: Option<String>,
}

/// Parses `SQUARES_XxSQUARES_Y` (ChArUco squares, e.g. `5x7`).
fn parse_squares(s: &str) -> Result<(u32, u32), String> {
    parse_board_size(s)
        .map_err(|_| format!("ChArUco size {s:?}: expected SQUARES_XxSQUARES_Y squares, e.g. 5x7"))
}

impl BoardArgs {
    /// The board, when its flags are all given; errors naming the missing or wrong flag otherwise.
    #[cfg_attr(not(feature = "vision"), allow(dead_code))]
    pub fn board(&self) -> anyhow::Result<Board> {
        let square = || {
            self.square.ok_or_else(|| {
                anyhow::anyhow!("--square SIZE is missing (square edge, e.g. 0.025 or 25mm)")
            })
        };
        if let Some((sx, sy)) = self.charuco {
            let marker = self.charuco_marker.ok_or_else(|| {
                anyhow::anyhow!(
                    "--charuco-marker SIZE is missing (the ChArUco marker edge, e.g. 20mm)"
                )
            })?;
            let dict = self.charuco_dict.as_deref().ok_or_else(|| {
                anyhow::anyhow!(
                    "--charuco-dict NAME is missing (the markers' dictionary, e.g. 6x6_250)"
                )
            })?;
            let dict: MarkerDictionary = dict
                .parse()
                .map_err(|e| anyhow::anyhow!("--charuco-dict: {e}"))?;
            let b = CharucoBoard {
                squares_x: sx,
                squares_y: sy,
                square_m: square()?,
                marker_m: marker,
                dictionary: dict,
            };
            if let Err((k, m)) = b.validate() {
                let flag = match k.as_str() {
                    "squares_x" | "squares_y" => "--charuco",
                    "square_m" => "--square",
                    "marker_m" => "--charuco-marker",
                    _ => "--charuco-dict",
                };
                anyhow::bail!("{flag}: {m}");
            }
            return Ok(Board::Charuco(b));
        }
        match self.board {
            Some((c, r)) => Ok(Board::Checkerboard(Checkerboard::new(c, r, square()?)?)),
            None => anyhow::bail!(
                "--board COLSxROWS is missing (checkerboard inner corners, e.g. 9x6; or --charuco \
                 SQUARES_XxSQUARES_Y for a ChArUco board)"
            ),
        }
    }

    /// True when any of the flags is given.
    #[cfg_attr(not(feature = "sim"), allow(dead_code))]
    pub fn given(&self) -> bool {
        self.board.is_some()
            || self.charuco.is_some()
            || self.square.is_some()
            || self.charuco_marker.is_some()
            || self.charuco_dict.is_some()
    }
}
