"""How well a single depth frame gives the heading: the Manhattan-frame yaw of its vertical
surfaces (``simn_sim.perception.manhattan``) against the truth, along oracle-driven episodes.

The office's walls are axis-aligned in the world, so through the *true* camera rotation every
frame's wall direction is 0 modulo 90 deg and the estimate's deviation from 0 is its error (the
heading error it would report on a drifted estimate). Every ``--every``-th step of each episode
is measured, for each sensing condition in the same run; reported per support threshold: frames
with an estimate, median / p90 / max absolute error, share within 0.5 deg.

    MUJOCO_GL=egl .venv/bin/python scripts/bench_manhattan_heading.py \\
        --episodes nav2-ref-004 nav2-L4-008 --out runs/manhattan.json
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import simn_sim  # noqa: E402,F401
from simn_sim.agents import make_agent  # noqa: E402
from simn_sim.env.episode_sets import EpisodeSet  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary  # noqa: E402
from simn_sim.experiments.runner import write_json  # noqa: E402
from simn_sim.paths import envs_dir  # noqa: E402
from simn_sim.perception.manhattan import frame_normals, manhattan_yaw  # noqa: E402

SUPPORTS = (0.0, 0.2, 0.3)


def measure(ep, sensing: str, stride: int, max_depth: float, every: int, size) -> list[dict]:
    """Per measured step: the estimate (None where too few vertical normals) and its support."""
    env = gym.make(
        "SimnOffice-v0", config={"width": size[0], "height": size[1], "sensing": sensing}
    )
    out = []
    try:
        obs, info = env.reset(seed=ep.seed, options={"episode": ep.to_dict()})
        intr = info["camera"].intrinsics
        agent = make_agent("oracle", env.unwrapped, {})
        agent.reset(obs, info)
        step = 0
        while True:
            if step % every == 0:
                n = frame_normals(obs["depth"], intr, stride=stride, max_depth=max_depth)
                m = manhattan_yaw(n @ info["T_world_cam"][:3, :3].T)
                out.append(
                    {
                        "step": step,
                        "yaw_err_deg": None if m is None else m.yaw_deg,
                        "support": 0.0 if m is None else m.support,
                    }
                )
            obs, _, term, trunc, info = env.step(agent.act(obs, info))
            step += 1
            if term or trunc:
                break
    finally:
        env.close()
    return out


def summarise(rows: list[dict]) -> dict:
    est = [r for r in rows if r["yaw_err_deg"] is not None]
    out = {"frames": len(rows), "with_estimate": len(est)}
    for s in SUPPORTS:
        e = np.abs([r["yaw_err_deg"] for r in est if r["support"] >= s])
        out[f"support>={s}"] = (
            {
                "n": int(e.size),
                "median": float(np.median(e)),
                "p90": float(np.percentile(e, 90)),
                "max": float(e.max()),
                "share_below_0.5deg": float(np.mean(e < 0.5)),
            }
            if e.size
            else {"n": 0}
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episode-file", type=Path, default=envs_dir() / "episodes/office_nav_v2.json")
    ap.add_argument("--episodes", nargs="+", required=True, help="episode ids")
    ap.add_argument("--sensing", nargs="+", default=["ideal", "realistic"])
    ap.add_argument("--stride", type=int, default=8)
    ap.add_argument("--max-depth", type=float, default=3.0)
    ap.add_argument("--every", type=int, default=5)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.every < 1:
        ap.error("--every must be >= 1")
    by_id = {e.episode_id: e for e in EpisodeSet.load(a.episode_file).episodes}
    unknown = [i for i in a.episodes if i not in by_id]
    if unknown:
        ap.error(f"unknown episode ids: {unknown}")
    doc = {
        "machine": machine_summary(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "episodes": a.episodes,
        "stride": a.stride,
        "max_depth": a.max_depth,
        "every": a.every,
        "size": [a.width, a.height],
        "results": {},
    }
    for sensing in a.sensing:
        rows = []
        for eid in a.episodes:
            rows += measure(
                by_id[eid], sensing, a.stride, a.max_depth, a.every, (a.width, a.height)
            )
        res = summarise(rows)
        doc["results"][sensing] = res
        print(f"{sensing}: {res['with_estimate']} of {res['frames']} frames with an estimate")
        for s in SUPPORTS:
            r = res[f"support>={s}"]
            if r["n"]:
                print(
                    f"  support >= {s}: n {r['n']}, |error| median {r['median']:.2f} p90 "
                    f"{r['p90']:.2f} max {r['max']:.2f} deg, within 0.5 deg "
                    f"{100 * r['share_below_0.5deg']:.0f} %"
                )
    if a.out:
        write_json(a.out, doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
