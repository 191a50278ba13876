"""Hand-eye calibration from pose arrays: T_ee_cam from (N, 4, 4) robot and board poses.

Simulates 20 noisy frames of a camera on a flange looking at a fixed board (0.1 deg / 1 mm of noise on the
board poses), solves with depthcal and, when OpenCV is installed, with cv2.calibrateHandEye for comparison.
Run: python examples/python/handeye_arrays.py
"""

import numpy as np

import depthcal

rng = np.random.default_rng(7)


def pose(axis, deg, xyz):
    t = np.eye(4)
    t[:3, :3] = depthcal.pose_to_matrix([0, 0, 0, *np.radians(deg) * np.asarray(axis) / np.linalg.norm(axis)], "ur")[:3, :3]
    t[:3, 3] = xyz
    return t


t_ee_cam = depthcal.kuka_to_matrix([30.0, -20.0, 80.0, 90.0, 5.0, -3.0])  # the truth, from KUKA mm/deg
t_base_board = depthcal.kuka_to_matrix([800.0, 100.0, 0.0, 10.0, 0.0, 0.0])
robot, board = [], []
for _ in range(20):
    t_base_ee = pose(rng.normal(size=3), rng.uniform(20, 60), [0.6, 0.0, 0.5] + rng.uniform(-0.15, 0.15, 3))
    t_cam_board = np.linalg.inv(t_ee_cam) @ np.linalg.inv(t_base_ee) @ t_base_board
    noise = pose(rng.normal(size=3), rng.normal(0, 0.1), rng.normal(0, 1e-3, 3))
    robot.append(t_base_ee)
    board.append(t_cam_board @ noise)
robot, board = np.array(robot), np.array(board)  # (20, 4, 4): OpenCV's gripper2base and target2cam

r = depthcal.handeye(robot, board)
print(r)


def error(est):
    d = np.linalg.inv(t_ee_cam) @ est
    deg = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return f"{deg:.4f} deg, {np.linalg.norm(d[:3, 3]) * 1e3:.3f} mm"


print("depthcal T_ee_cam error:", error(r.t_ee_cam), f"(reported 1-sigma {r.sigma_deg:.4f} deg, {r.sigma_mm:.3f} mm)")
print("T_ee_cam as KUKA XYZ-ABC (mm, deg):", np.round(depthcal.matrix_to_kuka(r.t_ee_cam), 3))
try:
    import cv2

    R, t = cv2.calibrateHandEye(robot[:, :3, :3], robot[:, :3, 3], board[:, :3, :3], board[:, :3, 3])
    cv = np.eye(4)
    cv[:3, :3], cv[:3, 3] = R, t.ravel()
    print("OpenCV (Tsai) T_ee_cam error:", error(cv))
except ImportError:
    pass
