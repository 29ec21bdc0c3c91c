#!/usr/bin/env bash
# Set up (GL libraries, .venv, CPU torch, the project with its test extras) and run the tests.
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow`.
# Test extras: dev (pytest, build), slam (evo), ray, ompl (the OMPL planner tests). Not bench:
# open3d-cpu (~300 MB installed) is used only by scripts/bench_tracking.py, by no test.
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRAS="${SIMN_EXTRAS:-dev,slam,ray,ompl}"
SIMN_EXTRAS="$EXTRAS" bash scripts/setup.sh
export MUJOCO_GL="${MUJOCO_GL:-egl}"
# with ompl installed, the OMPL tests fail instead of skipping when it cannot be imported
case ",$EXTRAS," in *,ompl,* | *,bench,*) export SIMN_REQUIRE_OMPL=1 ;; esac
exec .venv/bin/python -m pytest -q "$@"
