"""Regression gate: compare two episode-record files (BASE = stored baseline, NEW = candidate).

Episodes are paired by ``(episode_id, agent)``. For each agent and metric the report gives the
base and new means over the paired episodes and the mean paired change ``new - base`` with a
paired confidence interval (Student t on the per-episode differences, or a percentile
bootstrap with an explicit generator).

Regression rule (per agent; "significant" means the paired CI of the change excludes 0 on the
bad side, so a change whose CI contains 0 is never a regression, and neither is a significant
change smaller than its tolerance):

* ``success`` (0/1): mean change ``< -tol_success`` AND CI upper bound ``< 0``.
* ``spl``: mean change ``< -tol_spl`` AND CI upper bound ``< 0``.
* ``collisions`` (events per episode): mean change ``> +tol_collisions`` AND CI lower bound
  ``> 0``.
* ``plan_ms_median``: on per-episode log ratios ``log(new / base)`` (episodes where both are
  positive): geometric-mean ratio ``> tol_plan_ms_ratio`` AND the ratio's CI lower bound
  ``> 1``. The mean change in milliseconds is reported too.
* An episode that errors in NEW but not in BASE is always a regression (a crash).
* ``soft_spl`` is reported, never gated.

Episodes present in only one file are listed in the report (never silently dropped); with
``strict=True`` (``--strict``) such a mismatch is a regression. Paired metrics use episodes
without an error in either file and with a non-null value in both.

CLI (``simn-sim compare`` or ``python -m simn_sim.experiments.compare``)::

    BASE NEW [--tol-success 0.05] [--tol-spl 0.05] [--tol-collisions 0.1]
             [--tol-plan-ms-ratio 1.5] [--level 0.95] [--bootstrap N --seed S] [--strict]
             [--json REPORT.json]

Exit status: 0 no regression, 1 regression, 2 bad input (missing file, corrupt JSON line --
the message names the file and line -- bad tolerance, or no episode pairs at all).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from simn_sim.config import Config, ConfigError, require
from simn_sim.experiments.stats import RecordError, load_records, mean_ci

__all__ = ["AgentComparison", "ComparisonReport", "MetricChange", "Tolerances", "compare", "main"]

Key = tuple[str, str]  # (episode_id, agent)


@dataclass(frozen=True)
class Tolerances(Config):
    """How much worse a metric may get before it counts as a regression (see module doc)."""

    success: float = 0.05  # success-rate drop (absolute, 0..1)
    spl: float = 0.05  # SPL drop (absolute)
    collisions: float = 0.1  # collision events per episode (absolute increase)
    plan_ms_ratio: float = 1.5  # geometric-mean ratio new / base of plan_ms_median

    def validate(self) -> None:
        n = type(self).__name__
        for name in ("success", "spl", "collisions"):
            v = getattr(self, name)
            require(math.isfinite(v) and v >= 0.0, n, name, f"must be finite and >= 0, got {v}")
        r = self.plan_ms_ratio
        require(math.isfinite(r) and r >= 1.0, n, "plan_ms_ratio", f"must be >= 1, got {r}")


@dataclass(frozen=True)
class MetricChange:
    """Paired change of one metric for one agent (``delta = mean(new - base)``)."""

    metric: str
    n: int
    base_mean: float
    new_mean: float
    delta: float
    ci_low: float
    ci_high: float
    tolerance: float | None
    regression: bool
    ratio: float | None = None  # plan time only: geometric-mean ratio new / base
    ratio_ci_low: float | None = None
    ratio_ci_high: float | None = None


@dataclass
class AgentComparison:
    agent: str
    n_pairs: int
    changes: list[MetricChange]


@dataclass
class ComparisonReport:
    """Result of :func:`compare`. ``regressions`` holds one human-readable reason per failure."""

    agents: list[AgentComparison]
    only_in_base: list[Key]
    only_in_new: list[Key]
    new_errors: list[Key]
    resolved_errors: list[Key]
    both_errors: list[Key]
    regressions: list[str] = field(default_factory=list)
    level: float = 0.95

    @property
    def regression(self) -> bool:
        return bool(self.regressions)

    @property
    def n_pairs(self) -> int:
        return sum(a.n_pairs for a in self.agents)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN -> None)."""
        d = asdict(self)
        d["regression"] = self.regression
        return _no_nan(d)

    def format_table(self) -> str:
        """Plain-text report: one line per agent x metric, then episode lists and verdict."""
        pct = f"{self.level * 100:.0f}%"
        head = (
            f"{'agent':<14}{'metric':<16}{'n':>5}{'base':>11}{'new':>11}  "
            f"{'change [' + pct + ' CI]':<32}{'ratio [CI]':<22}{'tol':>6}  verdict"
        )
        lines = [head, "-" * len(head)]
        for a in self.agents:
            for c in a.changes:
                if c.n == 0:
                    lines.append(f"{a.agent:<14}{c.metric:<16}{0:>5}{'-':>11}{'-':>11}  (no pairs)")
                    continue
                ci = _ci_text(c.delta, c.ci_low, c.ci_high)
                tol = "-" if c.tolerance is None else f"{c.tolerance:g}"
                ratio = ""
                if c.ratio is not None:
                    ratio = f"x{c.ratio:.2f} {_ci_text(None, c.ratio_ci_low, c.ratio_ci_high)}"
                verdict = (
                    "REGRESSION" if c.regression else ("report" if c.tolerance is None else "ok")
                )
                lines.append(
                    f"{a.agent:<14}{c.metric:<16}{c.n:>5}{c.base_mean:>11.4g}{c.new_mean:>11.4g}  "
                    f"{ci:<32}{ratio:<22}{tol:>6}  {verdict}"
                )
        for title, keys in (
            ("only in BASE (missing from NEW)", self.only_in_base),
            ("only in NEW (not in BASE)", self.only_in_new),
            ("error in NEW only", self.new_errors),
            ("error in BASE only (fixed)", self.resolved_errors),
            ("error in both", self.both_errors),
        ):
            if keys:
                shown = ", ".join(f"{e}/{ag}" for e, ag in keys[:20])
                more = f" ... (+{len(keys) - 20})" if len(keys) > 20 else ""
                lines.append(f"{title}: {len(keys)}: {shown}{more}")
        if self.regressions:
            lines.append("REGRESSION:")
            lines += [f"  - {r}" for r in self.regressions]
        else:
            lines.append(f"OK: no regression ({self.n_pairs} paired episodes)")
        return "\n".join(lines)


def _no_nan(obj: Any) -> Any:
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: _no_nan(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_no_nan(v) for v in obj]
    return obj


def _ci_text(center: float | None, lo: float | None, hi: float | None) -> str:
    if lo is None or hi is None or math.isnan(lo):
        return "n/a" if center is None else f"{center:+.4g} [n/a]"
    if center is None:
        return f"[{lo:.2f}, {hi:.2f}]"
    return f"{center:+.4g} [{lo:+.4g}, {hi:+.4g}]"


def _index(records: Iterable[dict[str, Any]], name: str) -> dict[Key, dict[str, Any]]:
    out: dict[Key, dict[str, Any]] = {}
    for i, rec in enumerate(records):
        if not isinstance(rec, dict) or "episode_id" not in rec or "agent" not in rec:
            raise RecordError(f"{name} record {i}: needs 'episode_id' and 'agent'")
        key = (str(rec["episode_id"]), str(rec["agent"]))
        if key in out:
            raise RecordError(f"{name} record {i}: duplicate episode {key[0]!r} / agent {key[1]!r}")
        out[key] = rec
    return out


def _value(rec: dict[str, Any], metric: str) -> float | None:
    v = rec.get(metric)
    if v is None:
        return None
    if isinstance(v, bool):
        return float(v)
    if not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise RecordError(
            f"episode {rec['episode_id']!r}: field {metric!r} is not a finite number: {v!r}"
        )
    return float(v)


def _paired(
    base: list[dict[str, Any]], new: list[dict[str, Any]], metric: str
) -> tuple[np.ndarray, np.ndarray]:
    b, n = [], []
    for rb, rn in zip(base, new, strict=True):
        vb, vn = _value(rb, metric), _value(rn, metric)
        if vb is not None and vn is not None:
            b.append(vb)
            n.append(vn)
    return np.asarray(b, dtype=np.float64), np.asarray(n, dtype=np.float64)


def compare(
    base_records: Iterable[dict[str, Any]],
    new_records: Iterable[dict[str, Any]],
    tolerances: Tolerances | None = None,
    level: float = 0.95,
    method: Literal["t", "bootstrap"] = "t",
    rng: np.random.Generator | None = None,
    strict: bool = False,
) -> ComparisonReport:
    """Pair episodes by (episode_id, agent) and flag regressions (rule: see module docstring).

    Args:
        base_records, new_records: episode records (dicts, e.g. from ``load_records``).
        tolerances: allowed worsening per metric (defaults: :class:`Tolerances`).
        level: confidence level of the paired intervals.
        method: ``"t"`` or ``"bootstrap"`` (then ``rng`` is required).
        strict: episodes present in only one file count as a regression.
    """
    tol = tolerances if tolerances is not None else Tolerances()
    b_idx, n_idx = _index(base_records, "BASE"), _index(new_records, "NEW")
    only_base = [k for k in b_idx if k not in n_idx]
    only_new = [k for k in n_idx if k not in b_idx]
    common = [k for k in b_idx if k in n_idx]
    b_err = {k for k in common if b_idx[k].get("error") is not None}
    n_err = {k for k in common if n_idx[k].get("error") is not None}
    new_errors = [k for k in common if k in n_err and k not in b_err]
    resolved = [k for k in common if k in b_err and k not in n_err]
    both = [k for k in common if k in b_err and k in n_err]
    ok_pairs = [k for k in common if k not in b_err and k not in n_err]

    agents: list[str] = []
    for k in [*b_idx, *n_idx]:
        if k[1] not in agents:
            agents.append(k[1])

    def ci(x: np.ndarray) -> tuple[float, float, float]:
        return mean_ci(x, level, method, rng)

    report_agents: list[AgentComparison] = []
    regressions: list[str] = []
    for agent in agents:
        keys = [k for k in ok_pairs if k[1] == agent]
        rb = [b_idx[k] for k in keys]
        rn = [n_idx[k] for k in keys]
        changes: list[MetricChange] = []
        for metric, t, worse in (
            ("success", tol.success, "lower"),
            ("spl", tol.spl, "lower"),
            ("soft_spl", None, "lower"),
            ("collisions", tol.collisions, "higher"),
        ):
            xb, xn = _paired(rb, rn, metric)
            d, lo, hi = ci(xn - xb)
            if len(xb) == 0:
                changes.append(MetricChange(metric, 0, math.nan, math.nan, d, lo, hi, t, False))
                continue
            if t is None:
                bad = False
            elif worse == "lower":
                bad = d < -t and hi < 0.0
            else:
                bad = d > t and lo > 0.0
            changes.append(
                MetricChange(metric, len(xb), float(xb.mean()), float(xn.mean()), d, lo, hi, t, bad)
            )
            if bad:
                regressions.append(
                    f"{agent}: {metric} changed by {d:+.4g} ({level:.0%} CI [{lo:+.4g}, {hi:+.4g}], "
                    f"n={len(xb)}), worse than the tolerance {t:g}"
                )
        # Planning time: gate on the geometric-mean ratio.
        xb, xn = _paired(rb, rn, "plan_ms_median")
        pos = (xb > 0) & (xn > 0)
        xb, xn = xb[pos], xn[pos]
        d, lo, hi = ci(xn - xb)
        if len(xb) == 0:
            changes.append(
                MetricChange(
                    "plan_ms_median", 0, math.nan, math.nan, d, lo, hi, tol.plan_ms_ratio, False
                )
            )
        else:
            lr, lr_lo, lr_hi = ci(np.log(xn / xb))
            ratio = math.exp(lr)
            r_lo = math.exp(lr_lo) if not math.isnan(lr_lo) else math.nan
            r_hi = math.exp(lr_hi) if not math.isnan(lr_hi) else math.nan
            bad = ratio > tol.plan_ms_ratio and r_lo > 1.0
            changes.append(
                MetricChange(
                    "plan_ms_median",
                    len(xb),
                    float(xb.mean()),
                    float(xn.mean()),
                    d,
                    lo,
                    hi,
                    tol.plan_ms_ratio,
                    bad,
                    ratio,
                    r_lo,
                    r_hi,
                )
            )
            if bad:
                regressions.append(
                    f"{agent}: planning time x{ratio:.2f} (geometric mean, {level:.0%} CI "
                    f"[{r_lo:.2f}, {r_hi:.2f}], n={len(xb)}), above the tolerance x{tol.plan_ms_ratio:g}"
                )
        report_agents.append(AgentComparison(agent, len(keys), changes))

    if new_errors:
        regressions.append(f"{len(new_errors)} episode(s) error in NEW but not in BASE")
    if strict and (only_base or only_new):
        regressions.append(
            f"episode sets differ: {len(only_base)} only in BASE, {len(only_new)} only in NEW"
        )
    return ComparisonReport(
        report_agents, only_base, only_new, new_errors, resolved, both, regressions, level
    )


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="simn-sim compare",
        description="Compare two episodes.jsonl files; exit 1 on a regression, 2 on bad input.",
    )
    p.add_argument("base", metavar="BASE", help="baseline episodes.jsonl")
    p.add_argument("new", metavar="NEW", help="candidate episodes.jsonl")
    d = Tolerances()
    p.add_argument("--tol-success", type=float, default=d.success, help="allowed success-rate drop")
    p.add_argument("--tol-spl", type=float, default=d.spl, help="allowed SPL drop")
    p.add_argument(
        "--tol-collisions", type=float, default=d.collisions, help="allowed collisions/episode rise"
    )
    p.add_argument(
        "--tol-plan-ms-ratio", type=float, default=d.plan_ms_ratio, help="allowed plan-time ratio"
    )
    p.add_argument("--level", type=float, default=0.95, help="confidence level (default 0.95)")
    p.add_argument(
        "--bootstrap", type=int, default=0, metavar="N", help="bootstrap CIs with N resamples"
    )
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.add_argument("--strict", action="store_true", help="differing episode sets are a regression")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the report as JSON")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point; returns the exit status (0 ok, 1 regression, 2 bad input)."""
    parser = _build_parser()
    try:
        args = parser.parse_args(list(argv) if argv is not None else None)
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code) if isinstance(exc.code, int) else 2
    try:
        tol = Tolerances(
            success=args.tol_success,
            spl=args.tol_spl,
            collisions=args.tol_collisions,
            plan_ms_ratio=args.tol_plan_ms_ratio,
        )
        if not 0.0 < args.level < 1.0:
            raise ConfigError(f"--level must be in (0, 1), got {args.level}")
        base = load_records(args.base)
        new = load_records(args.new)
        rng = None
        if args.bootstrap:
            if args.bootstrap < 100:
                raise ConfigError(f"--bootstrap needs >= 100 resamples, got {args.bootstrap}")
            rng = np.random.default_rng(args.seed)
        report = compare(
            base,
            new,
            tol,
            level=args.level,
            method="bootstrap" if args.bootstrap else "t",
            rng=rng,
            strict=args.strict,
        )
    except (RecordError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"BASE: {args.base} ({len(base)} records)\nNEW:  {args.new} ({len(new)} records)")
    print(report.format_table())
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(report.to_dict(), f, indent=2, default=str)
    if report.n_pairs == 0 and not report.new_errors:
        print("error: no episode is present (without error) in both files", file=sys.stderr)
        return 2
    return 1 if report.regression else 0


if __name__ == "__main__":
    raise SystemExit(main())
