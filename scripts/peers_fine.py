#!/usr/bin/env python3
"""The fine stage of Open3D and small_gicp on one pair, timed, for BENCHMARK.md's comparison with
`depthcal profile SOURCE TARGET --init INIT --truth TRUTH --stages read,downsample_normals,icp,total`.

    python scripts/peers_fine.py SOURCE TARGET INIT TRUTH [--voxel V] [--threads N] [--repeat R]
                                 [--lib small_gicp|open3d|both]

Both start from INIT (4x4 text matrix) and are scored against TRUTH (the true SOURCE->TARGET transform).
small_gicp: `preprocess_points` (voxel downsampling at V, 10-neighbour covariances, kd-tree) of both clouds,
then GICP `align` (max correspondence distance 10 V). Open3D: `voxel_down_sample` at V, target normals
(hybrid r = 2V, 30), point-to-plane `registration_icp` (max distance 3V, up to 50 iterations, relative
tolerances 1e-6). Times exclude reading the files (reported as `read_ms`) and the interpreter's start-up.
Prints one JSON line per library and run: the stage times in ms, the process CPU time of the fine stage,
the points after downsampling, the iterations, `converged`, and the rotation (degrees) and translation
(cloud units) errors.
"""
import argparse
import json
import os
import time


def pose_error(T, G):
    import numpy as np
    E = np.linalg.inv(G) @ T
    rot = float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))))
    return rot, float(np.linalg.norm(T[:3, 3] - G[:3, 3]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("target")
    ap.add_argument("init")
    ap.add_argument("truth")
    ap.add_argument("--voxel", type=float, default=0.01)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--lib", default="both", choices=["small_gicp", "open3d", "both"])
    a = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    import numpy as np
    import open3d as o3d

    t = time.perf_counter()
    src = o3d.io.read_point_cloud(a.source)
    tgt = o3d.io.read_point_cloud(a.target)
    read_ms = (time.perf_counter() - t) * 1e3
    init = np.loadtxt(a.init).reshape(4, 4)
    truth = np.loadtxt(a.truth).reshape(4, 4)
    v = a.voxel
    libs = ["small_gicp", "open3d"] if a.lib == "both" else [a.lib]
    for run in range(a.repeat):
        for lib in libs:
            out = {"lib": lib, "run": run, "voxel": v, "threads": a.threads, "read_ms": read_ms,
                   "points_in": [len(src.points), len(tgt.points)]}
            c0, w0 = time.process_time(), time.perf_counter()
            if lib == "small_gicp":
                import small_gicp
                sp, tp = np.asarray(src.points), np.asarray(tgt.points)
                w = time.perf_counter()
                t_d, t_tree = small_gicp.preprocess_points(tp, downsampling_resolution=v, num_neighbors=10,
                                                           num_threads=a.threads)
                s_d, _ = small_gicp.preprocess_points(sp, downsampling_resolution=v, num_neighbors=10,
                                                      num_threads=a.threads)
                out["preprocess_ms"] = (time.perf_counter() - w) * 1e3
                w = time.perf_counter()
                r = small_gicp.align(t_d, s_d, t_tree, init_T_target_source=init, registration_type="GICP",
                                     max_correspondence_distance=10 * v, num_threads=a.threads)
                out["align_ms"] = (time.perf_counter() - w) * 1e3
                T = r.T_target_source
                out.update(points=[s_d.size(), t_d.size()], iterations=r.iterations, converged=bool(r.converged))
            else:
                w = time.perf_counter()
                s_d, t_d = src.voxel_down_sample(v), tgt.voxel_down_sample(v)
                out["downsample_ms"] = (time.perf_counter() - w) * 1e3
                w = time.perf_counter()
                t_d.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
                out["normals_ms"] = (time.perf_counter() - w) * 1e3
                w = time.perf_counter()
                reg = o3d.pipelines.registration
                r = reg.registration_icp(s_d, t_d, 3 * v, init, reg.TransformationEstimationPointToPlane(),
                                         reg.ICPConvergenceCriteria(1e-6, 1e-6, 50))
                out["icp_ms"] = (time.perf_counter() - w) * 1e3
                T = r.transformation
                out.update(points=[len(s_d.points), len(t_d.points)], fitness=r.fitness)
            out["fine_ms"] = (time.perf_counter() - w0) * 1e3
            out["fine_cpu_ms"] = (time.process_time() - c0) * 1e3
            out["rotation_error_deg"], out["translation_error"] = pose_error(np.asarray(T), truth)
            print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
