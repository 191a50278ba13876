#!/usr/bin/env python3
"""One side-by-side run of depthcal, Open3D and small_gicp for BENCHMARK.md: the same data, the same
machine, the same thread count, the tools alternated, in-process times (reading included where a pipeline
is timed, the interpreter's start-up excluded) and the accuracy beside every time.

    python scripts/bench_peers.py WORK_DIR [--threads N] [--rounds R] [--skip-5m]

Run from the repository root with the venv of `../shared/peers/setup.sh` (Open3D, small_gicp) after
`cargo build --release --bins --examples`. WORK_DIR receives the generated data. Prints the tables as
Markdown on stdout and every raw measurement as JSON lines on stderr.

1. Single stages on a real-depth pair (the 7-Scenes frames fused per robot at 7.5 mm, about 1.15M points a
   side; `tools/seven_scenes_two_robot_cell.py`, `depthcal fuse`): kd-tree build and 1M nearest-neighbour
   queries, normals, FPFH, one point-to-plane ICP iteration and ICP to convergence from a guess 0.5° / 1 cm
   off. depthcal's side is `tools/stage_times.rs`.
2. The register pipeline on the 3DMatch pairs 1→0, 4→0, 4→1 (`depthcal profile --json` in-process times
   against Open3D's tutorial pipeline in this process, and both whole processes).
3. The fine stage on large clouds from a guess 3° / 5 cm off: the 7-Scenes pair at 1.15M and 4.5M points a
   side and a generated 1M pair; depthcal's fine stage against small_gicp's `preprocess_points` + GICP
   `align`, given the same numbers of points (the source downsampled to about depthcal's count) and as it is
   used by default, and Open3D's downsample + normals + point-to-plane ICP (1M only).
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DEPTHCAL = os.path.join(ROOT, "target/release/depthcal")
STAGES = os.path.join(ROOT, "target/release/examples/stage_times")
DATA = os.path.join(ROOT, "../shared/data")


def log(obj):
    print(json.dumps(obj), file=sys.stderr, flush=True)


def run(cmd, env=None):
    """Runs a command; returns (stdout, wall seconds)."""
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    if p.returncode not in (0, 3):
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr}")
    return p.stdout, wall


def matrix(path):
    import numpy as np
    return np.loadtxt(path).reshape(4, 4)


def write_matrix(path, m):
    with open(path, "w") as f:
        for r in m:
            f.write(" ".join(repr(float(v)) for v in r) + "\n")


def offset(m, deg, metres):
    """`m` moved by a rotation of `deg` about (1, 2, 3) and a translation of `metres` (before it)."""
    import numpy as np
    a = np.array([1.0, 2.0, 3.0]) / math.sqrt(14.0)
    th = math.radians(deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    O = np.eye(4)
    O[:3, :3] = R
    O[:3, 3] = np.array([1.0, -1.0, 0.93]) * metres / math.sqrt(2.8649)
    return O @ m


def pose_error(T, G):
    import numpy as np
    E = np.linalg.inv(G) @ T
    rot = float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1))))
    return rot, float(np.linalg.norm(T[:3, 3] - G[:3, 3])) * 1e3


def seven_scenes_pair(work, voxel, name):
    """The 7-Scenes cell's two robots fused at `voxel`: (source, target, truth, init 3°/5 cm, near 0.5°/1 cm)."""
    cell = os.path.join(work, "s7")
    if not os.path.exists(os.path.join(cell, "cell.toml")):
        run([sys.executable, os.path.join(ROOT, "tools/seven_scenes_two_robot_cell.py"), cell, "0"])
    out = {}
    for robot in ("right", "left"):
        p = os.path.join(work, f"{name}_{robot}.ply")
        if not os.path.exists(p):
            run([DEPTHCAL, "fuse", cell, "--robot", robot, "--voxel", str(voxel), "--no-outlier-removal",
                 "--no-normals", "-o", p])
        out[robot] = p
    import numpy as np
    c, s = math.cos(2.6), math.sin(2.6)
    G = np.array([[c, -s, 0, 1.1], [s, c, 0, 0.5], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    paths = {k: os.path.join(work, f"s7_{k}.txt") for k in ("truth", "init", "near")}
    write_matrix(paths["truth"], G)
    write_matrix(paths["init"], offset(G, 3.0, 0.05))
    write_matrix(paths["near"], offset(G, 0.5, 0.01))
    return out["right"], out["left"], paths


def read_points(path):
    import numpy as np
    import open3d as o3d
    return np.asarray(o3d.io.read_point_cloud(path).points)


# ---------------------------------------------------------------------------------------------- 1. stages
def stages_depthcal(src, tgt, truth, near, work, threads):
    out, _ = run([STAGES, src, tgt, truth, near, os.path.join(work, "stages"), "3"],
                 env=dict(os.environ, RAYON_NUM_THREADS=str(threads)))
    r = json.loads(out)
    log(r)
    return r


def best(fn, repeat=3):
    ms, out = math.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        ms = min(ms, (time.perf_counter() - t) * 1e3)
    return ms, out


def stages_open3d(src, tgt, truth, near, work, threads):
    import numpy as np
    import open3d as o3d
    reg = o3d.pipelines.registration
    S, T = o3d.io.read_point_cloud(src), o3d.io.read_point_cloud(tgt)
    G, I = matrix(truth), matrix(near)
    r = {"lib": "open3d"}
    r["kdtree_build_ms"], _ = best(lambda: o3d.geometry.KDTreeFlann(T))
    q = (np.asarray(S.points)[:1_000_000] @ G[:3, :3].T + G[:3, 3]).astype(np.float64)
    tt = o3d.core.Tensor(np.asarray(T.points))
    qq = o3d.core.Tensor(q)

    def nn():
        s = o3d.core.nns.NearestNeighborSearch(tt)
        s.knn_index()
        return s.knn_search(qq, 1)
    r["nn_queries_ms"], res = best(nn)
    r["nn_queries_note"] = "tensor NearestNeighborSearch: knn_index() + knn_search(k=1), index build included"
    r["nn_mean_distance"] = float(np.sqrt(res[1].numpy()).mean())

    def normals():
        c = o3d.geometry.PointCloud(T)
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=30))
        return c
    r["normals_ms"], _ = best(normals)
    F = o3d.io.read_point_cloud(os.path.join(work, "stages/fpfh_target.ply"))
    F.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=30))
    r["fpfh_points"] = len(F.points)
    r["fpfh_ms"], _ = best(lambda: reg.compute_fpfh_feature(
        F, o3d.geometry.KDTreeSearchParamHybrid(radius=0.25, max_nn=100)))
    s1 = o3d.io.read_point_cloud(os.path.join(work, "stages/icp_source.ply"))
    t1 = o3d.io.read_point_cloud(os.path.join(work, "stages/icp_target.ply"))
    t1.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.02, max_nn=30))
    r["icp_points"] = [len(s1.points), len(t1.points)]
    p2l = reg.TransformationEstimationPointToPlane()
    r["icp_iteration_ms"], _ = best(lambda: reg.registration_icp(
        s1, t1, 0.1, I, p2l, reg.ICPConvergenceCriteria(max_iteration=1)))
    r["icp_converged_ms"], res = best(lambda: reg.registration_icp(
        s1, t1, 0.1, I, p2l, reg.ICPConvergenceCriteria(1e-6, 1e-6, 50)))
    r["icp_iterations"] = "≤50 (not reported)"
    r["icp_error_deg"], r["icp_error_mm"] = pose_error(np.asarray(res.transformation), G)
    log(r)
    return r


def stages_small_gicp(src, tgt, truth, near, work, threads):
    import numpy as np
    import small_gicp as sg
    G, I = matrix(truth), matrix(near)
    S, T = read_points(src), read_points(tgt)
    r = {"lib": "small_gicp"}
    r["kdtree_build_ms"], tree = best(lambda: sg.KdTree(T, num_threads=threads))
    q = S[:1_000_000] @ G[:3, :3].T + G[:3, 3]
    r["nn_queries_ms"], res = best(lambda: tree.batch_nearest_neighbor_search(q, num_threads=threads))
    r["nn_mean_distance"] = float(np.sqrt(np.asarray(res[1])).mean())

    def normals():
        c = sg.PointCloud(T)
        sg.estimate_normals(c, sg.KdTree(c, num_threads=threads), num_neighbors=30, num_threads=threads)
    r["normals_ms"], _ = best(normals)
    r["normals_note"] = "30 nearest, no radius (small_gicp has no radius search)"
    s1 = sg.PointCloud(read_points(os.path.join(work, "stages/icp_source.ply")))
    t1 = sg.PointCloud(read_points(os.path.join(work, "stages/icp_target.ply")))
    t_tree = sg.KdTree(t1, num_threads=threads)
    sg.estimate_normals(t1, t_tree, num_neighbors=30, num_threads=threads)
    r["icp_points"] = [s1.size(), t1.size()]
    one = lambda n: sg.align(t1, s1, t_tree, init_T_target_source=I, registration_type="PLANE_ICP",
                             max_correspondence_distance=0.1, num_threads=threads, max_iterations=n)
    r["icp_iteration_ms"], _ = best(lambda: one(1))
    r["icp_converged_ms"], res = best(lambda: one(50))
    r["icp_iterations"], r["icp_converged"] = res.iterations, bool(res.converged)
    r["icp_error_deg"], r["icp_error_mm"] = pose_error(np.asarray(res.T_target_source), G)
    log(r)
    return r


# -------------------------------------------------------------------------------------------- 2. register
def register_open3d(src, tgt, G, voxel, threads):
    """Open3D's tutorial pipeline in this process, reading included (as ../shared/peers/register.py)."""
    import numpy as np
    import open3d as o3d
    o3d.utility.random.seed(0)
    t0 = time.perf_counter()
    s, t = o3d.io.read_point_cloud(src), o3d.io.read_point_cloud(tgt)
    T = open3d_recipe(s, t, voxel)
    ms = (time.perf_counter() - t0) * 1e3
    return ms, pose_error(T, G)


def open3d_recipe(s, t, voxel):
    """Open3D's global-registration tutorial recipe on two loaded clouds at `voxel`: voxel downsample,
    normals (r = 2v, 30), FPFH (r = 5v, 100), mutual-filtered RANSAC (1.5v, edge-length and distance checkers,
    100000 iterations, 0.999), point-to-plane ICP (0.4v, 50 iterations). Gives the 4x4 source-to-target
    transform (numpy)."""
    import numpy as np
    import open3d as o3d
    reg = o3d.pipelines.registration
    v = voxel
    s_d, t_d = s.voxel_down_sample(v), t.voxel_down_sample(v)
    for c in (s_d, t_d):
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * v, max_nn=30))
    f = lambda c: reg.compute_fpfh_feature(c, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100))
    s_f, t_f = f(s_d), f(t_d)
    ransac = reg.registration_ransac_based_on_feature_matching(
        s_d, t_d, s_f, t_f, True, 1.5 * v, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    fine = reg.registration_icp(s_d, t_d, 0.4 * v, ransac.transformation,
                                reg.TransformationEstimationPointToPlane(),
                                reg.ICPConvergenceCriteria(max_iteration=50))
    return np.asarray(fine.transformation)


def register_pairs(threads, rounds):
    d = os.path.join(DATA, "3dmatch-redkitchen")
    gt = {}
    with open(os.path.join(d, "gt.log")) as f:
        lines = [l.split() for l in f if l.strip()]
    for k in range(0, len(lines), 5):
        i, j = int(lines[k][0]), int(lines[k][1])
        gt[(i, j)] = [[float(x) for x in lines[k + r]] for r in range(1, 5)]
    rows = []
    for (s, t) in [(1, 0), (4, 0), (4, 1)]:
        src, tgt = os.path.join(d, f"cloud_bin_{s}.ply"), os.path.join(d, f"cloud_bin_{t}.ply")
        import numpy as np
        G = np.array(gt[(t, s)])
        truth = os.path.join("/tmp", f"depthcal-bench-gt-{s}{t}.txt")
        write_matrix(truth, G)
        m = {"pair": f"3DMatch {s}→{t}", "depthcal": [], "depthcal_process": [], "open3d": [],
             "open3d_process": []}
        for _ in range(rounds):
            out, _ = run([DEPTHCAL, "profile", src, tgt, "--truth", truth, "--repeat", "1", "--json",
                          "--threads", str(threads)])
            p = json.loads(out)
            total = next(x for x in p["stages"] if x["name"] == "total")
            e = p["error_vs_truth"]
            m["depthcal"].append(total["wall_ms"])
            m["depthcal_error"] = (e["rotation_deg"], e["translation_m"] * 1e3)
            m["depthcal_stages"] = {x["name"]: round(x["wall_ms"], 1) for x in p["stages"]}
            _, wall = run([DEPTHCAL, "register", src, tgt, "--json", "--threads", str(threads)])
            m["depthcal_process"].append(wall * 1e3)
            ms, err = register_open3d(src, tgt, G, 0.05, threads)
            m["open3d"].append(ms)
            m["open3d_error"] = err
            _, wall = run([sys.executable, os.path.join(DATA, "../peers/register.py"), src, tgt, "--voxel",
                           "0.05", "--threads", str(threads)])
            m["open3d_process"].append(wall * 1e3)
        log(m)
        rows.append(m)
    return rows


# ------------------------------------------------------------------------------------------ 3. fine stage
def fine_depthcal(src, tgt, truth, init, threads):
    out, _ = run([DEPTHCAL, "profile", src, tgt, "--init", init, "--truth", truth, "--voxel", "0.02",
                  "--stages", "read,downsample_normals,icp,total", "--repeat", "1", "--json", "--threads",
                  str(threads)])
    p = json.loads(out)
    st = {x["name"]: x for x in p["stages"]}
    lv = p["icp_levels"]
    e = p["error_vs_truth"]
    r = {"lib": "depthcal", "fine_ms": st["downsample_normals"]["wall_ms"] + st["icp"]["wall_ms"],
         "fine_cpu_ms": (st["downsample_normals"]["cpu_ms"] or 0) + (st["icp"]["cpu_ms"] or 0),
         "levels": [[l["voxel"], l["source_points"], l["target_points"], len(l["iterations"]), l["converged"]]
                    for l in lv],
         "points": [lv[-1]["source_points"], lv[-1]["target_points"]],
         "iterations": sum(len(l["iterations"]) - 1 for l in lv), "converged": p["converged"],
         "error": (e["rotation_deg"], e["translation_m"] * 1e3), "peak_mb": p["peak_memory_bytes"] / 1e6}
    log(r)
    return r


def source_voxel_for(S, count, voxel, threads):
    """The source voxel at which small_gicp's own downsampling leaves about `count` points (untimed)."""
    import small_gicp as sg
    lo, hi = voxel, voxel
    while sg.voxelgrid_sampling(S, hi, num_threads=threads).size() > count:
        lo, hi = hi, hi * 2
    for _ in range(12):
        mid = (lo + hi) / 2
        if sg.voxelgrid_sampling(S, mid, num_threads=threads).size() > count:
            lo = mid
        else:
            hi = mid
    return hi


def fine_small_gicp(S, T, G, I, voxel, threads, source_points=None):
    """small_gicp's `preprocess_points` of both clouds and GICP `align`, timed together. With
    `source_points`, the source is downsampled at the voxel that leaves that many points (depthcal uses a
    stride subsample of that many at the target's voxel; small_gicp has no subsample of its own)."""
    import numpy as np
    import small_gicp as sg
    sv = source_voxel_for(S, source_points, voxel, threads) if source_points else voxel
    c0, w0 = time.process_time(), time.perf_counter()
    t_d, t_tree = sg.preprocess_points(T, downsampling_resolution=voxel, num_neighbors=10, num_threads=threads)
    s_d, _ = sg.preprocess_points(S, downsampling_resolution=sv, num_neighbors=10, num_threads=threads)
    r = sg.align(t_d, s_d, t_tree, init_T_target_source=I, registration_type="GICP",
                 max_correspondence_distance=10 * voxel, num_threads=threads)
    out = {"lib": "small_gicp", "fine_ms": (time.perf_counter() - w0) * 1e3,
           "fine_cpu_ms": (time.process_time() - c0) * 1e3, "points": [s_d.size(), t_d.size()],
           "source_voxel": sv, "iterations": r.iterations, "converged": bool(r.converged),
           "error": pose_error(np.asarray(r.T_target_source), G)}
    log(out)
    return out


def fine_open3d(src, tgt, G, I, voxel):
    import numpy as np
    import open3d as o3d
    reg = o3d.pipelines.registration
    S, T = o3d.io.read_point_cloud(src), o3d.io.read_point_cloud(tgt)
    c0, w0 = time.process_time(), time.perf_counter()
    s_d, t_d = S.voxel_down_sample(voxel), T.voxel_down_sample(voxel)
    t_d.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    r = reg.registration_icp(s_d, t_d, 3 * voxel, I, reg.TransformationEstimationPointToPlane(),
                             reg.ICPConvergenceCriteria(1e-6, 1e-6, 50))
    out = {"lib": "open3d", "fine_ms": (time.perf_counter() - w0) * 1e3,
           "fine_cpu_ms": (time.process_time() - c0) * 1e3, "points": [len(s_d.points), len(t_d.points)],
           "iterations": "≤50", "converged": None, "error": pose_error(np.asarray(r.transformation), G)}
    log(out)
    return out


def fine_pair(name, src, tgt, truth, init, threads, with_open3d):
    G, I = matrix(truth), matrix(init)
    d = fine_depthcal(src, tgt, truth, init, threads)
    S, T = read_points(src), read_points(tgt)
    equal = fine_small_gicp(S, T, G, I, d["levels"][-1][0], threads, source_points=d["points"][0])
    default = fine_small_gicp(S, T, G, I, d["levels"][-1][0], threads)
    o = fine_open3d(src, tgt, G, I, d["levels"][-1][0]) if with_open3d else None
    return {"pair": name, "points_in": [len(S), len(T)], "depthcal": d, "small_gicp_equal": equal,
            "small_gicp": default, "open3d": o}


# ---------------------------------------------------------------------------------------------- output
def med(xs):
    xs = sorted(xs)
    return xs[len(xs) // 2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("work")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--skip-5m", action="store_true")
    a = ap.parse_args()
    os.environ["OMP_NUM_THREADS"] = str(a.threads)
    os.makedirs(a.work, exist_ok=True)
    import open3d  # noqa: F401  (imported once, before any timing)
    import small_gicp  # noqa: F401

    src, tgt, m = seven_scenes_pair(a.work, 0.0075, "s7_1m")
    st = [stages_depthcal(src, tgt, m["truth"], m["near"], a.work, a.threads),
          stages_open3d(src, tgt, m["truth"], m["near"], a.work, a.threads),
          stages_small_gicp(src, tgt, m["truth"], m["near"], a.work, a.threads)]
    reg = register_pairs(a.threads, a.rounds)
    fine = [fine_pair("7-Scenes, 1.15M a side", src, tgt, m["truth"], m["init"], a.threads, True)]
    syn = os.path.join(a.work, "synthetic_1m")
    if not os.path.exists(os.path.join(syn, "truth.txt")):
        run([DEPTHCAL, "profile", "--synthetic", "1000000", "--write-pair", syn])
    fine.append(fine_pair("generated, 1M a side", os.path.join(syn, "source.ply"),
                          os.path.join(syn, "target.ply"), os.path.join(syn, "truth.txt"),
                          os.path.join(syn, "init.txt"), a.threads, False))
    if not a.skip_5m:
        s5, t5, _ = seven_scenes_pair(a.work, 0.003, "s7_5m")
        fine.append(fine_pair("7-Scenes, 4.5M a side", s5, t5, m["truth"], m["init"], a.threads, False))

    f = lambda x: "–" if x is None else (f"{x:.1f}" if isinstance(x, float) else str(x))
    print(f"## Stages ({a.threads} threads; 7-Scenes pair, {st[0]['points'][0]} / {st[0]['points'][1]} points)\n")
    print("| stage | depthcal ms | Open3D ms | small_gicp ms | agreement / accuracy |")
    print("|---|---|---|---|---|")
    row = lambda name, k, acc: print(f"| {name} | {f(st[0].get(k))} | {f(st[1].get(k))} | {f(st[2].get(k))} | {acc} |")
    row("kd-tree build (target)", "kdtree_build_ms", "")
    row(f"{st[0]['nn_queries']} nearest-neighbour queries", "nn_queries_ms",
        "mean distance " + " / ".join(f"{s['nn_mean_distance'] * 1e3:.4f}" for s in st) + " mm")
    row("normals (30 within 2 cm; kd-tree included)", "normals_ms", "small_gicp: 30 nearest, no radius")
    row(f"FPFH ({st[0]['fpfh_points']} points, 25 cm, 100)", "fpfh_ms", "small_gicp has none")
    row(f"one point-to-plane ICP iteration ({st[0]['icp_points'][0]} / {st[0]['icp_points'][1]})",
        "icp_iteration_ms", "")
    row("ICP to convergence (≤ 50)", "icp_converged_ms", " / ".join(
        f"{s['icp_error_deg']:.3f}° {s['icp_error_mm']:.1f} mm ({s.get('icp_iterations')} it.)" for s in st))
    print(f"\n## Register pipeline ({a.threads} threads, median of {a.rounds}, alternated)\n")
    print("| pair | depthcal in-process (read incl.) | Open3D in-process (read incl.) | ratio | depthcal process | Open3D process | ratio | errors depthcal / Open3D |")
    print("|---|---|---|---|---|---|---|---|")
    for r in reg:
        d, o, dp, op = med(r["depthcal"]), med(r["open3d"]), med(r["depthcal_process"]), med(r["open3d_process"])
        de, oe = r["depthcal_error"], r["open3d_error"]
        print(f"| {r['pair']} | {d:.0f} ms | {o:.0f} ms | {o / d:.2f}x | {dp:.0f} ms | {op:.0f} ms | {op / dp:.2f}x | "
              f"{de[0]:.2f}° {de[1]:.1f} mm / {oe[0]:.2f}° {oe[1]:.1f} mm |")
    print("\ndepthcal stages (last run, ms): " + "; ".join(
        f"{r['pair']}: " + ", ".join(f"{k} {v}" for k, v in r["depthcal_stages"].items()) for r in reg))
    print(f"\n## Fine stage from a guess 3° / 5 cm off ({a.threads} threads)\n")
    print("| pair | tool | points (source / target) | wall ms | CPU ms | iterations | converged | error |")
    print("|---|---|---|---|---|---|---|---|")
    for p in fine:
        for k, label in [("depthcal", "depthcal (levels " + ", ".join(
                f"{l[0] * 100:.0f} cm: {l[1]} / {l[2]}, {l[3] - 1} it." for l in p["depthcal"]["levels"]) + ")"),
                         ("small_gicp_equal", "small_gicp, same counts"), ("small_gicp", "small_gicp, default"),
                         ("open3d", "Open3D")]:
            r = p[k]
            if r is None:
                continue
            print(f"| {p['pair']} | {label} | {r['points'][0]} / {r['points'][1]} | {r['fine_ms']:.0f} | "
                  f"{r['fine_cpu_ms']:.0f} | {r['iterations']} | {f(r['converged'])} | "
                  f"{r['error'][0]:.3f}° {r['error'][1]:.1f} mm |")


if __name__ == "__main__":
    main()
