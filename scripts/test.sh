#!/usr/bin/env bash
# Set up (GL libraries, .venv, CPU torch, the project with its test extras) and run the tests.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow`.
set -euo pipefail
cd "$(dirname "$0")/.."
SIMN_EXTRAS="${SIMN_EXTRAS:-dev,slam,ray}" bash scripts/setup.sh
export MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/python -m pytest -q "$@"
