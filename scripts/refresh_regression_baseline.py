"""Refresh the stored navigation-regression baseline of an agent, on purpose.

    MUJOCO_GL=egl .venv/bin/python scripts/refresh_regression_baseline.py --agent oracle

runs ``envs/episodes/regression_v1.json`` with the agent exactly as
``tests/test_regression_nav.py`` does (160x120, ``simn_sim.experiments.batch.run_regression``),
prints the comparison with the current baseline (if any) and writes
``tests/baselines/regression_v1_<agent>.jsonl``. Commit the new file with a message that says
why the behaviour changed. ``--check`` only compares (exit 1 on a regression, like the test).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def baseline_path(agent: str, name: str) -> Path:
    """``tests/baselines/<name>_<agent>.jsonl``."""
    return ROOT / "tests" / "baselines" / f"{name}_{agent}.jsonl"


def main(argv: list[str] | None = None) -> int:
    from simn_sim.experiments.batch import REGRESSION_SET, run_regression
    from simn_sim.experiments.compare import Tolerances, compare
    from simn_sim.experiments.stats import load_records

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--agent", required=True)
    p.add_argument("--set", default=REGRESSION_SET, help="episode set under envs/episodes/")
    p.add_argument("--workers", type=int, default=0, help="0: in-process")
    p.add_argument("--check", action="store_true", help="compare only, write nothing")
    args = p.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="simn-regression-") as tmp:
        recs = run_regression(args.agent, tmp, workers=args.workers, name=args.set)
    errs = [r for r in recs if r.get("error") is not None]
    for r in recs:
        print(
            f"{r['episode_id']:14s} success={r['success']} spl={r['spl']} "
            f"collisions={r['collisions']} steps={r['steps']} termination={r['termination']}"
        )
    dest = baseline_path(args.agent, args.set)
    status = 0
    if dest.is_file():
        rep = compare(load_records(dest), recs, Tolerances(plan_ms_ratio=1e6), strict=True)
        print(rep.format_table())
        status = 1 if rep.regression else 0
    if args.check:
        return status
    if errs:
        print(f"refusing to store a baseline with {len(errs)} errored episode(s):", file=sys.stderr)
        for r in errs:
            print(f"  {r['episode_id']}: {str(r['error']).splitlines()[0]}", file=sys.stderr)
        return 1
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text("".join(json.dumps(r, sort_keys=True, default=str) + "\n" for r in recs))
    print(f"wrote {dest} ({len(recs)} records)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
