//! Nearest-neighbour indexes: the 3-D kd-tree over positions ([`KdIndex`], kiddo) and exact nearest
//! neighbours in the 33-D FPFH space ([`feature`]).

pub mod feature;
mod kdtree;

pub use kdtree::KdIndex;
