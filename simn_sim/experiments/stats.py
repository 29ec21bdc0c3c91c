"""Episode-record statistics: means with 95 % confidence intervals, per agent and metric.

Records are the per-episode JSON objects of ``episodes.jsonl`` (one object per line; see
``simn_sim/experiments/runner.py``): ``episode_id``, ``agent``, ``success`` (bool), ``spl``,
``soft_spl``, ``collisions`` (int), ``plan_ms_median`` (float or null), ``path_length_m``,
``error`` (null or a string), ...

Confidence intervals:

* ``method="t"``: Student-t interval ``mean +- t_{n-1, (1+level)/2} * s / sqrt(n)``;
* ``method="bootstrap"``: percentile bootstrap of the mean with an explicit
  ``numpy.random.Generator`` (``n_boot`` resamples).

With n < 2 the interval is undefined (NaN); with zero spread it collapses to the mean.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import stats as sps

__all__ = [
    "DEFAULT_METRICS",
    "RecordError",
    "SummaryRow",
    "load_records",
    "mean_ci",
    "metric_values",
    "summarize",
    "summary_markdown",
    "write_summary_csv",
]

#: Metrics summarised by default (record field names).
DEFAULT_METRICS: tuple[str, ...] = (
    "success",
    "spl",
    "soft_spl",
    "collisions",
    "path_length_m",
    "plan_ms_median",
)
#: Metrics that count an errored episode as a failure (0) rather than leaving it out.
FAILURE_METRICS: frozenset[str] = frozenset({"success", "spl", "soft_spl"})

_NUMERIC_FIELDS = ("spl", "soft_spl", "collisions", "plan_ms_median", "path_length_m")


class RecordError(ValueError):
    """A records file or record is malformed; the message names the file and line."""


# --------------------------------------------------------------------------- loading


def _check_record(rec: Any, where: str) -> dict[str, Any]:
    if not isinstance(rec, dict):
        raise RecordError(f"{where}: expected a JSON object, got {type(rec).__name__}")
    for key in ("episode_id", "agent"):
        if key not in rec or rec[key] is None:
            raise RecordError(f"{where}: missing field '{key}'")
    s = rec.get("success")
    if s is not None and not isinstance(s, bool) and s not in (0, 1):
        raise RecordError(f"{where}: field 'success' must be true/false/null, got {s!r}")
    for key in _NUMERIC_FIELDS:
        v = rec.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise RecordError(f"{where}: field '{key}' must be a number or null, got {v!r}")
        if isinstance(v, float) and math.isnan(v):
            raise RecordError(f"{where}: field '{key}' is NaN")
    err = rec.get("error")
    if err is not None and not isinstance(err, str):
        raise RecordError(f"{where}: field 'error' must be null or a string, got {err!r}")
    return rec


def load_records(path: str | Path) -> list[dict[str, Any]]:
    """Read a JSONL file of episode records (blank lines are skipped).

    Raises:
        RecordError: unreadable file, corrupt JSON, a non-object line, a malformed field or a
            duplicated (episode_id, agent); the message names the file and line number.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise RecordError(f"{p}: cannot read ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise RecordError(f"{p}: not UTF-8 text ({exc.reason})") from exc
    out: list[dict[str, Any]] = []
    seen: dict[tuple[str, str], int] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{p}:{lineno}"
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise RecordError(f"{where}: corrupt JSON ({exc.msg} at column {exc.colno})") from exc
        rec = _check_record(rec, where)
        key = (str(rec["episode_id"]), str(rec["agent"]))
        if key in seen:
            raise RecordError(
                f"{where}: duplicate episode_id {key[0]!r} for agent {key[1]!r} "
                f"(first on line {seen[key]})"
            )
        seen[key] = lineno
        out.append(rec)
    return out


# --------------------------------------------------------------------------- statistics


def mean_ci(
    values: Sequence[float] | np.ndarray,
    level: float = 0.95,
    method: Literal["t", "bootstrap"] = "t",
    rng: np.random.Generator | None = None,
    n_boot: int = 10_000,
) -> tuple[float, float, float]:
    """Mean and confidence interval of ``values`` (1-D, finite).

    Args:
        values: (n,) samples.
        level: confidence level in (0, 1).
        method: ``"t"`` (Student t) or ``"bootstrap"`` (percentile bootstrap; needs ``rng``).
        rng: explicit generator for the bootstrap.
        n_boot: bootstrap resamples.

    Returns:
        (mean, low, high); NaN for an empty input, (mean, NaN, NaN) for n == 1.
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"values must be 1-D, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("values must be finite (found NaN or inf)")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    n = len(x)
    if n == 0:
        return math.nan, math.nan, math.nan
    m = float(x.mean())
    if n == 1:
        return m, math.nan, math.nan
    if method == "t":
        sd = float(x.std(ddof=1))
        half = float(sps.t.ppf(0.5 + level / 2.0, df=n - 1)) * sd / math.sqrt(n)
        return m, m - half, m + half
    if method == "bootstrap":
        if not isinstance(rng, np.random.Generator):
            raise ValueError("method='bootstrap' needs an explicit numpy.random.Generator rng")
        if n_boot < 100:
            raise ValueError(f"n_boot must be >= 100, got {n_boot}")
        means = x[rng.integers(0, n, size=(n_boot, n))].mean(axis=1)
        lo, hi = np.quantile(means, [0.5 - level / 2.0, 0.5 + level / 2.0])
        return m, float(min(lo, m)), float(max(hi, m))
    raise ValueError(f"method must be 't' or 'bootstrap', got {method!r}")


def metric_values(
    records: Iterable[dict[str, Any]], metric: str, errors_as_failures: bool = True
) -> np.ndarray:
    """Values of ``metric`` over ``records`` as float64 (bool -> 0/1).

    Records with a null value are left out. Errored records (``error`` not null) count as 0
    for success / spl / soft_spl when ``errors_as_failures``, and are left out otherwise and
    for every other metric.
    """
    vals = []
    for rec in records:
        errored = rec.get("error") is not None
        if errored:
            if errors_as_failures and metric in FAILURE_METRICS:
                vals.append(0.0)
            continue
        v = rec.get(metric)
        if v is None:
            continue
        vals.append(float(v))
    return np.asarray(vals, dtype=np.float64)


@dataclass(frozen=True)
class SummaryRow:
    """One (agent, metric) summary: mean with a ``level`` confidence interval."""

    agent: str
    metric: str
    n: int
    mean: float
    ci_low: float
    ci_high: float
    std: float
    n_episodes: int
    n_errors: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "agent": self.agent,
            "metric": self.metric,
            "n": self.n,
            "mean": self.mean,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "std": self.std,
            "n_episodes": self.n_episodes,
            "n_errors": self.n_errors,
        }


def summarize(
    records: Iterable[dict[str, Any]],
    metrics: Sequence[str] = DEFAULT_METRICS,
    level: float = 0.95,
    method: Literal["t", "bootstrap"] = "t",
    rng: np.random.Generator | None = None,
    errors_as_failures: bool = True,
) -> list[SummaryRow]:
    """Per agent and metric: n, mean, CI, std (long format: one row per agent x metric).

    Agents appear in order of first appearance; metrics in the given order. See
    :func:`metric_values` for how null values and errored episodes are treated.
    """
    by_agent: dict[str, list[dict[str, Any]]] = {}
    for rec in records:
        by_agent.setdefault(str(rec["agent"]), []).append(rec)
    rows: list[SummaryRow] = []
    for agent, recs in by_agent.items():
        n_err = sum(r.get("error") is not None for r in recs)
        for metric in metrics:
            x = metric_values(recs, metric, errors_as_failures)
            m, lo, hi = mean_ci(x, level, method, rng)
            sd = float(x.std(ddof=1)) if len(x) > 1 else math.nan
            rows.append(SummaryRow(agent, metric, len(x), m, lo, hi, sd, len(recs), n_err))
    return rows


def write_summary_csv(rows: Sequence[SummaryRow], path: str | Path) -> None:
    """Write summary rows (long format) as CSV with a header line."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fields = list(SummaryRow.__dataclass_fields__)
    with p.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        for r in rows:
            w.writerow(r.as_dict())


def _fmt(mean: float, lo: float, hi: float, digits: int) -> str:
    if math.isnan(mean):
        return "-"
    if math.isnan(lo):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def summary_markdown(rows: Sequence[SummaryRow], digits: int = 3) -> str:
    """Markdown table, one line per agent: ``mean [ci_low, ci_high]`` per metric."""
    agents: list[str] = []
    metrics: list[str] = []
    cell: dict[tuple[str, str], SummaryRow] = {}
    for r in rows:
        if r.agent not in agents:
            agents.append(r.agent)
        if r.metric not in metrics:
            metrics.append(r.metric)
        cell[(r.agent, r.metric)] = r
    head = ["agent", "episodes", "errors", *metrics]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for a in agents:
        first = next(r for r in rows if r.agent == a)
        vals = []
        for m in metrics:
            r = cell.get((a, m))
            vals.append("-" if r is None else _fmt(r.mean, r.ci_low, r.ci_high, digits))
        lines.append(
            "| " + " | ".join([a, str(first.n_episodes), str(first.n_errors), *vals]) + " |"
        )
    return "\n".join(lines) + "\n"
