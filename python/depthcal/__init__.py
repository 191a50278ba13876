"""depthcal: point-cloud registration and depth-only calibration of multi-robot cells.

NumPy arrays in and out, the Rust library underneath (the results are bit-identical to the
``depthcal`` command line's for the same inputs and seed, at any thread count).

Conventions: ``T_a_b`` maps coordinates in frame b to frame a (``p_a = T_a_b @ [p_b, 1]``); transforms
are 4x4 float64 arrays in metres (registration: in the clouds' unit); points are (N, 3) float32 or
float64 arrays; angles in the pose formats are degrees (KUKA, Fanuc) or radians (UR), as each
controller writes them.

Main functions:

* :func:`register` -- the rigid transform moving one cloud onto another, with its uncertainty and a
  verdict (trusted or not, with the reasons).
* :func:`calibrate` -- ``T_base1_base2`` of a two-robot cell dataset; :func:`fuse`, :func:`simulate`; :func:`profile` -- where registration spends its time.
* :func:`handeye` -- ``T_ee_cam`` from (N, 4, 4) robot and board poses.
* :func:`read_cloud`, :func:`write_cloud`, :func:`read_poses`, :func:`write_poses`.
* pose conversions: :func:`kuka_to_matrix`, :func:`matrix_to_kuka`, ``ur``, ``abb``, ``fanuc``,
  ``quaternion``, and the general :func:`pose_to_matrix` / :func:`matrix_to_pose`.

Errors are subclasses of :class:`Error`: :class:`InputError`, :class:`FormatError` and
:class:`ConfigError` are also ``ValueError``; :class:`FileError` is also ``OSError``;
:class:`FailedError` and :class:`UntrustedError` are also ``RuntimeError``.

Docs: docs/python.md in the repository.
"""

from __future__ import annotations

from typing import Any

from ._depthcal import (
    Calibration,
    ConfigError,
    Error,
    FailedError,
    FileError,
    FormatError,
    HandEye,
    InputError,
    PointCloud,
    Registration,
    UntrustedError,
    __version__,
    calibrate,
    fuse,
    handeye,
    matrix_to_pose,
    pose_to_matrix,
    profile,
    read_cloud,
    read_poses,
    register,
    ros2_static_transform,
    simulate,
    transform_files,
    write_cloud,
    write_poses,
)

__all__ = [
    "Calibration",
    "ConfigError",
    "Error",
    "FailedError",
    "FileError",
    "FormatError",
    "HandEye",
    "InputError",
    "PointCloud",
    "Registration",
    "UntrustedError",
    "__version__",
    "abb_to_matrix",
    "calibrate",
    "fanuc_to_matrix",
    "fuse",
    "handeye",
    "kuka_to_matrix",
    "matrix_to_abb",
    "matrix_to_fanuc",
    "matrix_to_kuka",
    "matrix_to_pose",
    "matrix_to_quaternion",
    "matrix_to_ur",
    "pose_to_matrix",
    "profile",
    "quaternion_to_matrix",
    "read_cloud",
    "read_poses",
    "register",
    "ros2_static_transform",
    "simulate",
    "transform_files",
    "ur_to_matrix",
    "write_cloud",
    "write_poses",
]


def kuka_to_matrix(xyzabc: Any) -> Any:
    """KUKA XYZ-ABC to 4x4 matrices.

    ``xyzabc``: ``[x_mm, y_mm, z_mm, a_deg, b_deg, c_deg]`` or an (N, 6) array; millimetres and degrees,
    ``R = Rz(A) @ Ry(B) @ Rx(C)``. Returns (4, 4) or (N, 4, 4) float64 in metres.
    """
    return pose_to_matrix(xyzabc, "kuka")


def matrix_to_kuka(matrix: Any) -> Any:
    """4x4 rigid matrices (metres) to KUKA ``[x_mm, y_mm, z_mm, a_deg, b_deg, c_deg]``.

    A and C in (-180, 180], B in [-90, 90] (C = 0 at gimbal lock). (4, 4) gives 6 values, (N, 4, 4) an
    (N, 6) array.
    """
    return matrix_to_pose(matrix, "kuka")


def ur_to_matrix(pose: Any) -> Any:
    """Universal Robots pose vectors ``[x, y, z, rx, ry, rz]`` (metres, rotation vector in radians) to 4x4
    matrices (metres); one vector or an (N, 6) array."""
    return pose_to_matrix(pose, "ur")


def matrix_to_ur(matrix: Any) -> Any:
    """4x4 rigid matrices (metres) to UR pose vectors ``[x, y, z, rx, ry, rz]`` (metres, radians; the
    rotation angle in [0, pi])."""
    return matrix_to_pose(matrix, "ur")


def abb_to_matrix(pose: Any) -> Any:
    """ABB frames ``[x_mm, y_mm, z_mm, q1, q2, q3, q4]`` (millimetres, unit quaternion
    ``q1..q4 = w, x, y, z``) to 4x4 matrices (metres); one frame or an (N, 7) array."""
    return pose_to_matrix(pose, "abb")


def matrix_to_abb(matrix: Any) -> Any:
    """4x4 rigid matrices (metres) to ABB ``[x_mm, y_mm, z_mm, q1, q2, q3, q4]`` (``q1 = w >= 0``)."""
    return matrix_to_pose(matrix, "abb")


def fanuc_to_matrix(pose: Any) -> Any:
    """Fanuc XYZ-WPR ``[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]`` (``R = Rz(r) @ Ry(p) @ Rx(w)``) to 4x4
    matrices (metres); one pose or an (N, 6) array."""
    return pose_to_matrix(pose, "fanuc")


def matrix_to_fanuc(matrix: Any) -> Any:
    """4x4 rigid matrices (metres) to Fanuc ``[x_mm, y_mm, z_mm, w_deg, p_deg, r_deg]``."""
    return matrix_to_pose(matrix, "fanuc")


def quaternion_to_matrix(xyzquat: Any) -> Any:
    """``[x, y, z, qx, qy, qz, qw]`` (metres, unit quaternion, scalar last as in ROS) to 4x4 matrices;
    one pose or an (N, 7) array. The quaternion's norm must be 1 within 1e-3."""
    return pose_to_matrix(xyzquat, "xyzquat")


def matrix_to_quaternion(matrix: Any) -> Any:
    """4x4 rigid matrices (metres) to ``[x, y, z, qx, qy, qz, qw]`` with ``qw >= 0`` (ROS order)."""
    return matrix_to_pose(matrix, "xyzquat")
