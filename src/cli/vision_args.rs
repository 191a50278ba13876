//! Command-line pieces shared by the commands of the checkerboard workflow (`intrinsics`, `handeye --images`,
//! `calibrate --method checkerboard`), and the message of a build without the `vision` feature.

use clap::Args as ClapArgs;
use depthcal::cell::board::{parse_board_size, parse_length_m};
use depthcal::cell::Checkerboard;

/// What a command that needs OpenCV says in a build without the `vision` feature.
#[cfg_attr(feature = "vision", allow(dead_code))]
pub const WITHOUT_VISION: &str = "this depthcal was built without the `vision` feature (OpenCV), which \
    this needs; rebuild with `cargo build --release --features vision` on a machine with OpenCV 4 and \
    libclang (Debian: `source .ci/setup-vision.sh` installs them)";

/// The checkerboard on the command line.
#[derive(ClapArgs, Clone, Debug, Default)]
pub struct BoardArgs {
    /// Checkerboard inner corners COLSxROWS, e.g. 9x6 (corners where four squares meet, not squares).
    #[arg(long, value_name = "COLSxROWS", value_parser = parse_board_size)]
    pub board: Option<(u32, u32)>,
    /// Checkerboard square edge: metres, or with a unit (0.025, 25mm, 2.5cm).
    #[arg(long, value_name = "SIZE", value_parser = parse_length_m)]
    pub square: Option<f64>,
}

impl BoardArgs {
    /// The board, when both flags are given; errors naming the missing flag otherwise.
    #[cfg_attr(not(feature = "vision"), allow(dead_code))]
    pub fn board(&self) -> anyhow::Result<Checkerboard> {
        match (self.board, self.square) {
            (Some((c, r)), Some(s)) => Ok(Checkerboard::new(c, r, s)?),
            (None, _) => anyhow::bail!("--board COLSxROWS is missing (inner corners, e.g. 9x6)"),
            (_, None) => {
                anyhow::bail!("--square SIZE is missing (square edge, e.g. 0.025 or 25mm)")
            }
        }
    }

    /// True when either flag is given.
    #[cfg_attr(not(feature = "sim"), allow(dead_code))]
    pub fn given(&self) -> bool {
        self.board.is_some() || self.square.is_some()
    }
}
