#!/usr/bin/env python3
"""Open3D's global-registration tutorial recipe on the trust sweep's kept cells, beside `calibrate`.

    python scripts/sweep_open3d.py SWEEP_OUTPUT KEEP_DIR [--voxel V ...] [--threads N] [--seed S]

KEEP_DIR holds the cells a sweep kept (`DEPTHCAL_TRUST_SWEEP_KEEP=KEEP_DIR`), each with the two fused clouds
the sweep registered (`fused-<robot>.ply`, `depthcal fuse` of each robot) and `ground_truth.json`;
SWEEP_OUTPUT is that sweep's printed output (one line per cell). For each cell and each voxel the recipe
(voxel downsample, normals r=2v/30, FPFH r=5v/100, mutual-filtered RANSAC 1.5v with edge-length and distance
checkers, 100000 iterations / 0.999, point-to-plane ICP at 0.4v: `bench_peers.open3d_recipe`, the recipe of
`../shared/peers/register.py`)
registers the second robot's cloud onto the reference's, and the result is compared with `T_base1_base2`.
Right is the sweep's: within 0.1 deg and 2 mm. Prints one line per cell and a table per family: Open3D right
(at any of the voxels tried, so the count is generous to Open3D), and the cells where `calibrate` is wrong
but Open3D right. Needs Open3D and numpy (the peers' venv: `../shared/peers/setup.sh`).
"""
import argparse
import json
import os
import re
import sys
import time

RIGHT_DEG, RIGHT_MM = 0.1, 2.0


def sweep_lines(path):
    """{(family, seed): (class, register error deg, register mm, register exit)} from a sweep's output."""
    out = {}
    pat = re.compile(r"^(\S+)\s+(\d+)\s+(RightTrusted|RightRefused|WrongRefused|WrongTrusted|Failed)\b")
    reg = re.compile(r"\| register\s+([0-9.]+)°\s+([0-9.]+) mm exit (\d+)")
    with open(path) as f:
        for line in f:
            m = pat.match(line)
            if not m:
                continue
            r = reg.search(line)
            out[(m.group(1), int(m.group(2)))] = (
                m.group(3),
                (float(r.group(1)), float(r.group(2)), int(r.group(3))) if r else None,
            )
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sweep_output")
    ap.add_argument("keep_dir")
    ap.add_argument("--voxel", type=float, nargs="+", default=[0.02, 0.05])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()

    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    import numpy as np
    import open3d as o3d

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from bench_peers import open3d_recipe

    o3d.utility.random.seed(a.seed)
    sweep = sweep_lines(a.sweep_output)

    def error(T, G):
        D = T @ np.linalg.inv(G)
        c = np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)
        return float(np.degrees(np.arccos(c))), float(np.linalg.norm(D[:3, 3]) * 1e3)

    rows = []
    for name in sorted(os.listdir(a.keep_dir)):
        d = os.path.join(a.keep_dir, name)
        m = re.match(r"^(.*)-(\d+)$", name)
        if not m or not os.path.isfile(os.path.join(d, "ground_truth.json")):
            continue
        family, seed = m.group(1), int(m.group(2))
        with open(os.path.join(d, "ground_truth.json")) as f:
            G = np.array(json.load(f)["T_base1_base2"], dtype=float)
        fused = sorted(p for p in os.listdir(d) if p.startswith("fused-") and p.endswith(".ply"))
        with open(os.path.join(d, "cell.toml")) as f:
            ref = re.search(r'^reference\s*=\s*"([^"]+)"', f.read(), re.M).group(1)
        tgt_name = f"fused-{ref}.ply"
        others = [p for p in fused if p != tgt_name]
        if tgt_name not in fused or len(others) != 1:
            print(f"{name}: no fused pair, skipped", flush=True)
            continue
        src = o3d.io.read_point_cloud(os.path.join(d, others[0]))
        tgt = o3d.io.read_point_cloud(os.path.join(d, tgt_name))
        errs = []
        t0 = time.perf_counter()
        for v in a.voxel:
            errs.append(error(open3d_recipe(src, tgt, v), G))
        wall = time.perf_counter() - t0
        o3d_right = any(r <= RIGHT_DEG and t <= RIGHT_MM for r, t in errs)
        cal, regr = sweep.get((family, seed), (None, None))
        rows.append((family, seed, cal, regr, o3d_right))
        es = "  ".join(f"v{v:g} {r:7.3f}°/{t:7.1f}mm" for v, (r, t) in zip(a.voxel, errs))
        print(f"{family:18} {seed}  calibrate {cal or '?':12}  open3d {'right' if o3d_right else 'wrong'}  "
              f"{es}  {wall:.1f}s", flush=True)

    fams = sorted({r[0] for r in rows})
    print()
    print("| family | cells | Open3D right | register right | calibrate right | calibrate wrong where Open3D right |")
    print("|---|---|---|---|---|---|")
    tot = [0, 0, 0, 0, 0]
    for fam in fams + [None]:
        sel = [r for r in rows if fam is None or r[0] == fam]
        n = len(sel)
        o = sum(r[4] for r in sel)
        rr = sum(1 for r in sel if r[3] and r[3][0] <= RIGHT_DEG and r[3][1] <= RIGHT_MM)
        cr = sum(1 for r in sel if r[2] and r[2].startswith("Right"))
        miss = [f"{r[0]} {r[1]}" for r in sel if r[4] and not (r[2] or "").startswith("Right")]
        label = "**total**" if fam is None else fam
        print(f"| {label} | {n} | {o} | {rr} | {cr} | {len(miss)}{' (' + ', '.join(miss) + ')' if miss and fam else ''} |")


if __name__ == "__main__":
    sys.exit(main())
