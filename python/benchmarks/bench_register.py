"""Speed of depthcal's Python binding: the conversion overhead, and depthcal.register beside small_gicp.align and
Open3D's FPFH + RANSAC + ICP pipeline, in the same Python process on the sample pair (clouds/demo_*.ply).

Run from the repository root, in an environment with depthcal (and optionally open3d, small_gicp):
    python python/benchmarks/bench_register.py [REPEATS]
Figures are medians of REPEATS runs (default 5); docs/python.md has the ones measured on the 2-core machine.
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

import depthcal

REPEATS = int(sys.argv[1]) if len(sys.argv) > 1 else 5
truth = np.loadtxt("clouds/demo_truth.txt")
src = depthcal.read_cloud("clouds/demo_source.ply").points
tgt = depthcal.read_cloud("clouds/demo_target.ply").points


def median_ms(f):
    times = []
    out = None
    for _ in range(REPEATS):
        t = time.perf_counter()
        out = f()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times), out


def error(t):
    d = np.linalg.inv(truth) @ t
    deg = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
    return f"{deg:.3f} deg / {np.linalg.norm(d[:3, 3]) * 1e3:.1f} mm"


print(f"sample pair: {len(src)} and {len(tgt)} points; medians of {REPEATS} runs")
# 1. The binding's overhead: the copies and conversions of the inputs (and of the arrays given back), against
#    the whole call. PointCloud(points) converts an array into the library's layout and copies it back out:
#    at least what register spends on its two inputs.
big = np.random.default_rng(0).normal(size=(1_000_000, 3))
for name, arr in [
    ("27k float32 C", src),
    ("27k float64 Fortran", np.asfortranarray(src.astype(np.float64))),
    ("1M float64 C", big),
]:
    ms, _ = median_ms(lambda: depthcal.PointCloud(arr))
    print(f"conversion in + out, {name:20s} {ms:8.2f} ms")
ms_reg, r = median_ms(lambda: depthcal.register(src, tgt))
ms_dict, _ = median_ms(lambda: r.to_dict())
print(f"depthcal.register (global + ICP)      {ms_reg:8.1f} ms   {error(r.transform)}   trusted {r.trusted}")
print(f"  of which the library's stages       {sum(r.timings_ms.values()):8.1f} ms;  to_dict() {ms_dict:.3f} ms")

# 2. Local refinement from a perturbed truth (what small_gicp does).
d = np.eye(4)
c, s = np.cos(np.radians(3)), np.sin(np.radians(3))
d[:2, :2] = [[c, -s], [s, c]]
d[:3, 3] = [0.03, -0.02, 0.01]
init = truth @ d
ms, r = median_ms(lambda: depthcal.register(src, tgt, init=init))
print(f"depthcal.register(init=...) (ICP)     {ms:8.1f} ms   {error(r.transform)}")
voxel = r.voxel
try:
    import small_gicp

    for kind in ("GICP", "PLANE_ICP"):
        ms, res = median_ms(
            lambda: small_gicp.align(
                tgt.astype(np.float64),
                src.astype(np.float64),
                init_T_target_source=init,
                registration_type=kind,
                downsampling_resolution=voxel / 2,
                max_correspondence_distance=3 * voxel,
                num_threads=2,
            )
        )
        print(f"small_gicp.align({kind}) from init{' ' * (10 - len(kind))}{ms:8.1f} ms   {error(res.T_target_source)}")
except ImportError:
    print("small_gicp not installed: skipped")

# 3. Open3D's global pipeline with the same voxel: downsample, normals, FPFH, RANSAC, point-to-plane ICP.
try:
    import open3d as o3d

    reg = o3d.pipelines.registration

    def open3d_pipeline():
        a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(src.astype(np.float64)))
        b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tgt.astype(np.float64)))
        feats = []
        downs = []
        for pc in (a, b):
            dn = pc.voxel_down_sample(voxel)
            dn.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
            feats.append(reg.compute_fpfh_feature(dn, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)))
            downs.append(dn)
        g = reg.registration_ransac_based_on_feature_matching(
            downs[0], downs[1], feats[0], feats[1], True, 1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
            reg.RANSACConvergenceCriteria(100000, 0.999),
        )
        fine = reg.registration_icp(downs[0], downs[1], 1.5 * voxel, g.transformation, reg.TransformationEstimationPointToPlane())
        return fine.transformation

    o3d.utility.random.seed(0)
    ms, t = median_ms(open3d_pipeline)
    print(f"Open3D FPFH + RANSAC + ICP            {ms:8.1f} ms   {error(t)}")
except ImportError:
    print("open3d not installed: skipped")
