"""handeye with (N, 4, 4) arrays, and the pose conversions."""

from __future__ import annotations

import numpy as np
import pytest

import depthcal
from conftest import assert_same, pose, rot


def hand_eye_data(n=15, seed=0, noise_deg=0.05, noise_mm=0.5):
    """Robot poses T_base_ee, board poses T_cam_board (noisy), and the truth (T_ee_cam, T_base_board)."""
    rng = np.random.default_rng(seed)
    x = pose([0.2, 0.1, 1.0], 30.0, [0.03, -0.02, 0.08])  # T_ee_cam
    z = pose([0, 0, 1], 10.0, [0.8, 0.1, 0.0])  # T_base_board
    robot, target = [], []
    for _ in range(n):
        a = pose(rng.normal(size=3), rng.uniform(15, 60), [0.6, 0.0, 0.5] + rng.uniform(-0.15, 0.15, 3))
        b = np.linalg.inv(x) @ np.linalg.inv(a) @ z  # T_cam_board
        e = pose(rng.normal(size=3), rng.normal(0, noise_deg), rng.normal(0, noise_mm * 1e-3, 3))
        robot.append(a)
        target.append(b @ e)
    return np.array(robot), np.array(target), x, z


def err(a, b):
    d = np.linalg.inv(a) @ b
    return np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))), np.linalg.norm(d[:3, 3]) * 1e3


def test_noisy_hand_eye_from_arrays():
    robot, target, x, z = hand_eye_data()
    r = depthcal.handeye(robot, target)
    deg, mm = err(r.t_ee_cam, x)
    assert deg < 0.1 and mm < 1.0, (deg, mm)
    assert r.t_base_board.shape == (4, 4)
    assert r.sigma_deg > 0 and r.sigma_mm > 0
    assert r.method == "refined" and r.converged
    assert [f["frame"] for f in r.residuals] == [str(i) for i in range(15)]
    assert "HandEye(method=\"refined\"" in repr(r)
    d = r.to_dict()
    assert d["T_ee_cam"]["matrix"] == r.t_ee_cam.tolist() and d["setup"] == "eye-in-hand"


def write_matrix_csv(path, poses, ids):
    """A matrix-format pose file holding exactly these float64 values (repr round-trips)."""
    lines = ["frame," + ",".join(f"m{r}{c}" for r in range(4) for c in range(4))]
    for i, m in zip(ids, poses):
        lines.append(i + "," + ",".join(repr(float(v)) for v in m.ravel()))
    path.write_text("\n".join(lines) + "\n")


def test_arrays_and_files_equal_the_cli_bit_for_bit(cli, tmp_path):
    robot, target, _, _ = hand_eye_data(seed=4)
    ids = [f"f{i:02d}" for i in range(len(robot))]
    rp, tp = tmp_path / "robot.csv", tmp_path / "board.csv"
    write_matrix_csv(rp, robot, ids)
    write_matrix_csv(tp, target, ids)
    want = cli("handeye", "--robot-poses", str(rp), "--robot-format", "matrix", "--target-poses", str(tp))
    from_files = depthcal.handeye(str(rp), str(tp), robot_format="matrix")
    assert_same(from_files.to_dict(), want)
    from_arrays = depthcal.handeye(robot, target, frame_ids=ids)
    assert_same(from_arrays.to_dict(), want, ignore=("robot_poses", "target_poses"))
    for kw in ({"method": "park", "refine": False}, {"seed": 3}, {"eye_to_hand": True}):
        args = ["--method", kw["method"], "--no-refine"] if "method" in kw else []
        args += ["--seed", "3"] if "seed" in kw else []
        args += ["--eye-to-hand"] if "eye_to_hand" in kw else []
        want = cli("handeye", "--robot-poses", str(rp), "--robot-format", "matrix", "--target-poses", str(tp), *args, ok_codes=(0, 1))
        got = depthcal.handeye(robot, target, frame_ids=ids, **kw)
        assert_same(got.to_dict(), want, ignore=("robot_poses", "target_poses"))


def test_thread_counts_give_identical_hand_eyes():
    robot, target, _, _ = hand_eye_data(seed=2)
    a = depthcal.handeye(robot, target, threads=1).to_dict()
    b = depthcal.handeye(robot, target, threads=2).to_dict()
    assert_same(a, b)


def test_hand_eye_bad_input():
    robot, target, _, _ = hand_eye_data()
    with pytest.raises(depthcal.InputError, match=r"robot_poses: expected an \(N, 4, 4\) array"):
        depthcal.handeye(robot[:, :3], target)
    with pytest.raises(depthcal.InputError, match="robot_poses has 15 poses and target_poses 14"):
        depthcal.handeye(robot, target[:14])
    bad = robot.copy()
    bad[3, :3, :3] *= 1.1
    with pytest.raises(depthcal.InputError, match=r"robot_poses\[3\]: the rotation block is not a proper rotation"):
        depthcal.handeye(bad, target)
    with pytest.raises(depthcal.InputError, match="unknown hand-eye method"):
        depthcal.handeye(robot, target, method="opencv")
    with pytest.raises(depthcal.InputError, match="3"):
        depthcal.handeye(robot[:2], target[:2])
    with pytest.raises(depthcal.InputError, match="give two arrays or two pose file paths"):
        depthcal.handeye("robot.csv", target)
    with pytest.raises(depthcal.FileError):
        depthcal.handeye("no-robot.csv", "no-board.csv")
    with pytest.raises(depthcal.ConfigError, match="max_pairs"):
        depthcal.handeye(robot, target, config={"max_pairs": 0})
    with pytest.raises(depthcal.InputError, match="appears twice"):
        depthcal.handeye(robot, target, frame_ids=["a"] * 15)


KUKA = np.array([100.0, -20.0, 5.0, 90.0, 0.0, 0.0])


def test_kuka_matches_its_definition():
    m = depthcal.kuka_to_matrix(KUKA)
    assert np.allclose(m[:3, :3] @ [1, 0, 0], [0, 1, 0]) and np.allclose(m[:3, 3], [0.1, -0.02, 0.005])
    assert np.allclose(depthcal.matrix_to_kuka(m), KUKA)


@pytest.mark.parametrize("fmt", ["kuka", "ur", "abb", "fanuc", "xyzquat", "matrix"])
def test_every_format_round_trips_single_and_batched(fmt):
    rng = np.random.default_rng(5)
    ms = np.array([pose(rng.normal(size=3), rng.uniform(0, 170), rng.uniform(-1, 1, 3)) for _ in range(6)])
    v = depthcal.matrix_to_pose(ms, fmt)
    assert v.shape[0] == 6
    back = depthcal.pose_to_matrix(v, fmt)
    assert back.shape == (6, 4, 4) and np.allclose(back, ms, atol=1e-12)
    one = depthcal.matrix_to_pose(ms[0], fmt)
    assert np.array_equal(one, v[0])
    assert np.allclose(depthcal.pose_to_matrix(one, fmt), ms[0], atol=1e-12)


def test_named_conversions():
    m = pose([1, 2, 3], 40, [0.1, 0.2, 0.3])
    for to, back in [
        (depthcal.matrix_to_ur, depthcal.ur_to_matrix),
        (depthcal.matrix_to_abb, depthcal.abb_to_matrix),
        (depthcal.matrix_to_fanuc, depthcal.fanuc_to_matrix),
        (depthcal.matrix_to_quaternion, depthcal.quaternion_to_matrix),
        (depthcal.matrix_to_kuka, depthcal.kuka_to_matrix),
    ]:
        assert np.allclose(back(to(m)), m, atol=1e-12)
    q = depthcal.matrix_to_quaternion(m)
    assert q[6] >= 0 and np.isclose(np.linalg.norm(q[3:]), 1)
    abb = depthcal.matrix_to_abb(m)
    assert np.allclose(abb[:3], [100, 200, 300]) and np.allclose(abb[3:], [q[6], *q[3:6]])


def test_pose_conversion_errors():
    with pytest.raises(depthcal.InputError, match="has norm 2.000000, not 1"):
        depthcal.quaternion_to_matrix([0, 0, 0, 0, 0, 0, 2.0])
    with pytest.raises(depthcal.InputError, match=r"expected 6 numbers or an \(N, 6\) array, got shape \(5,\)"):
        depthcal.kuka_to_matrix([1, 2, 3, 4, 5])
    with pytest.raises(depthcal.InputError, match="unknown pose format"):
        depthcal.pose_to_matrix([0] * 6, "yaskawa")
    with pytest.raises(depthcal.InputError, match="NaN"):
        depthcal.kuka_to_matrix([np.nan, 0, 0, 0, 0, 0])
    with pytest.raises(depthcal.InputError, match="matrix: the rotation block is not a proper rotation"):
        depthcal.matrix_to_kuka(np.diag([1, 1, 2, 1.0]))


def test_pose_files_round_trip(tmp_path):
    ms = np.array([pose([0, 0, 1], 10 * i, [0.1 * i, 0, 0.5]) for i in range(4)])
    f = tmp_path / "p.csv"
    depthcal.write_poses(f, ms, "kuka", frame_ids=["a", "b", "c", "d"])
    ids, back = depthcal.read_poses(f)
    assert ids == ["a", "b", "c", "d"] and np.allclose(back, ms, atol=1e-8)
    assert f.read_text().startswith("frame,x_mm,y_mm,z_mm,a_deg,b_deg,c_deg\n")
    with pytest.raises(depthcal.FormatError, match="does not match pose format ur"):
        depthcal.read_poses(f, "ur")


def test_ros_outputs():
    m = pose([0, 0, 1], 90, [1.0, 2.0, 0.0])
    line = depthcal.ros2_static_transform(m, "left_base", "right_base")
    assert line.startswith("ros2 run tf2_ros static_transform_publisher --x 1.000000 --y 2.000000")
    assert line.endswith("--frame-id left_base --child-frame-id right_base")
    files = depthcal.transform_files(m, "left_base", "right_base")
    assert set(files) >= {"static_tf.launch.py", "base_joint.urdf.xacro", "tf.yaml", "kuka_base.txt"}
    with pytest.raises(depthcal.InputError, match="must differ"):
        depthcal.transform_files(m, "a", "a")
