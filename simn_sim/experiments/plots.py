"""PNG plots of a batch folder (matplotlib, Agg backend: headless).

* :func:`plot_trajectories`: one figure per layout (``trajectories_ref.png`` for the reference
  office, ``trajectories_L<seed>.png`` for a generated one): the true floor plan
  (``layout.footprints((0.03, 0.95))``, grey), and per episode the driven path
  (``trajectories/<agent>/<episode_id>.npy``), start (circle) and goal (star); one colour per
  agent, a failed or errored episode dashed.
* :func:`plot_success_spl`: success rate and SPL per agent as bars with 95 % CI error bars.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from simn_sim.experiments.batch_files import (
    EPISODE_SET_FILE,
    RECORDS_FILE,
    read_records_lenient,
    trajectory_file,
)

__all__ = ["layout_tag", "plot_success_spl", "plot_trajectories"]

#: Floor-plan band: everything between 3 cm and 95 cm above the floor blocks the robot.
FLOORPLAN_Z_BAND = (0.03, 0.95)
#: At most this many episodes per agent are drawn in one trajectory figure.
MAX_EPISODES_PER_PLOT = 60


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def layout_tag(layout_seed: int | None) -> str:
    """``ref`` for the reference office, ``L<seed>`` for a generated layout."""
    return "ref" if layout_seed is None else f"L{int(layout_seed)}"


def plot_trajectories(
    out: str | Path, records: Sequence[dict[str, Any]] | None = None
) -> list[Path]:
    """Write ``trajectories_<layout>.png`` for every layout in the batch folder ``out``.

    ``records`` default to ``out/episodes.jsonl``; goals come from ``out/episode_set.json``.
    Returns the written files.
    """
    from simn_sim.env.office import load_layout

    plt = _plt()
    out = Path(out)
    if records is None:
        records, _ = read_records_lenient(out / RECORDS_FILE)
    specs: dict[str, dict[str, Any]] = {}
    set_file = out / EPISODE_SET_FILE
    if set_file.is_file():
        specs = {e["episode_id"]: e for e in json.loads(set_file.read_text())["episodes"]}
    agents = list(dict.fromkeys(str(r["agent"]) for r in records))
    colours = plt.get_cmap("tab10")
    by_layout: dict[int | None, list[dict[str, Any]]] = {}
    for r in records:
        lay = specs.get(r["episode_id"], {}).get("layout_seed", r.get("layout_seed"))
        by_layout.setdefault(lay, []).append(r)
    written: list[Path] = []
    for lay, recs in sorted(by_layout.items(), key=lambda kv: (kv[0] is not None, kv[0] or 0)):
        layout = load_layout(lay)
        x0, y0, x1, y1 = layout.bounds
        aspect = (y1 - y0) / max(x1 - x0, 1e-6)
        fig, ax = plt.subplots(figsize=(10, max(4.0, 10 * aspect + 1.0)))
        for poly in layout.footprints(FLOORPLAN_Z_BAND):
            p = np.asarray(poly)
            ax.fill(p[:, 0], p[:, 1], color="0.55", lw=0)
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="0.3", lw=0.8)
        drawn: dict[str, int] = {}
        for r in recs:
            agent = str(r["agent"])
            if drawn.get(agent, 0) >= MAX_EPISODES_PER_PLOT:
                continue
            c = colours(agents.index(agent) % 10)
            f = trajectory_file(out, agent, str(r["episode_id"]))
            spec = specs.get(r["episode_id"])
            ok = bool(r.get("success")) and r.get("error") is None
            label = agent if agent not in drawn else None
            if f.is_file():
                xy = np.load(f)
                if len(xy):
                    ax.plot(
                        xy[:, 0],
                        xy[:, 1],
                        color=c,
                        lw=1.2,
                        ls="-" if ok else "--",
                        alpha=0.9,
                        label=label,
                    )
                    label = None
            if spec is not None:
                ax.plot(*spec["start"][:2], "o", color=c, ms=5, mfc="white", label=label)
                ax.plot(*spec["goal"], "*", color=c, ms=11, mec="k", mew=0.5)
            drawn[agent] = drawn.get(agent, 0) + 1
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        name = "reference office" if lay is None else f"layout seed {lay}"
        ax.set_title(f"Driven paths, {name} ({len(recs)} episodes; dashed: not successful)")
        if drawn:
            ax.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        path = out / f"trajectories_{layout_tag(lay)}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def plot_success_spl(rows: Sequence[Any], path: str | Path) -> Path:
    """Bar chart of success rate and SPL per agent with CI error bars.

    ``rows``: :class:`~simn_sim.experiments.stats.SummaryRow` objects (others are ignored).
    """
    plt = _plt()
    path = Path(path)
    metrics = ("success", "spl")
    agents = list(dict.fromkeys(r.agent for r in rows))
    cell = {(r.agent, r.metric): r for r in rows if r.metric in metrics}
    fig, ax = plt.subplots(figsize=(max(4.0, 1.6 * len(agents) + 2), 4))
    width = 0.38
    x = np.arange(len(agents))
    for k, m in enumerate(metrics):
        means, lo, hi = [], [], []
        for a in agents:
            r = cell.get((a, m))
            mean = r.mean if r is not None and not math.isnan(r.mean) else 0.0
            means.append(mean)
            have = r is not None and not math.isnan(r.ci_low)
            lo.append(max(0.0, mean - r.ci_low) if have else 0.0)
            hi.append(max(0.0, r.ci_high - mean) if have else 0.0)
        bars = ax.bar(
            x + (k - 0.5) * width,
            means,
            width,
            yerr=[lo, hi],
            capsize=4,
            label={"success": "success rate", "spl": "SPL"}[m],
        )
        for b, v in zip(bars, means, strict=True):
            ax.text(
                b.get_x() + b.get_width() / 2,
                v / 2,
                f"{v:.2f}",
                ha="center",
                va="center",
                fontsize=9,
                color="white",
            )
    ax.set_xticks(
        x,
        [
            f"{a}\n(n={cell[(a, 'success')].n_episodes})" if (a, "success") in cell else a
            for a in agents
        ],
    )
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("mean (95 % CI)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax.set_title("Success and SPL per agent (95 % CI)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
