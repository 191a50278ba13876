"""Shared fixtures: the repository's sample data and the `depthcal` command line to compare against."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
CLOUDS = REPO / "clouds"
SOURCE = CLOUDS / "demo_source.ply"
TARGET = CLOUDS / "demo_target.ply"
CELL = CLOUDS / "demo-cell"

# Keys of the JSON results that hold wall times: everything else must be equal bit for bit.
TIMING_KEYS = {"timings_ms", "total_ms", "seconds"}


def cli_path() -> Path | None:
    """The `depthcal` binary: $DEPTHCAL_CLI, else target/release/depthcal of the repository, else PATH."""
    env = os.environ.get("DEPTHCAL_CLI")
    if env:
        return Path(env)
    p = REPO / "target" / "release" / "depthcal"
    if p.exists():
        return p
    w = shutil.which("depthcal")
    return Path(w) if w else None


@pytest.fixture(scope="session")
def cli():
    """Runs the command line and returns its parsed --json output (skips when there is no binary)."""
    exe = cli_path()
    if exe is None:
        pytest.skip("no depthcal binary (cargo build --release, or set DEPTHCAL_CLI)")

    def run(*args: str, ok_codes=(0, 3)) -> dict:
        out = subprocess.run([str(exe), *args, "--json"], capture_output=True, text=True, cwd=REPO)
        assert out.returncode in ok_codes, out.stderr
        return json.loads(out.stdout)

    run.exe = exe
    return run


def without_timings(d):
    """The JSON value without its wall-time keys (recursively)."""
    if isinstance(d, dict):
        return {k: without_timings(v) for k, v in d.items() if k not in TIMING_KEYS}
    if isinstance(d, list):
        return [without_timings(v) for v in d]
    return d


def assert_same(a: dict, b: dict, ignore=()):
    """Equal JSON values except timings and `ignore` keys, naming the first differing key."""
    a, b = without_timings(a), without_timings(b)
    for k in ignore:
        a.pop(k, None)
        b.pop(k, None)
    for k in sorted(set(a) | set(b)):
        assert a.get(k) == b.get(k), f"{k}: {str(a.get(k))[:300]} != {str(b.get(k))[:300]}"


def rot(axis, deg):
    """A 3x3 rotation about `axis` by `deg` degrees (Rodrigues)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    t = np.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def pose(axis, deg, xyz):
    """A 4x4 rigid transform."""
    t = np.eye(4)
    t[:3, :3] = rot(axis, deg)
    t[:3, 3] = xyz
    return t


@pytest.fixture(scope="session")
def demo():
    """The sample clouds as read by depthcal."""
    import depthcal

    return depthcal.read_cloud(SOURCE), depthcal.read_cloud(TARGET)
