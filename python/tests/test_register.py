"""depthcal.register: equality with the CLI, array conversions, bad input, threads, the GIL."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import depthcal
from conftest import SOURCE, TARGET, assert_same, pose


def test_paths_equal_the_cli_bit_for_bit(cli, monkeypatch):
    # The CLI runs in the repository root with relative names; Python gets the same names.
    monkeypatch.chdir(SOURCE.parents[1])
    got = depthcal.register("clouds/demo_source.ply", "clouds/demo_target.ply").to_dict()
    want = cli("register", "clouds/demo_source.ply", "clouds/demo_target.ply")
    assert_same(got, want)
    assert set(got["timings_ms"]) == set(want["timings_ms"])


def test_arrays_equal_the_cli(cli, demo):
    s, t = demo
    want = cli("register", "clouds/demo_source.ply", "clouds/demo_target.ply")
    r = depthcal.register(s.points, t.points)
    # Arrays have no file names; the rest is the same.
    assert_same(r.to_dict(), want, ignore=("source", "target"))
    assert np.array_equal(r.transform, np.array(want["transform"]["matrix"]))
    assert r.transform.dtype == np.float64 and r.transform.shape == (4, 4)
    assert r.covariance.shape == (6, 6)
    assert r.trusted and r.converged and r.reasons == []
    assert 0 < r.fitness <= 1 and 0 < r.overlap <= 1 and r.inlier_rmse > 0
    assert "icp" in r.timings_ms and "read" not in r.timings_ms


@pytest.mark.parametrize(
    "convert",
    [
        lambda p: p.astype(np.float64),
        lambda p: np.asfortranarray(p),
        lambda p: np.asfortranarray(p.astype(np.float64)),
        lambda p: np.repeat(p, 2, axis=0)[::2],  # a strided view
        lambda p: np.hstack([p, np.zeros((len(p), 1), np.float32)])[:, :3],  # non-contiguous columns
        lambda p: p.tolist(),
    ],
    ids=["float64", "fortran", "fortran64", "strided", "column-view", "list"],
)
def test_any_layout_and_float_dtype_gives_the_same_result(demo, convert):
    s, t = demo
    base = depthcal.register(s.points, t.points)
    other = depthcal.register(convert(s.points), convert(t.points))
    assert np.array_equal(base.transform, other.transform)
    assert base.to_dict()["covariance"] == other.to_dict()["covariance"]


def test_point_clouds_and_open3d_like_objects_are_accepted(demo):
    s, t = demo

    class Pcd:  # Open3D's PointCloud has `.points` (a Vector3dVector that np.asarray reads)
        def __init__(self, p):
            self.points = p.astype(np.float64)

    a = depthcal.register(s, t)
    b = depthcal.register(Pcd(s.points), Pcd(t.points))
    assert np.array_equal(a.transform, b.transform)


def test_a_known_transform_is_recovered(demo):
    s, _ = demo
    truth = pose([0.3, -0.5, 0.8], 35.0, [0.4, -0.2, 0.15])
    p = s.points.astype(np.float64)
    moved = p @ truth[:3, :3].T + truth[:3, 3]
    r = depthcal.register(p, moved, seed=3)
    d = np.linalg.inv(truth) @ r.transform
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.05 and np.linalg.norm(d[:3, 3]) < 1e-3, (angle, d[:3, 3])
    assert r.trusted


def test_init_skips_the_global_stage_and_equals_the_cli(cli, demo, tmp_path):
    s, t = demo
    guess = np.loadtxt(SOURCE.parent / "demo_truth.txt")
    f = tmp_path / "init.txt"
    np.savetxt(f, guess, fmt="%.17g")
    want = cli("register", "clouds/demo_source.ply", "clouds/demo_target.ply", "--init", str(f))
    r = depthcal.register(s.points, t.points, init=guess)
    assert want["global"] is None and r.to_dict()["global"] is None
    assert_same(r.to_dict(), want, ignore=("source", "target"))


def test_config_is_merged_like_the_cli(cli, demo, tmp_path):
    s, t = demo
    cfg = {"icp": {"kernel": "tukey"}, "icp_levels": 3}
    f = tmp_path / "c.json"
    import json

    f.write_text(json.dumps(cfg))
    want = cli("register", "clouds/demo_source.ply", "clouds/demo_target.ply", "--config", str(f), "--seed", "5")
    r = depthcal.register(s.points, t.points, config=cfg, seed=5)
    assert_same(r.to_dict(), want, ignore=("source", "target"))
    assert r.to_dict()["seed"] == 5


def test_thread_counts_give_identical_results(demo):
    s, t = demo
    results = [depthcal.register(s.points, t.points, threads=n).to_dict() for n in (1, 2, 4)]
    for r in results[1:]:
        assert_same(r, results[0])


def test_the_gil_is_released_during_a_long_register(demo):
    s, t = demo
    done = {}

    def work():
        done["r"] = depthcal.register(s.points, t.points, threads=1)

    th = threading.Thread(target=work)
    ticks = 0
    start = time.perf_counter()
    th.start()
    while th.is_alive():
        ticks += 1
        time.sleep(0.001)
    elapsed = time.perf_counter() - start
    assert done["r"].trusted
    # With the GIL held for the whole call the loop would run about once; released, once per ~ms.
    assert elapsed > 0.1
    assert ticks > 0.3 * elapsed / 0.001 * 0.1, (ticks, elapsed)
    assert ticks > 20, ticks


def test_help_is_useful():
    doc = depthcal.register.__doc__
    for word in ["source", "target", "init", "voxel", "seed", "threads", "config", "Returns", "Raises", "GIL"]:
        assert word in doc, word
    assert "init=None" in depthcal.register.__text_signature__
    assert "p_target" in depthcal.Registration.transform.__doc__
    assert "Registration(trusted=True" in repr(depthcal.register(*[depthcal.read_cloud(p) for p in (SOURCE, TARGET)]))


def test_check_returns_a_trusted_result(demo):
    r = depthcal.register(*demo)
    assert r.check() is r


def test_an_untrusted_result_is_returned_and_check_raises():
    rng = np.random.default_rng(0)
    a = rng.uniform(-1, 1, (3000, 3))
    b = rng.uniform(-1, 1, (3000, 3))
    r = depthcal.register(a, b)
    assert not r.trusted and r.reasons
    with pytest.raises(depthcal.UntrustedError) as e:
        r.check()
    assert isinstance(e.value, RuntimeError) and e.value.reasons == r.reasons


GOOD = np.random.default_rng(1).uniform(-1, 1, (200, 3))


@pytest.mark.parametrize(
    "bad, message",
    [
        (GOOD.T, "expected an (N, 3) array, got shape (3, 200) (it looks transposed: pass arr.T)"),
        (GOOD[:, :2], "expected an (N, 3) array, got shape (200, 2)"),
        (GOOD.ravel(), "expected an (N, 3) array, got shape (600,) (a flat array"),
        (GOOD[None], "expected an (N, 3) array, got shape (1, 200, 3)"),
        (GOOD.astype(np.int64), "expected a float32 or float64 array, got dtype int64"),
        (GOOD.astype(np.float16), "got dtype float16"),
        (np.array([["a", "b", "c"]] * 20), "expected a float32 or float64 array, got dtype str32"),
        ("not/a/file.ply", "not/a/file.ply"),
    ],
)
def test_bad_source_arrays_raise_input_errors(bad, message):
    with pytest.raises(depthcal.Error) as e:
        depthcal.register(bad, GOOD)
    assert message in str(e.value)
    assert isinstance(e.value, (ValueError, OSError))


def test_nan_and_inf_raise_unless_dropped():
    p = GOOD.copy()
    p[7, 1] = np.nan
    p[9, 0] = np.inf
    with pytest.raises(depthcal.InputError, match=r"source: 2 of 200 rows have NaN or infinite values \(the first is row 7\)"):
        depthcal.register(p, GOOD)
    with pytest.raises(ValueError, match="target: 1 of 200 rows"):
        depthcal.register(GOOD, np.where(np.arange(200)[:, None] == 3, 1e300, GOOD))  # inf in float32
    r = depthcal.register(p, GOOD, drop_nonfinite=True, init=np.eye(4))
    assert "2 source points with NaN/infinite coordinates were dropped" in r.warnings


def test_empty_and_tiny_clouds_give_the_library_message():
    with pytest.raises(depthcal.InputError, match="the source cloud has 0 finite points; registration needs at least 10"):
        depthcal.register(np.zeros((0, 3)), GOOD)
    with pytest.raises(depthcal.InputError, match="the target cloud has 5 finite points"):
        depthcal.register(GOOD, GOOD[:5])
    with pytest.raises(depthcal.InputError, match="all points of the source cloud coincide"):
        depthcal.register(np.ones((50, 3)), GOOD)


@pytest.mark.parametrize(
    "init, message",
    [
        (np.diag([2.0, 2.0, 2.0, 1.0]), "init: the rotation block is not a proper rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "init: the rotation block is not a proper rotation"),
        (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "init: the bottom row must be 0 0 0 1"),
        (np.full((4, 4), np.nan), "init: matrix has a NaN or infinite entry"),
        (np.eye(3), "init: expected a 4x4 matrix, got shape (3, 3)"),
        ([["a"] * 4] * 4, "init: expected a real-valued (float) array"),
    ],
)
def test_a_non_rigid_init_is_rejected(init, message):
    with pytest.raises(depthcal.InputError) as e:
        depthcal.register(GOOD, GOOD, init=init)
    assert message in str(e.value)


def test_bad_configuration_raises_config_errors():
    with pytest.raises(depthcal.ConfigError, match="voxle"):
        depthcal.register(GOOD, GOOD, config={"voxle": 0.1})
    with pytest.raises(depthcal.ConfigError, match="icp.max_iterations"):
        depthcal.register(GOOD, GOOD, config={"icp": {"max_iterations": 0}})
    with pytest.raises(ValueError, match="voxel: -1: the voxel size must be a positive number"):
        depthcal.register(GOOD, GOOD, voxel=-1)
    with pytest.raises(depthcal.InputError, match="voxel 10 exceeds the extent of the clouds"):
        depthcal.register(GOOD, GOOD, voxel=10.0)
    with pytest.raises(depthcal.ConfigError, match="NaN or infinite"):
        depthcal.register(GOOD, GOOD, config={"voxel": float("nan")})
    with pytest.raises(depthcal.ConfigError, match="expected a dict"):
        depthcal.register(GOOD, GOOD, config=[1, 2])


def test_bad_thread_counts():
    with pytest.raises(depthcal.InputError, match="threads must be at least 1"):
        depthcal.register(GOOD, GOOD, threads=0)
    with pytest.raises(depthcal.InputError, match="8 per core"):
        depthcal.register(GOOD, GOOD, threads=100000)
    with pytest.raises(OverflowError):
        depthcal.register(GOOD, GOOD, threads=-1)


def test_units_mismatch_is_named_as_the_cli_names_it():
    with pytest.raises(depthcal.Error, match=r"differ 1000x .*millimetres vs metres"):
        depthcal.register(GOOD * 1000.0, GOOD)


def test_open3d_clouds_register_directly(demo):
    o3d = pytest.importorskip("open3d", reason="open3d is not installed")
    s, t = demo
    a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s.points.astype(np.float64)))
    b = o3d.io.read_point_cloud(str(TARGET))
    r1 = depthcal.register(a, b)
    r2 = depthcal.register(np.asarray(a.points), np.asarray(b.points))
    r3 = depthcal.register(s, t)
    assert np.array_equal(r1.transform, r2.transform) and np.array_equal(r1.transform, r3.transform)


def test_profile_reports_every_stage_of_a_synthetic_pair():
    r = depthcal.profile(synthetic=20000, repeat=1, threads=2)
    assert r["schema"] == "depthcal.profile/1"
    names = [s["name"] for s in r["stages"]]
    assert "icp" in names and "fpfh" in names and names[-1] == "total"
    assert r["error_vs_truth"]["rotation_deg"] < 0.5
    fine = depthcal.profile(synthetic=20000, stages=["icp"], repeat=1)
    assert fine["fine_only"] and len(fine["stages"]) == 1


def test_profile_arguments_are_checked():
    with pytest.raises(depthcal.ConfigError, match="icpp"):
        depthcal.profile(synthetic=1000, stages=["icpp"])
    with pytest.raises(depthcal.InputError, match="synthetic"):
        depthcal.profile()
