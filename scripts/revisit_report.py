"""Closed-loop revisit precision and recall pooled over a batch's episodes.

Reads ``episodes.jsonl`` of each batch folder (``simn-sim batch --out DIR``) and prints, per
folder and agent: accepted revisits, correct ones (loop arc within 0.2 m / 5 deg of the true
one) and of those the ones more than 0.05 m off, precision = correct / accepted,
opportunities (frames opened near a frame the check may consider), recall = opportunities
closed by a correct revisit / opportunities, and the median of the episodes' median arc
errors. Definitions: ``simn_sim/eval/revisits.py``.

    .venv/bin/python scripts/revisit_report.py runs/v2_rrtstar [more dirs]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from simn_sim.experiments.stats import load_records


def pooled(records: list[dict]) -> dict:
    """Pooled revisit figures of records that carry the judged fields."""
    rs = [r for r in records if r.get("revisits_correct") is not None]
    acc = sum(int(r.get("revisits") or 0) for r in rs)
    cor = sum(int(r["revisits_correct"]) for r in rs)
    opp = sum(int(r["revisit_opportunities"]) for r in rs)
    closed = sum(int(r["revisit_opportunities_closed"]) for r in rs)
    em = [r["revisit_err_m_median"] for r in rs if r.get("revisit_err_m_median") is not None]
    ed = [r["revisit_err_deg_median"] for r in rs if r.get("revisit_err_deg_median") is not None]
    fine = [r.get("revisits_off_fine") for r in rs]  # None in records before 2026-12-07
    return {
        "episodes": len(rs),
        "accepted": acc,
        "correct": cor,
        "precision": cor / acc if acc else None,
        "off_fine": None if any(v is None for v in fine) else sum(int(v) for v in fine),
        "opportunities": opp,
        "closed": closed,
        "recall": closed / opp if opp else None,
        "err_m_median": float(np.median(em)) if em else None,
        "err_deg_median": float(np.median(ed)) if ed else None,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="batch output folders")
    ap.add_argument("--json", action="store_true", help="print JSON")
    a = ap.parse_args(argv)
    out = {}
    for d in a.dirs:
        recs = load_records(d / "episodes.jsonl")
        for agent in sorted({r["agent"] for r in recs}):
            p = pooled([r for r in recs if r["agent"] == agent])
            if p["episodes"] == 0:
                print(f"{d} {agent}: no judged revisit fields (a run before 3d9d79e?)")
                continue
            out[f"{d}:{agent}"] = p
    if a.json:
        print(json.dumps(out, indent=2))
        return 0
    for k, p in out.items():
        f = lambda v, n=3: "-" if v is None else f"{v:.{n}f}"  # noqa: E731
        print(
            f"{k}: {p['episodes']} episodes, revisits {p['accepted']} accepted, "
            f"{p['correct']} correct (precision {f(p['precision'])}, "
            f"{'-' if p['off_fine'] is None else p['off_fine']} of them over 0.05 m off); "
            "opportunities "
            f"{p['opportunities']}, closed {p['closed']} (recall {f(p['recall'])}); "
            f"arc error median {f(p['err_m_median'])} m / {f(p['err_deg_median'], 2)} deg"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
