#!/usr/bin/env python3
"""Compare depthcal's hand-eye solvers with OpenCV's on OpenCV's hand-eye noise protocol.

The data are the 100 seeded trials of tests/handeye.rs (10 poses each; camera-to-target noise 0.002 rad /
5 mm, robot noise 0.001 rad / 1 mm per component, exactly the protocol of OpenCV's
modules/calib3d/test/test_calibration_hand_eye.cpp). Rust writes them as CSV (an ignored test); this script
runs `depthcal handeye --json` and OpenCV's five cv2.calibrateHandEye methods (plus the two
cv2.calibrateRobotWorldHandEye methods) on the same files and prints the mean/median T_ee_cam errors.

Usage (from the repository root, with the peers' Python that has opencv-contrib-python-headless):
    PY=$(../shared/peers/setup.sh); $PY scripts/compare_handeye.py [--out DIR]
Not part of CI's test run.
"""
import argparse
import csv
import json
import os
import subprocess
import sys

import cv2
import numpy as np
from scipy.spatial.transform import Rotation


def read_matrix_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    out = []
    for r in rows[1:]:
        if not r or r[0].startswith("#"):
            continue
        out.append((r[0], np.array([float(v) for v in r[1:17]]).reshape(4, 4)))
    return out


def rot_err_deg(r_est, r_true):
    return np.degrees(Rotation.from_matrix(r_est.T @ r_true).magnitude())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="target/handeye_protocol", help="where the trial CSV files go")
    ap.add_argument("--skip-generate", action="store_true", help="reuse the CSV files already in --out")
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = os.path.abspath(os.path.join(root, a.out)) if not os.path.isabs(a.out) else a.out
    if not a.skip_generate:
        env = dict(os.environ, DEPTHCAL_HANDEYE_OUT=out)
        subprocess.run(
            ["cargo", "test", "--release", "--test", "handeye", "--", "--ignored", "write_protocol_data"],
            cwd=root, env=env, check=True, stdout=subprocess.DEVNULL)
        subprocess.run(["cargo", "build", "--release"], cwd=root, check=True, stdout=subprocess.DEVNULL)
    exe = os.path.join(root, "target", "release", "depthcal")
    truth = {}
    with open(os.path.join(out, "truth_T_ee_cam.csv")) as f:
        rows = list(csv.reader(f))
    for r in rows[1:]:
        truth[int(r[0])] = np.array([float(v) for v in r[1:17]]).reshape(4, 4)

    cv_methods = [
        ("cv TSAI", cv2.CALIB_HAND_EYE_TSAI),
        ("cv PARK", cv2.CALIB_HAND_EYE_PARK),
        ("cv HORAUD", cv2.CALIB_HAND_EYE_HORAUD),
        ("cv ANDREFF", cv2.CALIB_HAND_EYE_ANDREFF),
        ("cv DANIILIDIS", cv2.CALIB_HAND_EYE_DANIILIDIS),
    ]
    rw_methods = [
        ("cv RW SHAH", cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH),
        ("cv RW LI", cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI),
    ]
    errs = {}

    def add(name, t_est, t_true):
        e = errs.setdefault(name, ([], []))
        e[0].append(rot_err_deg(t_est[:3, :3], t_true[:3, :3]))
        e[1].append(1e3 * np.linalg.norm(t_est[:3, 3] - t_true[:3, 3]))

    for trial in sorted(truth):
        rp = os.path.join(out, f"trial{trial:03d}_robot.csv")
        tp = os.path.join(out, f"trial{trial:03d}_target.csv")
        robot = read_matrix_csv(rp)
        target = dict(read_matrix_csv(tp))
        t_true = truth[trial]
        # OpenCV: gripper2base = T_base_ee, target2cam = T_cam_board, result cam2gripper = T_ee_cam.
        rg = [m[:3, :3] for _, m in robot]
        tg = [m[:3, 3] for _, m in robot]
        rt = [target[k][:3, :3] for k, _ in robot]
        tt = [target[k][:3, 3] for k, _ in robot]
        for name, flag in cv_methods:
            r, t = cv2.calibrateHandEye(rg, tg, rt, tt, method=flag)
            est = np.eye(4)
            est[:3, :3] = r
            est[:3, 3] = t.ravel()
            add(name, est, t_true)
        # Robot-world: world2cam = T_cam_board, base2gripper = T_ee_base; result gripper2cam = T_cam_ee.
        inv = [np.linalg.inv(m) for _, m in robot]
        for name, flag in rw_methods:
            _, _, r, t = cv2.calibrateRobotWorldHandEye(
                rt, tt, [m[:3, :3] for m in inv], [m[:3, 3] for m in inv], method=flag)
            t_cam_ee = np.eye(4)
            t_cam_ee[:3, :3] = r
            t_cam_ee[:3, 3] = t.ravel()
            add(name, np.linalg.inv(t_cam_ee), t_true)
        res = subprocess.run(
            [exe, "handeye", "--robot-poses", rp, "--target-poses", tp, "--robot-format", "matrix",
             "--target-format", "matrix", "--json"],
            check=True, capture_output=True, text=True)
        j = json.loads(res.stdout)
        for cf in j["closed_forms"]:
            if cf["T_ee_cam"] is not None:
                add("depthcal " + cf["method"], np.array(cf["T_ee_cam"]), t_true)
        add("depthcal refined", np.array(j["T_ee_cam"]), t_true)

    n = len(truth)
    print(f"OpenCV hand-eye noise protocol: {n} trials, 10 poses, camera noise 0.002 rad / 5 mm, "
          f"robot noise 0.001 rad / 1 mm; OpenCV {cv2.__version__}")
    print(f"{'method':<24} {'rot mean [deg]':>15} {'rot median':>11} {'trans mean [mm]':>16} {'trans median':>13}")
    for name, (r, t) in errs.items():
        print(f"{name:<24} {np.mean(r):>15.4f} {np.median(r):>11.4f} {np.mean(t):>16.3f} {np.median(t):>13.3f}")
    best_cv_r = min(np.mean(errs[k][0]) for k, _ in cv_methods)
    best_cv_t = min(np.mean(errs[k][1]) for k, _ in cv_methods)
    ours = errs["depthcal refined"]
    ok = np.mean(ours[0]) <= best_cv_r and np.mean(ours[1]) <= best_cv_t
    print(f"depthcal refined vs best of OpenCV's five calibrateHandEye methods: rotation {np.mean(ours[0]):.4f} "
          f"vs {best_cv_r:.4f} deg, translation {np.mean(ours[1]):.3f} vs {best_cv_t:.3f} mm -> "
          f"{'at least as accurate' if ok else 'LESS accurate'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
