//! Nearest-neighbour index over 3-D positions: the kd-tree [`KdIndex`]. Nearest neighbours in
//! the 33-D FPFH space are [`crate::features::nearest`].

mod kdtree;

pub use kdtree::{KdIndex, NearestMemo, MEMO_MARGIN, MEMO_REACH};
