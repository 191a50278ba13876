"""calibrate, fuse and simulate: equality with the CLI, threads, bad cells."""

from __future__ import annotations

import filecmp
import json
import os
import shutil

import numpy as np
import pytest

import depthcal
from conftest import CELL, REPO, assert_same


@pytest.fixture(autouse=True)
def in_repo(monkeypatch):
    # The CLI runs in the repository root with relative names; Python gets the same names.
    monkeypatch.chdir(REPO)


def test_calibrate_equals_the_cli_bit_for_bit(cli):
    want = cli("calibrate", "clouds/demo-cell")
    c = depthcal.calibrate("clouds/demo-cell")
    assert_same(c.to_dict(), want)
    assert np.array_equal(c.transform, np.array(want["transform"]["matrix"]))
    assert c.trusted and c.reference == "left" and c.other == "right" and c.method == "depth"
    deg, mm = c.error_vs_truth
    # The demo cell: 0.064 deg / 0.70 mm since fusion fits quadrics to curved parts (docs/accuracy.md).
    assert deg < 0.1 and mm < 1.0
    assert c.ros2.startswith("ros2 run tf2_ros static_transform_publisher --x 0.937646") and c.frame_ids == ("left_base", "right_base")
    assert c.sigma_deg.shape == (3,) and c.sigma_mm.shape == (3,)
    assert "static_tf.launch.py" in c.transform_files()
    assert c.check() is c
    assert "Calibration(right -> left" in repr(c)


def test_calibrate_options_equal_the_cli(cli, tmp_path):
    init = tmp_path / "init.txt"
    want = cli("calibrate", "clouds/demo-cell")
    np.savetxt(init, np.array(want["transform"]["matrix"]), fmt="%.17g")
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"max_range_factor": None}))
    for args, kw in [
        (["--no-priors", "--seed", "2"], {"priors": False, "seed": 2}),
        (["--init", str(init)], {"init": str(init)}),
        (["--init", str(init), "--no-refine"], {"init": str(init), "refine": False}),
        (["--config", str(cfg), "--child-frame-id", "ur10/base_link"], {"config": {"max_range_factor": None}, "child_frame_id": "ur10/base_link"}),
    ]:
        want = cli("calibrate", "clouds/demo-cell", *args)
        got = depthcal.calibrate("clouds/demo-cell", **kw).to_dict()
        assert_same(got, want)
    # An array init is the same guess, named "init".
    got = depthcal.calibrate("clouds/demo-cell", init=np.loadtxt(init)).to_dict()
    want = cli("calibrate", "clouds/demo-cell", "--init", str(init))
    assert got["initial"]["detail"] == "user guess from init"
    got["initial"]["detail"] = want["initial"]["detail"]
    assert_same(got, want)


def test_calibrate_threads_give_identical_results():
    a = depthcal.calibrate("clouds/demo-cell", threads=1).to_dict()
    b = depthcal.calibrate("clouds/demo-cell", threads=2).to_dict()
    assert_same(a, b)


def test_bad_cells(tmp_path):
    with pytest.raises(depthcal.FileError) as e:
        depthcal.calibrate(tmp_path / "none")
    assert "cell.toml" in str(e.value) or "none" in str(e.value)
    (tmp_path / "cell.toml").write_text("this is = not [toml\n")
    with pytest.raises(depthcal.FormatError, match="cell.toml"):
        depthcal.calibrate(tmp_path)
    broken = tmp_path / "broken"
    shutil.copytree(CELL, broken)
    os.remove(next((broken / "right" / "depth").iterdir()))
    with pytest.raises(depthcal.Error, match="right"):
        depthcal.calibrate(broken)
    with pytest.raises(depthcal.InputError, match="unknown method \"magic\": expected one of depth, guess, checkerboard"):
        depthcal.calibrate("clouds/demo-cell", method="magic")
    with pytest.raises(depthcal.InputError, match="needs init"):
        depthcal.calibrate("clouds/demo-cell", method="guess")
    with pytest.raises(depthcal.ConfigError, match="max_range_factor"):
        depthcal.calibrate("clouds/demo-cell", config={"max_range_factor": 0.0})
    with pytest.raises(depthcal.InputError, match="rotation block"):
        depthcal.calibrate("clouds/demo-cell", init=np.diag([1, 1, 3, 1.0]))


def test_fuse_equals_the_cli(cli, tmp_path):
    out = tmp_path / "right.ply"
    want = cli("fuse", "clouds/demo-cell", "--robot", "right", "--output", str(out))
    cloud, stats = depthcal.fuse("clouds/demo-cell", "right")
    assert stats["output"] is None
    assert_same(stats, want, ignore=("output",))
    ref = depthcal.read_cloud(out)
    assert np.array_equal(cloud.points, ref.points) and np.array_equal(cloud.normals, ref.normals)
    assert cloud.points.dtype == np.float32


def test_fuse_bad_input():
    with pytest.raises(depthcal.Error, match="nobody"):
        depthcal.fuse("clouds/demo-cell", "nobody")
    with pytest.raises(depthcal.InputError, match="crop: expected 6 finite numbers"):
        depthcal.fuse("clouds/demo-cell", crop=[0, 0, 0])
    with pytest.raises(depthcal.ConfigError, match="max_depth_m: must exceed min_depth_m"):
        depthcal.fuse("clouds/demo-cell", min_depth=2.0, max_depth=1.0)


def test_simulate_equals_the_cli_byte_for_byte(cli, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    want = cli("simulate", str(a), "--seed", "3", "--frames", "4", "--no-color", "--noise", "low")
    got = depthcal.simulate(b, seed=3, frames=4, color=False, noise="low", threads=1)
    assert_same(got, want, ignore=("out_dir",))
    cmp = filecmp.dircmp(a, b)
    assert not cmp.left_only and not cmp.right_only and not cmp.diff_files
    for sub in ("left/depth", "right/depth"):
        names = sorted(os.listdir(a / sub))
        match, mismatch, errors = filecmp.cmpfiles(a / sub, b / sub, names, shallow=False)
        assert not mismatch and not errors and len(match) == 4
    with pytest.raises(depthcal.InputError, match="not empty"):
        depthcal.simulate(b, seed=3, frames=4)
    c = depthcal.calibrate(b)
    assert c.trusted and c.error_vs_truth[0] < 0.1


def test_three_robots_equal_the_cli_and_give_every_pose(cli, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    want = cli("simulate", str(a), "--robots", "3", "--seed", "4", "--frames", "14", "--no-color")
    got = depthcal.simulate(b, robots=3, seed=4, frames=14, color=False)
    assert_same(got, want, ignore=("out_dir",))
    assert got["robots"] == ["left", "right", "robot3"]
    want = cli("calibrate", str(a))
    c = depthcal.calibrate(a)
    assert_same(c.to_dict(), want)
    poses = c.poses
    assert sorted(poses) == ["right", "robot3"]
    for r in want["robots"]:
        assert r["trusted"], r["reasons"]
        assert np.array_equal(poses[r["name"]], np.array(r["transform"]["matrix"]))
    files = c.transform_files()
    assert "T_left_robot3.txt" in files and files["static_tf.launch.py"].count("static_transform_publisher") == 2
    with pytest.raises(depthcal.InputError, match="3 robots"):
        depthcal.calibrate(a, refine=False)
    with pytest.raises(depthcal.ConfigError, match="robots"):
        depthcal.simulate(tmp_path / "c", robots=9)


def test_two_robots_give_the_other_robots_pose():
    c = depthcal.calibrate("clouds/demo-cell", refine=False)
    assert list(c.poses) == ["right"] and np.array_equal(c.poses["right"], c.transform)


def test_simulate_bad_input(tmp_path):
    with pytest.raises(depthcal.InputError, match="noise"):
        depthcal.simulate(tmp_path / "x", noise="loud")
    with pytest.raises(depthcal.InputError, match="resolution"):
        depthcal.simulate(tmp_path / "x", resolution="10x10")
    with pytest.raises(depthcal.ConfigError, match="frames|overlap"):
        depthcal.simulate(tmp_path / "x", overlap=3.0)
