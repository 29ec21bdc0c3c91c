#!/usr/bin/env bash
# Set up simn-sim on a fresh Debian machine (root, python3 only).
# Installs the GL libraries for headless rendering, a venv in .venv, the CPU torch wheel,
# and the project with the extras named in $SIMN_EXTRAS (default: dev).
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="${SIMN_EXTRAS:-dev}"
APT_PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libglx-mesa0 libgl1 python3-venv libusb-1.0-0"
missing=""
for p in $APT_PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing
  else
    echo "setup.sh: missing system packages:$missing (no apt-get here; install them by hand)" >&2
  fi
fi
PY="${PYTHON:-python3}"
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
# The CPU build of torch first: a plain 'torch' requirement would pull a multi-GB CUDA build.
.venv/bin/python -c "import torch" 2>/dev/null || \
  .venv/bin/python -m pip install -q torch==2.13.0
# the numeric packages at pinned versions (scripts/constraints.txt: results depend on them)
.venv/bin/python -m pip install -q -c scripts/constraints.txt -e ".[${EXTRAS}]"
