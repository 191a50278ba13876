#!/usr/bin/env python3
"""Where each robot's depth splits into a near and a far mode, and what a cut between them would do.

    python scripts/depth_modes.py CELL_DIR [CELL_DIR ...] [--factor 2.5] [--stride 2]

For each robot of each cell (the depth PNGs its `cell.toml` names as `ROBOT/depth/*.png`, millimetres), the
depth samples of every frame (every `stride`-th pixel each way, 0.1-6 m) are split in two by Otsu's threshold
(a 240-bin histogram over 0-6 m). Printed per robot: the overall median, the near and far parts' medians and
the far part's share, and `fires` when the far part's median lies beyond `factor` x the near part's and the
cut at `factor` x the overall median (calibrate's range cut, `max_range_factor`) would keep it. The rule and
what it measured on the 390 kept trust-sweep cells: docs/accuracy.md, "A far mode in the depth". Needs numpy
and Open3D (to read the PNGs; the peers' venv: `../shared/peers/setup.sh`).
"""
import argparse
import glob
import json
import os

import numpy as np
import open3d as o3d


def depth_samples(depth_dir, stride):
    parts = []
    for f in sorted(glob.glob(os.path.join(depth_dir, "*.png"))):
        a = np.asarray(o3d.io.read_image(f))[::stride, ::stride].astype(np.float64) * 1e-3
        parts.append(a[(a > 0.1) & (a < 6.0)])
    return np.concatenate(parts) if parts else np.zeros(0)


def otsu(d):
    h, e = np.histogram(d, bins=240, range=(0.0, 6.0))
    c = 0.5 * (e[:-1] + e[1:])
    w = h.astype(float)
    total = w.sum()
    w0 = np.cumsum(w)
    w1 = total - w0
    m0 = np.cumsum(w * c)
    mt = m0[-1]
    ok = (w0 > 0) & (w1 > 0)
    between = np.zeros_like(w)
    between[ok] = (mt * w0[ok] / total - m0[ok]) ** 2 / (w0[ok] * w1[ok] / total)
    return e[int(np.argmax(between)) + 1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cells", nargs="+")
    ap.add_argument("--factor", type=float, default=2.5)
    ap.add_argument("--stride", type=int, default=2)
    a = ap.parse_args()
    for cell in a.cells:
        out = {}
        for robot in sorted(os.listdir(cell)):
            d = depth_samples(os.path.join(cell, robot, "depth"), a.stride)
            if d.size < 100:
                continue
            t = otsu(d)
            near, far = d[d < t], d[d >= t]
            if near.size == 0 or far.size == 0:
                continue
            med, nm, fm = float(np.median(d)), float(np.median(near)), float(np.median(far))
            out[robot] = {
                "median_m": round(med, 3),
                "near_median_m": round(nm, 3),
                "far_median_m": round(fm, 3),
                "far_share": round(far.size / d.size, 3),
                "fires": bool(fm > a.factor * nm and a.factor * med >= fm),
            }
        print(os.path.basename(os.path.normpath(cell)), json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
