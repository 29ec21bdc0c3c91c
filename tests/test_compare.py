"""Statistics and the regression gate on synthetic episode records."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.experiments.compare import Tolerances, compare, main
from simn_sim.experiments.stats import (
    RecordError,
    load_records,
    mean_ci,
    summarize,
    summary_markdown,
    write_summary_csv,
)


def make_records(
    rng: np.random.Generator,
    n: int = 40,
    agent: str = "simn",
    p_success: float = 0.8,
    collision_rate: float = 0.5,
    plan_ms: float = 20.0,
) -> list[dict]:
    recs = []
    for i in range(n):
        ok = bool(rng.random() < p_success)
        recs.append(
            {
                "episode_id": f"ep-{i:03d}",
                "agent": agent,
                "success": ok,
                "spl": float(rng.uniform(0.6, 0.95)) if ok else 0.0,
                "soft_spl": float(rng.uniform(0.5, 0.95)),
                "collisions": int(rng.poisson(collision_rate)),
                "plan_ms_median": float(plan_ms * rng.lognormal(0.0, 0.1)),
                "path_length_m": float(rng.uniform(3, 12)),
                "error": None,
            }
        )
    return recs


def write_jsonl(path, records) -> str:
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return str(path)


# ----------------------------------------------------------------------------- stats


def test_mean_ci_student_t_hand_value():
    m, lo, hi = mean_ci([1, 2, 3, 4, 5])
    half = 2.7764451051977987 * math.sqrt(2.5) / math.sqrt(5)  # t_{4, 0.975} * s / sqrt(n)
    assert m == 3.0
    assert lo == pytest.approx(3 - half) and hi == pytest.approx(3 + half)
    assert mean_ci([2.0, 2.0, 2.0]) == (2.0, 2.0, 2.0)
    m1, lo1, hi1 = mean_ci([4.0])
    assert m1 == 4.0 and math.isnan(lo1) and math.isnan(hi1)
    assert all(math.isnan(v) for v in mean_ci([]))


def test_mean_ci_bootstrap_needs_rng_and_is_reproducible():
    x = np.random.default_rng(0).normal(1.0, 2.0, 400)
    with pytest.raises(ValueError, match="Generator"):
        mean_ci(x, method="bootstrap")
    a = mean_ci(x, method="bootstrap", rng=np.random.default_rng(5))
    b = mean_ci(x, method="bootstrap", rng=np.random.default_rng(5))
    assert a == b
    t = mean_ci(x)
    assert a[1] == pytest.approx(t[1], abs=0.05) and a[2] == pytest.approx(t[2], abs=0.05)
    with pytest.raises(ValueError):
        mean_ci([1.0, float("nan")])
    with pytest.raises(ValueError):
        mean_ci([1.0, 2.0], method="jackknife")


def test_summarize_counts_errors_as_failures_and_skips_nulls(tmp_path):
    recs = [
        {
            "episode_id": "a",
            "agent": "x",
            "success": True,
            "spl": 0.8,
            "collisions": 1,
            "plan_ms_median": 10.0,
            "error": None,
        },
        {
            "episode_id": "b",
            "agent": "x",
            "success": False,
            "spl": 0.0,
            "collisions": 3,
            "plan_ms_median": None,
            "error": None,
        },
        {
            "episode_id": "c",
            "agent": "x",
            "success": None,
            "spl": None,
            "collisions": None,
            "plan_ms_median": None,
            "error": "boom",
        },
        {
            "episode_id": "a",
            "agent": "y",
            "success": True,
            "spl": 1.0,
            "collisions": 0,
            "plan_ms_median": 5.0,
            "error": None,
        },
    ]
    rows = summarize(recs, metrics=("success", "spl", "collisions", "plan_ms_median"))
    by = {(r.agent, r.metric): r for r in rows}
    assert len(rows) == 8
    assert by[("x", "success")].n == 3 and by[("x", "success")].mean == pytest.approx(1 / 3)
    assert by[("x", "spl")].mean == pytest.approx(0.8 / 3)
    assert by[("x", "collisions")].n == 2 and by[("x", "collisions")].mean == 2.0
    assert by[("x", "plan_ms_median")].n == 1 and math.isnan(by[("x", "plan_ms_median")].ci_low)
    assert by[("x", "success")].n_errors == 1 and by[("x", "success")].n_episodes == 3
    rows2 = summarize(recs, metrics=("success",), errors_as_failures=False)
    assert rows2[0].n == 2 and rows2[0].mean == 0.5
    md = summary_markdown(rows)
    assert (
        md.splitlines()[0]
        == "| agent | episodes | errors | success | spl | collisions | plan_ms_median |"
    )
    assert "| x | 3 | 1 | 0.333 [" in md
    write_summary_csv(rows, tmp_path / "summary.csv")
    lines = (tmp_path / "summary.csv").read_text().splitlines()
    assert lines[0].startswith("agent,metric,n,mean,ci_low,ci_high") and len(lines) == 9


def test_load_records_errors_name_file_and_line(tmp_path):
    good = {"episode_id": "e1", "agent": "simn", "success": True, "error": None}
    p = tmp_path / "runs.jsonl"
    p.write_text(json.dumps(good) + "\n\n" + '{"episode_id": "e2", "agent": "simn", "succ\n')
    with pytest.raises(RecordError, match=r"runs\.jsonl:3: corrupt JSON"):
        load_records(p)
    p.write_text(json.dumps(good) + "\n" + json.dumps(good) + "\n")
    with pytest.raises(RecordError, match=r"runs\.jsonl:2: duplicate.*line 1"):
        load_records(p)
    p.write_text(json.dumps({**good, "spl": "high"}) + "\n")
    with pytest.raises(RecordError, match=r"runs\.jsonl:1: field 'spl'"):
        load_records(p)
    p.write_text("[1, 2]\n")
    with pytest.raises(RecordError, match="JSON object"):
        load_records(p)
    with pytest.raises(RecordError, match="cannot read"):
        load_records(tmp_path / "missing.jsonl")
    p.write_text(json.dumps(good) + "\n")
    assert load_records(p) == [good]


# ----------------------------------------------------------------------------- compare


def test_no_change_is_not_a_regression(tmp_path, capsys):
    recs = make_records(np.random.default_rng(0))
    rep = compare(recs, recs)
    assert not rep.regression and rep.n_pairs == 40
    for c in rep.agents[0].changes:
        assert c.delta == 0.0 and not c.regression
    b = write_jsonl(tmp_path / "base.jsonl", recs)
    n = write_jsonl(tmp_path / "new.jsonl", recs)
    assert main([b, n]) == 0
    assert "OK: no regression (40 paired episodes)" in capsys.readouterr().out


def test_clear_success_and_spl_regression(tmp_path, capsys):
    rng = np.random.default_rng(1)
    base = make_records(rng, p_success=1.0)
    new = [dict(r) for r in base]
    for r in new[::2]:  # half the episodes now fail
        r["success"], r["spl"] = False, 0.0
    rep = compare(base, new)
    ch = {c.metric: c for c in rep.agents[0].changes}
    assert ch["success"].delta == pytest.approx(-0.5)
    assert ch["success"].regression and ch["spl"].regression
    assert ch["success"].ci_high < 0
    assert not ch["collisions"].regression and not ch["plan_ms_median"].regression
    assert any("success" in r for r in rep.regressions)
    b = write_jsonl(tmp_path / "base.jsonl", base)
    n = write_jsonl(tmp_path / "new.jsonl", new)
    assert main([b, n]) == 1
    out = capsys.readouterr().out
    assert "REGRESSION" in out and "simn" in out
    # A tolerance larger than the drop turns the gate off for these metrics.
    assert main([b, n, "--tol-success", "0.6", "--tol-spl", "0.6"]) == 0


def test_small_or_insignificant_changes_pass():
    rng = np.random.default_rng(2)
    base = make_records(rng, n=30)
    new = [dict(r) for r in base]
    new[0]["success"], new[0]["spl"] = (not base[0]["success"]), 0.0  # one flip: -0.03 or +0.03
    new[1]["collisions"] += 2  # +0.067 per episode < 0.1
    rep = compare(base, new)
    assert not rep.regression, rep.regressions
    # Large but noisy change: one episode with many collisions; CI includes 0 -> not flagged.
    new2 = [dict(r) for r in base]
    new2[0]["collisions"] += 30
    rep2 = compare(base, new2)
    c = next(c for c in rep2.agents[0].changes if c.metric == "collisions")
    assert c.delta == pytest.approx(1.0) and c.ci_low < 0 and not c.regression


def test_collision_and_planning_time_regressions():
    rng = np.random.default_rng(3)
    base = make_records(rng, collision_rate=0.2, plan_ms=20.0)
    new = [dict(r) for r in base]
    for r in new:
        r["collisions"] += 1
        r["plan_ms_median"] *= 2.0
    rep = compare(base, new)
    ch = {c.metric: c for c in rep.agents[0].changes}
    assert ch["collisions"].regression and ch["collisions"].delta == pytest.approx(1.0)
    assert ch["plan_ms_median"].regression and ch["plan_ms_median"].ratio == pytest.approx(2.0)
    # 1.2x slower: significant but within the 1.5x tolerance.
    new_ok = [dict(r, plan_ms_median=r["plan_ms_median"] * 1.2) for r in base]
    pm = next(c for c in compare(base, new_ok).agents[0].changes if c.metric == "plan_ms_median")
    assert pm.ratio == pytest.approx(1.2) and pm.ratio_ci_low > 1.0 and not pm.regression
    # Null planning times (agent without a planner) are skipped, not a failure.
    nulls = [dict(r, plan_ms_median=None) for r in base]
    pm0 = next(c for c in compare(nulls, nulls).agents[0].changes if c.metric == "plan_ms_median")
    assert pm0.n == 0 and not pm0.regression


def test_unpaired_episodes_and_errors_are_reported():
    rng = np.random.default_rng(4)
    base = make_records(rng, n=10) + make_records(rng, n=5, agent="oracle")
    new = [dict(r) for r in base[2:]]  # ep-000, ep-001 of simn missing
    new.append(dict(base[0], episode_id="ep-new"))
    new[0] = dict(new[0], error="RuntimeError: planner exploded")  # simn ep-002 now errors
    rep = compare(base, new)
    assert rep.only_in_base == [("ep-000", "simn"), ("ep-001", "simn")]
    assert rep.only_in_new == [("ep-new", "simn")]
    assert rep.new_errors == [("ep-002", "simn")]
    assert rep.regression and "error in NEW" in rep.regressions[0]
    assert [a.agent for a in rep.agents] == ["simn", "oracle"]
    assert rep.agents[0].n_pairs == 7 and rep.agents[1].n_pairs == 5
    text = rep.format_table()
    assert "only in BASE (missing from NEW): 2: ep-000/simn, ep-001/simn" in text
    assert "error in NEW only: 1: ep-002/simn" in text
    # Missing episodes alone: reported, a regression only when strict.
    new_ok = [dict(r) for r in base[1:]]
    assert not compare(base, new_ok).regression
    assert compare(base, new_ok, strict=True).regression


def test_bootstrap_compare_is_reproducible():
    rng = np.random.default_rng(5)
    base = make_records(rng)
    new = [dict(r, spl=r["spl"] * 0.5) for r in base]
    a = compare(base, new, method="bootstrap", rng=np.random.default_rng(0))
    b = compare(base, new, method="bootstrap", rng=np.random.default_rng(0))
    assert a.to_dict() == b.to_dict()
    assert a.regression


def test_main_bad_input_returns_2(tmp_path, capsys):
    recs = make_records(np.random.default_rng(6), n=3)
    b = write_jsonl(tmp_path / "base.jsonl", recs)
    assert main([b, str(tmp_path / "nope.jsonl")]) == 2
    assert "nope.jsonl" in capsys.readouterr().err
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps(recs[0]) + "\n" + "{not json}\n")
    assert main([b, str(bad)]) == 2
    assert "bad.jsonl:2: corrupt JSON" in capsys.readouterr().err
    assert main([b, b, "--tol-spl", "-1"]) == 2
    assert main([b]) == 2  # usage error
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    assert main([b, str(empty)]) == 2
    with pytest.raises(ConfigError):
        Tolerances(plan_ms_ratio=0.5)


def test_main_writes_json_report(tmp_path):
    recs = make_records(np.random.default_rng(7), n=5)
    b = write_jsonl(tmp_path / "base.jsonl", recs)
    out = tmp_path / "report.json"
    assert main([b, b, "--json", str(out), "--bootstrap", "500", "--seed", "1"]) == 0
    rep = json.loads(out.read_text())
    assert rep["regression"] is False and rep["agents"][0]["n_pairs"] == 5
