# shellcheck shell=bash
# Setup for the cargo feature `realsense` (sourced by .ci/run under `set -euo pipefail`).
#
# librealsense2 is not packaged in Debian. For CI, the librealsense (2.59.1) that is linked statically into
# the `pyrealsense2` wheel from PyPI serves as the shared library realsense-sys links against: the wheel's
# extension module is copied to target/realsense/lib/librealsense2.so.2.59, given that soname and a
# dependency on libpython3.11 (it references the Python C API), and described by a realsense2.pc. The
# wheel itself also stays installed: scripts/make_realsense_recording.py uses it to write the synthetic
# ROS2 .db3 recordings that tests/realsense_playback.rs imports. librealsense 2.59 no longer writes ROS1 .bag,
# so the 2.56 wheel is installed beside it (Python only, never linked) to write the .bag recordings.
#
# Idempotent: a second run finds everything in place and only exports the variables. Users install Intel's
# librealsense packages instead (see docs/capture.md).

rs_version="2.59.1"
rs_wheel="pyrealsense2==2.59.1.11053"
rs_root="$(pwd)/target/realsense"
rs_lib="$rs_root/lib"
rs_py="$rs_root/python"
rs_bag_wheel="pyrealsense2==2.56.5.9235"
rs_py_bag="$rs_root/python-2.56"

rs_missing=()
for pkg in patchelf libusb-1.0-0 libudev1 libpython3.11; do
  dpkg -s "$pkg" >/dev/null 2>&1 || rs_missing+=("$pkg")
done
if ((${#rs_missing[@]})); then
  echo "installing ${rs_missing[*]}"
  # Wait for another apt/dpkg run (up to 10 minutes) instead of failing on its lock.
  apt-get -o DPkg::Lock::Timeout=600 update -qq
  DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=600 install -y -qq "${rs_missing[@]}" >/dev/null
fi

if ! ls "$rs_py"/pyrealsense2/pyrealsense2.cpython-311-*.so >/dev/null 2>&1; then
  echo "installing $rs_wheel into $rs_py"
  python3 -m pip install --quiet --disable-pip-version-check --root-user-action=ignore --no-deps \
    --target "$rs_py" "$rs_wheel"
fi

if ! ls "$rs_py_bag"/pyrealsense2/pyrealsense2.cpython-311-*.so >/dev/null 2>&1; then
  echo "installing $rs_bag_wheel into $rs_py_bag"
  python3 -m pip install --quiet --disable-pip-version-check --root-user-action=ignore --no-deps \
    --target "$rs_py_bag" "$rs_bag_wheel"
fi

if [ ! -f "$rs_lib/librealsense2.so.2.59" ] || [ ! -f "$rs_lib/pkgconfig/realsense2.pc" ]; then
  mkdir -p "$rs_lib/pkgconfig"
  rs_so=$(ls "$rs_py"/pyrealsense2/pyrealsense2.cpython-311-*.so | head -n 1)
  cp "$rs_so" "$rs_lib/librealsense2.so.2.59.tmp"
  patchelf --set-soname librealsense2.so.2.59 "$rs_lib/librealsense2.so.2.59.tmp"
  patchelf --add-needed libpython3.11.so.1.0 "$rs_lib/librealsense2.so.2.59.tmp"
  mv "$rs_lib/librealsense2.so.2.59.tmp" "$rs_lib/librealsense2.so.2.59"
  ln -sf librealsense2.so.2.59 "$rs_lib/librealsense2.so"
  cat >"$rs_lib/pkgconfig/realsense2.pc.tmp" <<PC
prefix=$rs_root
libdir=$rs_lib
includedir=$rs_root/include

Name: realsense2
Description: Intel RealSense SDK 2.0 (from the pyrealsense2 wheel, for CI)
Version: $rs_version
Libs: -L\${libdir} -lrealsense2
Cflags: -I\${includedir}
PC
  mv "$rs_lib/pkgconfig/realsense2.pc.tmp" "$rs_lib/pkgconfig/realsense2.pc"
fi

export PKG_CONFIG_PATH="$rs_lib/pkgconfig${PKG_CONFIG_PATH:+:$PKG_CONFIG_PATH}"
export LD_LIBRARY_PATH="$rs_lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
# Where the tests' recording script finds pyrealsense2 (2.59: .db3; 2.56: .bag).
export DEPTHCAL_PYREALSENSE2_PATH="$rs_py"
export DEPTHCAL_PYREALSENSE2_BAG_PATH="$rs_py_bag"
echo "librealsense $rs_version for the realsense feature: $rs_lib"
