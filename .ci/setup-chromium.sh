#!/usr/bin/env bash
# Sourced by .ci/run (under `set -euo pipefail`) before the tests: tests/report.rs opens the pages of
# `--report` in headless Chromium. Installs Debian's `chromium` when no Chromium is on PATH. Idempotent.
# Needs root (CI and the developers' machines run as root) or sudo.
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 \
  || command -v google-chrome >/dev/null 2>&1; then
  echo "setup-chromium: a Chromium is already installed"
else
  echo "setup-chromium: installing chromium"
  _sudo=""
  if [ "$(id -u)" != 0 ]; then _sudo="sudo"; fi
  _t0=$(date +%s)
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $_sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null
  echo "setup-chromium: installed in $(($(date +%s) - _t0)) s"
  unset _sudo _t0
fi
