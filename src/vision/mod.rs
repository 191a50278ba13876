//! The image side of calibration (cargo feature `vision`): checkerboard inner corners with subpixel
//! refinement ([`corners`]), ChArUco corners with their ids, from whole or partial views ([`charuco`]),
//! either board's view ([`board_view`]), intrinsic calibration by Zhang's method ([`intrinsics`]), the board pose in
//! each camera by PnP ([`pnp`]), and the board seen by a whole set of images or by a cell's robots
//! ([`observe`]); square fiducial markers, ArUco and AprilTag ([`markers`]), and their poses in a cell's
//! frames with depth ([`marker_sightings`]); 2D keypoint features (SIFT, ORB, AKAZE), their matches and the
//! homography between two views of a plane ([`features`]), and keypoints lifted to 3D ([`feature_lift`]).
//!
//! OpenCV (through the `opencv` crate) does the image work; its types stay inside this module. The public
//! API takes and returns nalgebra types, [`GreyImage`] and the crate's own [`Intrinsics`] and
//! [`Board`]: pixels follow librealsense and OpenCV alike (`(0, 0)` is the centre of the top-left
//! pixel), lengths are metres.
//!
//! [`Intrinsics`]: crate::camera::Intrinsics
//! [`Board`]: crate::cell::Board

pub mod annotate;
pub mod apriltag;
pub mod aruco;
pub mod board_view;
pub mod charuco;
pub mod circles;
pub mod corners;
mod cv;
mod edges;
pub mod feature_lift;
pub mod features;
pub mod frames;
pub mod image;
pub mod initializers;
pub mod intrinsics;
pub mod marker_sightings;
pub mod markers;
pub mod observe;
pub mod pnp;

pub use annotate::write_marker_annotation;
pub use apriltag::AprilTagConfig;
pub use aruco::{dictionary_bits, ArucoConfig, ArucoRefinement};
pub use board_view::{detect_board, BoardView};
pub use charuco::{charuco_image, detect_charuco, CharucoConfig, CharucoCorners};
pub use corners::{detect_checkerboard, BoardCorners, CornerConfig};
pub use features::{
    detect_features, detect_features_masked, fit_homography, knn_match, match_features,
    transfer_error, Descriptors, FeatureConfig, FeatureKind, FeatureMatch, Features, Homography,
    HomographyConfig, Keypoint,
};
pub use image::{read_grey_image, GreyImage};
pub use intrinsics::{calibrate_intrinsics, IntrinsicCalibration, IntrinsicsConfig, ViewResidual};
pub use markers::{
    detect_markers, CornerOrder, MarkerConfig, MarkerDetection, MarkerDetector, SubpixConfig,
    SubpixMethod,
};
pub use observe::{
    board_in_robot_base, find_frame_images, observe_board, BoardObservation, BoardObservations,
    RobotBoardPose,
};
pub use pnp::{board_pose, BoardPose};
