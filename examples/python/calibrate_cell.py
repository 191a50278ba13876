"""Calibrate the demo cell (two robots with depth cameras) and print T_base1_base2 for ROS 2 and KUKA.

Run from the repository root: python examples/python/calibrate_cell.py [CELL_DIR]
"""

import sys

import numpy as np

import depthcal

cell = sys.argv[1] if len(sys.argv) > 1 else "clouds/demo-cell"
c = depthcal.calibrate(cell)  # fuse, initialise from depth, refine, check
print(c)
print("T_base1_base2 (maps", c.other, "base coordinates into", c.reference, "base, metres):")
print(np.array2string(c.transform, precision=6, suppress_small=True))
print("1-sigma: rotation", np.round(c.sigma_deg, 4), "deg, translation", np.round(c.sigma_mm, 3), "mm")
print("KUKA XYZ-ABC (mm, deg):", " ".join(f"{v:.4f}" for v in depthcal.matrix_to_kuka(c.transform)))
print("ROS 2:", c.ros2)
if c.error_vs_truth is not None:
    print("error against ground_truth.json: {:.4f} deg, {:.3f} mm".format(*c.error_vs_truth))
if not c.trusted:
    print("NOT trusted:", *c.reasons, sep="\n  ")
    sys.exit(3)
# c.transform_files() holds the ROS 2 launch file, URDF joint, TF YAML, KUKA, UR and ABB frames.
print(c.transform_files()["static_tf.launch.py"])
