"""Navigation regression gate: the fixed set ``envs/episodes/regression_v1.json`` against a
stored baseline per agent (``tests/baselines/regression_v1_<agent>.jsonl``).

Two rules, both must pass:

* the paired comparison of :func:`simn_sim.experiments.compare.compare` (success, SPL,
  collisions; significant changes beyond the tolerances; a new crash; a different episode set),
  with planning time not gated (timings belong to benchmarks, not to a behaviour test);
* per episode, for agents whose runs are deterministic on one machine: an episode that
  succeeded in the baseline must still succeed, its SPL may drop by at most ``spl_drop`` and its
  collisions may not rise by more than ``collisions_rise``. Six episodes are too few for the
  paired CI alone to catch one lost episode.

Adding an agent: one line in :data:`AGENTS` plus its baseline from
``scripts/refresh_regression_baseline.py --agent NAME`` (see docs/experiments.md).
"""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path
from typing import Any

import pytest

from simn_sim.experiments.batch import run_regression
from simn_sim.experiments.compare import Tolerances, compare
from simn_sim.experiments.stats import load_records

BASELINES = Path(__file__).parent / "baselines"


@dataclasses.dataclass(frozen=True)
class Gate:
    """Per-agent regression tolerances. ``per_episode=False`` for a stochastic agent leaves
    only the paired (aggregate) rule."""

    per_episode: bool = True
    spl_drop: float = 0.05
    collisions_rise: int = 0
    tolerances: Tolerances = Tolerances(plan_ms_ratio=1e6)


AGENTS: dict[str, Gate] = {
    "oracle": Gate(),
    # deterministic on one machine (iteration-budget planners, seeded noise): per-episode rules
    "simn": Gate(),  # the learned map (the default)
    "simn_points": Gate(),  # the point-store ablation
}
SLOW_AGENTS = {"simn", "simn_points"}  # ~1-5 min each on 2 cores: run in CI's slow step


def regressions(base: list[dict[str, Any]], new: list[dict[str, Any]], gate: Gate) -> list[str]:
    """Every reason why ``new`` is a regression from ``base`` (empty: none)."""
    rep = compare(base, new, gate.tolerances, strict=True)
    out = list(rep.regressions)
    if rep.n_pairs == 0:
        out.append("no episode pairs between baseline and run")
    if gate.per_episode:
        b_idx = {(r["episode_id"], r["agent"]): r for r in base}
        for r in new:
            b = b_idx.get((r["episode_id"], r["agent"]))
            if b is None or b.get("error") is not None:
                continue
            eid = r["episode_id"]
            if r.get("error") is not None:
                continue  # already reported by compare as a new error
            if b.get("success") and not r.get("success"):
                out.append(f"{eid}: succeeded in the baseline, now {r.get('termination')}")
            if (b.get("spl") or 0.0) - (r.get("spl") or 0.0) > gate.spl_drop:
                out.append(f"{eid}: SPL {b.get('spl'):.3f} -> {r.get('spl') or 0.0:.3f}")
            if (r.get("collisions") or 0) - (b.get("collisions") or 0) > gate.collisions_rise:
                out.append(f"{eid}: collisions {b.get('collisions')} -> {r.get('collisions')}")
    return out


#: (set, agent) pairs gated; regression_real_v1 is realistic sensing at 320x240 (slow)
CASES = [("regression_v1", a) for a in sorted(AGENTS)] + [
    ("regression_real_v1", a) for a in sorted(SLOW_AGENTS)
]


@pytest.mark.parametrize(
    "name, agent",
    [
        pytest.param(n, a, marks=pytest.mark.slow)
        if a in SLOW_AGENTS or n != "regression_v1"
        else (n, a)
        for n, a in CASES
    ],
)
def test_regression_set_matches_baseline(name: str, agent: str, tmp_path: Path) -> None:
    base_file = BASELINES / f"{name}_{agent}.jsonl"
    assert base_file.is_file(), (
        f"no baseline {base_file}; create it with scripts/refresh_regression_baseline.py "
        f"--agent {agent} --set {name}"
    )
    base = load_records(base_file)
    new = run_regression(agent, tmp_path / "batch", workers=0, name=name)
    assert len(new) == len(base) >= 4
    problems = regressions(base, new, AGENTS[agent])
    assert not problems, (
        f"{agent} regressed on {name} (if intended, refresh the baseline, see "
        "docs/experiments.md):\n  " + "\n  ".join(problems)
    )


def _degraded(base: list[dict[str, Any]], how: str) -> list[dict[str, Any]]:
    new = copy.deepcopy(base)
    if how == "one_failure":
        new[0].update(success=False, spl=0.0, termination="timeout")
    elif how == "all_slower":
        for r in new:
            r["spl"] = (r["spl"] or 0.0) * 0.7
    elif how == "collision":
        new[1]["collisions"] = (new[1]["collisions"] or 0) + 2
    elif how == "crash":
        new[2].update(error="RuntimeError: boom\nTraceback ...", termination="error")
    elif how == "missing":
        new = new[1:]
    return new


@pytest.mark.parametrize("how", ["one_failure", "all_slower", "collision", "crash", "missing"])
def test_gate_flags_degraded_copies_of_the_baseline(how: str) -> None:
    base = load_records(BASELINES / "regression_v1_oracle.jsonl")
    assert regressions(base, copy.deepcopy(base), AGENTS["oracle"]) == []
    assert regressions(base, _degraded(base, how), AGENTS["oracle"]), how
