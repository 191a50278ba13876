#!/usr/bin/env bash
# CI: the Python package. A fresh virtual environment, the README's install command (`pip install ./python`,
# maturin from PyPI through build isolation), then the pytest suite, which compares the results with the
# `depthcal` binary built by `cargo test --release` (target/release/depthcal).
set -euo pipefail
cd "$(dirname "$0")/.."
py=${PYTHON:-python3}
venv=$(mktemp -d)/venv
if ! "$py" -m venv "$venv" >/dev/null 2>&1; then
  echo "python3 -m venv failed: installing python3-venv"
  _sudo=""; [ "$(id -u)" -ne 0 ] && _sudo=sudo
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends python3-venv >/dev/null
  rm -rf "$venv"
  "$py" -m venv "$venv"
fi
"$venv/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip
"$venv/bin/python" -m pip install -q --disable-pip-version-check ./python pytest numpy
DEPTHCAL_CLI="$PWD/target/release/depthcal" "$venv/bin/python" -m pytest python/tests -q
