#!/usr/bin/env bash
# Sourced by .ci/run (under `set -euo pipefail`) before the lints and tests with the cargo feature `vision`.
# Installs Debian's OpenCV 4.6 (with the contrib modules: aruco) and the clang the `opencv` crate's binding
# generator needs, then exports what its build script reads. Idempotent: a machine that has the packages
# only gets the exports. Needs root (CI and the developers' machines run as root) or sudo.
_vision_pkgs=(libopencv-dev libopencv-contrib-dev clang libclang-dev pkg-config)
_vision_missing=()
for _p in "${_vision_pkgs[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$_p" 2>/dev/null | grep -q "install ok installed"; then
    _vision_missing+=("$_p")
  fi
done
if ((${#_vision_missing[@]})); then
  echo "setup-vision: installing ${_vision_missing[*]}"
  _sudo=""
  if [ "$(id -u)" != 0 ]; then _sudo="sudo"; fi
  _t0=$(date +%s)
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${_vision_missing[@]}" >/dev/null
  echo "setup-vision: installed in $(($(date +%s) - _t0)) s"
else
  echo "setup-vision: OpenCV and clang already installed"
fi
# The opencv crate finds OpenCV through pkg-config (opencv4.pc) and libclang through LIBCLANG_PATH.
_llvm_lib=$(ls -d /usr/lib/llvm-*/lib 2>/dev/null | sort -V | tail -n 1 || true)
if [ -n "$_llvm_lib" ] && [ -z "${LIBCLANG_PATH:-}" ]; then
  export LIBCLANG_PATH="$_llvm_lib"
fi
echo "setup-vision: OpenCV $(pkg-config --modversion opencv4), LIBCLANG_PATH=${LIBCLANG_PATH:-unset}"
unset _vision_pkgs _vision_missing _p _sudo _t0 _llvm_lib
