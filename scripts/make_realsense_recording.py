#!/usr/bin/env python3
"""Write a small synthetic RealSense recording with librealsense's own recorder (pyrealsense2).

A `software_device` with a depth sensor (Z16) and, with --color, a colour sensor (RGB8) is recorded to OUT
(librealsense 2.59 writes ROS2 `.db3` only; 2.56 and older write ROS1 `.bag`).
The frames carry known values so that a test can check an import exactly:

    depth[k][v][u] = (1000 + 7*u + 13*v + 101*k) % 65536, except 0 where (u + v + k) % 11 == 0
    colour[k][v][u] = ((u + k) % 256, (v + 2*k) % 256, (u + v) % 256)

Intrinsics, depth units and frame count come from the command line; the script prints a JSON summary of
what it wrote (including librealsense's version) on stdout.

Usage: make_realsense_recording.py OUT [--frames N] [--width W] [--height H] [--fx FX] [--fy FY]
       [--ppx PPX] [--ppy PPY] [--model brown_conrady|inverse_brown_conrady|none] [--coeffs k1,k2,p1,p2,k3]
       [--depth-units METRES] [--fps FPS] [--color]

pyrealsense2 is imported from $DEPTHCAL_PYREALSENSE2_PATH when set (what .ci/setup-realsense.sh installs).
"""

import argparse
import json
import os
import sys
import time


def depth_value(u, v, k):
    """The raw depth unit of pixel (u, v) in frame k (0 = no data)."""
    if (u + v + k) % 11 == 0:
        return 0
    return (1000 + 7 * u + 13 * v + 101 * k) % 65536


def color_value(u, v, k):
    """The RGB8 value of pixel (u, v) in frame k."""
    return ((u + k) % 256, (v + 2 * k) % 256, (u + v) % 256)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--width", type=int, default=64)
    p.add_argument("--height", type=int, default=48)
    p.add_argument("--fx", type=float, default=61.25)
    p.add_argument("--fy", type=float, default=60.75)
    p.add_argument("--ppx", type=float, default=31.5)
    p.add_argument("--ppy", type=float, default=23.25)
    p.add_argument("--model", default="brown_conrady")
    p.add_argument("--coeffs", default="0.125,-0.25,0.001,-0.002,0.0625")
    p.add_argument("--depth-units", type=float, default=0.0001)
    p.add_argument("--fps", type=int, default=30)
    p.add_argument("--color", action="store_true")
    a = p.parse_args()

    extra = os.environ.get("DEPTHCAL_PYREALSENSE2_PATH")
    if extra:
        sys.path.insert(0, extra)
    import pyrealsense2 as rs

    coeffs = [float(c) for c in a.coeffs.split(",")]
    if len(coeffs) != 5:
        sys.exit("--coeffs needs 5 numbers")
    models = {
        "none": rs.distortion.none,
        "brown_conrady": rs.distortion.brown_conrady,
        "inverse_brown_conrady": rs.distortion.inverse_brown_conrady,
        "kannala_brandt4": rs.distortion.kannala_brandt4,
    }
    if a.model not in models:
        sys.exit(f"--model must be one of {sorted(models)}")

    def intrinsics():
        i = rs.intrinsics()
        i.width, i.height = a.width, a.height
        i.fx, i.fy, i.ppx, i.ppy = a.fx, a.fy, a.ppx, a.ppy
        i.model = models[a.model]
        i.coeffs = coeffs
        return i

    dev = rs.software_device()
    dev.register_info(rs.camera_info.name, "depthcal synthetic camera")
    dev.register_info(rs.camera_info.serial_number, "000000000001")
    depth_sensor = dev.add_sensor("Stereo Module")
    vs = rs.video_stream()
    vs.type = rs.stream.depth
    vs.index = 0
    vs.uid = 1
    vs.width, vs.height, vs.fps = a.width, a.height, a.fps
    vs.bpp = 2
    vs.fmt = rs.format.z16
    vs.intrinsics = intrinsics()
    depth_profile = depth_sensor.add_video_stream(vs).as_video_stream_profile()
    depth_sensor.add_read_only_option(rs.option.depth_units, a.depth_units)

    color_sensor = color_profile = None
    if a.color:
        color_sensor = dev.add_sensor("RGB Camera")
        cs = rs.video_stream()
        cs.type = rs.stream.color
        cs.index = 0
        cs.uid = 2
        cs.width, cs.height, cs.fps = a.width, a.height, a.fps
        cs.bpp = 3
        cs.fmt = rs.format.rgb8
        cs.intrinsics = intrinsics()
        color_profile = color_sensor.add_video_stream(cs).as_video_stream_profile()

    recorder = rs.recorder(a.out, dev)
    sink = []
    depth_sensor.open(depth_profile)
    depth_sensor.start(lambda f: sink.append(f.get_frame_number()))
    if color_sensor:
        color_sensor.open(color_profile)
        color_sensor.start(lambda f: None)

    period_ms = 1000.0 / a.fps
    for k in range(a.frames):
        ts = 1000.0 + k * period_ms
        d = bytearray(2 * a.width * a.height)
        for v in range(a.height):
            for u in range(a.width):
                val = depth_value(u, v, k)
                i = 2 * (v * a.width + u)
                d[i] = val & 0xFF
                d[i + 1] = val >> 8
        f = rs.software_video_frame()
        f.pixels = bytes(d)
        f.bpp = 2
        f.stride = 2 * a.width
        f.timestamp = ts
        f.domain = rs.timestamp_domain.hardware_clock
        f.frame_number = k + 1
        f.profile = depth_profile
        f.depth_units = a.depth_units
        depth_sensor.on_video_frame(f)
        if color_sensor:
            c = bytearray(3 * a.width * a.height)
            for v in range(a.height):
                for u in range(a.width):
                    i = 3 * (v * a.width + u)
                    c[i : i + 3] = bytes(color_value(u, v, k))
            g = rs.software_video_frame()
            g.pixels = bytes(c)
            g.bpp = 3
            g.stride = 3 * a.width
            g.timestamp = ts
            g.domain = rs.timestamp_domain.hardware_clock
            g.frame_number = k + 1
            g.profile = color_profile
            color_sensor.on_video_frame(g)
        time.sleep(0.01)

    time.sleep(0.1)
    depth_sensor.stop()
    depth_sensor.close()
    if color_sensor:
        color_sensor.stop()
        color_sensor.close()
    del recorder
    print(
        json.dumps(
            {
                "file": a.out,
                "librealsense": getattr(rs, "__version__", "unknown"),
                "frames": a.frames,
                "delivered": len(sink),
                "bytes": os.path.getsize(a.out) if os.path.exists(a.out) else None,
            }
        )
    )


if __name__ == "__main__":
    main()
