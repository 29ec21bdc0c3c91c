#!/usr/bin/env bash
# Set up (GL libraries, .venv, CPU torch, the project) and run one headless demo episode.
# Extra arguments go to `simn-sim demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
SIMN_EXTRAS="${SIMN_EXTRAS:-slam}" bash scripts/setup.sh
export MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/simn-sim demo --out runs/demo "$@"
