"""read_cloud / write_cloud / PointCloud."""

from __future__ import annotations

import errno

import numpy as np
import pytest

import depthcal
from conftest import SOURCE


def test_read_cloud_gives_float32_points(demo):
    s, _ = demo
    assert isinstance(s, depthcal.PointCloud)
    assert s.points.dtype == np.float32 and s.points.shape == (len(s), 3)
    assert np.asarray(s) is s.points or np.array_equal(np.asarray(s), s.points)
    assert np.asarray(s, dtype=np.float64).dtype == np.float64
    assert repr(s).startswith("PointCloud(27245 points")


def test_write_and_read_back_with_normals_and_colors(tmp_path):
    rng = np.random.default_rng(0)
    p = rng.normal(size=(500, 3)).astype(np.float32)
    n = p / np.linalg.norm(p, axis=1, keepdims=True)
    c = rng.integers(0, 256, (500, 3), dtype=np.uint8)
    f = tmp_path / "c.ply"
    depthcal.write_cloud(f, p, normals=n, colors=c)
    back = depthcal.read_cloud(f)
    assert np.array_equal(back.points, p)
    assert np.array_equal(back.normals, n.astype(np.float32))
    assert np.array_equal(back.colors, c)
    # Open3D's float colours in [0, 1] are scaled to 0-255.
    depthcal.write_cloud(f, p, colors=c / 255.0)
    assert np.array_equal(depthcal.read_cloud(f).colors, c)
    # A PointCloud writes with its normals and colours.
    depthcal.write_cloud(tmp_path / "d.ply", depthcal.PointCloud(p, n, c))
    assert np.array_equal(depthcal.read_cloud(tmp_path / "d.ply").colors, c)
    depthcal.write_cloud(str(tmp_path / "e.xyz"), p.astype(np.float64))
    assert np.allclose(depthcal.read_cloud(tmp_path / "e.xyz").points, p, atol=1e-6)


def test_npy_reads(tmp_path):
    p = np.arange(30, dtype=np.float64).reshape(10, 3)
    np.save(tmp_path / "a.npy", p)
    assert np.array_equal(depthcal.read_cloud(tmp_path / "a.npy").points, p.astype(np.float32))


def test_a_missing_file_is_a_file_error(tmp_path):
    f = tmp_path / "none.ply"
    with pytest.raises(depthcal.FileError) as e:
        depthcal.read_cloud(f)
    assert isinstance(e.value, OSError) and isinstance(e.value, depthcal.Error)
    assert str(f) in str(e.value) and e.value.errno == errno.ENOENT and e.value.filename == str(f)


def test_bad_files_are_format_errors(tmp_path):
    (tmp_path / "e.ply").write_bytes(b"")
    with pytest.raises(depthcal.FormatError, match="e.ply: the file is empty"):
        depthcal.read_cloud(tmp_path / "e.ply")
    (tmp_path / "x.abc").write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"unknown file format \(expected one of .ply"):
        depthcal.read_cloud(tmp_path / "x.abc")
    (tmp_path / "t.ply").write_bytes(SOURCE.read_bytes()[:2000])
    with pytest.raises(depthcal.FormatError, match="t.ply"):
        depthcal.read_cloud(tmp_path / "t.ply")
    with pytest.raises(depthcal.InputError, match="expected a path"):
        depthcal.read_cloud(42)


def test_write_checks_its_input(tmp_path):
    p = np.zeros((4, 3))
    with pytest.raises(depthcal.FormatError, match="for writing"):
        depthcal.write_cloud(tmp_path / "a.pcd", p)
    with pytest.raises(depthcal.InputError, match="points normals: 3 rows for 4 points"):
        depthcal.write_cloud(tmp_path / "a.ply", p, normals=np.zeros((3, 3)))
    with pytest.raises(depthcal.InputError, match=r"float colours must be in \[0, 1\]"):
        depthcal.write_cloud(tmp_path / "a.ply", p, colors=np.full((4, 3), 2.0))
    with pytest.raises(depthcal.InputError, match="NaN or infinite"):
        depthcal.write_cloud(tmp_path / "a.ply", np.full((4, 3), np.nan))
    with pytest.raises(depthcal.FileError):
        depthcal.write_cloud(tmp_path / "no" / "dir" / "a.ply", p)
