"""Register two Open3D clouds with depthcal: the sample pair (two partial views of one scene, 55% overlap),
the target re-posed by a known transform, so that the answer is known: T_repose @ clouds/demo_truth.txt.

Run from the repository root: python examples/python/register_open3d.py
(uses Open3D when it is installed, else depthcal's own reader).
"""

import numpy as np

import depthcal

try:
    import open3d as o3d
except ImportError:  # the example still runs without Open3D
    o3d = None

def load(path):
    if o3d is not None:
        return o3d.io.read_point_cloud(path)
    return depthcal.read_cloud(path).points  # (N, 3) float32


# A known re-posing: 40 degrees about a tilted axis and a 0.3 m shift.
axis = np.array([0.2, -0.4, 0.9]) / np.linalg.norm([0.2, -0.4, 0.9])
k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
angle = np.radians(40.0)
repose = np.eye(4)
repose[:3, :3] = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
repose[:3, 3] = [0.3, -0.1, 0.05]
truth = repose @ np.loadtxt("clouds/demo_truth.txt")  # T_target_source after the re-posing

source = load("clouds/demo_source.ply")
target = load("clouds/demo_target.ply")
if o3d is not None:
    target.transform(repose)
    points, target_points = np.asarray(source.points), np.asarray(target.points)  # (N, 3) float64
else:
    points, target_points = source, target @ repose[:3, :3].T + repose[:3, 3]

result = depthcal.register(points, target_points)  # any (N, 3) float32/float64 array
print(result)
d = np.linalg.inv(truth) @ result.transform
err_deg = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
print(f"error against the known transform: {err_deg:.4f} deg, {np.linalg.norm(d[:3, 3]) * 1e3:.3f} mm")
print("1-sigma [rx ry rz (rad), tx ty tz (m)]:", " ".join(f"{v:.2e}" for v in result.sigma))
result.check()  # raises depthcal.UntrustedError with the reasons when the result is not trusted
