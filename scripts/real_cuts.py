#!/usr/bin/env python3
"""Low-overlap cuts of the real 3DMatch redkitchen pairs, with ground truth, for `depthcal register`.

Each of the pairs 1->0, 4->0 and 4->1 is cut four times: in the target's frame a random, mostly horizontal
direction d is drawn; the source keeps its points beyond one quantile along d, the target its points before
another, redrawn until 12-30 % of the kept source lies within 3 cm of the kept target. The source is then moved
by a random rigid motion. Written per cut: NAME_s.ply (source), NAME_t.ply (target) and NAME_T.txt (the 4x4
that maps the written source onto the target: p_t = T p_s).

Usage (Python with numpy and open3d, e.g. the one ../shared/peers/setup.sh prints):
    python scripts/real_cuts.py SEED PREFIX OUT_DIR [DATA_DIR]
then, per cut:
    depthcal register OUT_DIR/NAME_s.ply OUT_DIR/NAME_t.ply --truth OUT_DIR/NAME_T.txt
docs/accuracy.md ("Registration covariance on real pairs") used seeds 5, 11 and 12.
"""
import os
import sys

import numpy as np
import open3d as o3d


def truth_of(gt_log, i, j):
    """The 4x4 of gt.log's entry (i, j): p_i = T p_j."""
    lines = open(gt_log).read().split("\n")
    for k in range(0, len(lines) - 4, 5):
        h = lines[k].split()
        if len(h) >= 2 and (int(h[0]), int(h[1])) == (i, j):
            return np.array([[float(v) for v in lines[k + r].split()] for r in range(1, 5)])
    raise KeyError((i, j))


def rotation(axis, angle):
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def main():
    seed, prefix, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    here = os.path.dirname(os.path.abspath(__file__))
    data = sys.argv[4] if len(sys.argv) > 4 else os.path.join(here, "..", "..", "shared", "data", "3dmatch-redkitchen")
    os.makedirs(out, exist_ok=True)
    rng = np.random.default_rng(seed)
    k = 0
    for i, j in [(0, 1), (0, 4), (1, 4)]:
        src = np.asarray(o3d.io.read_point_cloud(f"{data}/cloud_bin_{j}.ply").points)
        tgt = np.asarray(o3d.io.read_point_cloud(f"{data}/cloud_bin_{i}.ply").points)
        t_ij = truth_of(f"{data}/gt.log", i, j)
        src_in_tgt = src @ t_ij[:3, :3].T + t_ij[:3, 3]
        for _ in range(4):
            d = rng.normal(size=3)
            d[2] *= 0.3
            d /= np.linalg.norm(d)
            ps, pt = src_in_tgt @ d, tgt @ d
            for _ in range(60):
                keep_s = ps > np.quantile(ps, rng.uniform(0.2, 0.6))
                keep_t = pt < np.quantile(pt, rng.uniform(0.4, 0.8))
                if keep_s.sum() < 3000 or keep_t.sum() < 3000:
                    continue
                s_cut, t_cut = src_in_tgt[keep_s], tgt[keep_t]
                tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(t_cut)))
                sample = s_cut[rng.choice(len(s_cut), min(3000, len(s_cut)), replace=False)]
                shared = np.mean([tree.search_radius_vector_3d(p, 0.03)[0] > 0 for p in sample])
                if 0.12 <= shared <= 0.30:
                    break
            else:
                continue
            pose = np.eye(4)
            pose[:3, :3] = rotation(rng.normal(size=3), rng.uniform(0, np.pi))
            pose[:3, 3] = rng.uniform(-1, 1, 3)
            s_own = (s_cut - t_ij[:3, 3]) @ t_ij[:3, :3]
            s_posed = s_own @ pose[:3, :3].T + pose[:3, 3]
            name = f"{prefix}{k:02d}"
            k += 1
            o3d.io.write_point_cloud(f"{out}/{name}_s.ply", o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s_posed)))
            o3d.io.write_point_cloud(f"{out}/{name}_t.ply", o3d.geometry.PointCloud(o3d.utility.Vector3dVector(t_cut)))
            np.savetxt(f"{out}/{name}_T.txt", t_ij @ np.linalg.inv(pose))
            print(name, f"{j}->{i}", f"shared {shared:.2f}", len(s_posed), len(t_cut))


if __name__ == "__main__":
    main()
