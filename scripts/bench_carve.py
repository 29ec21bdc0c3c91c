"""Cost of free-space carving against the number of local frames it reaches.

Carving (``slam.stores.carve``) removes stored obstacle points that the current depth image
sees through. ``stores.carve_frames`` bounds the frames it looks at (the 2 most recent, or 0:
every frame). This script drives the ``simn_points`` agent for ``--steps`` steps of one
``office_nav_v2`` episode (realistic sensing), so the local frames hold real obstacle stores,
then times ``LocalFrames.carve`` of the last view against the stores of every frame so far,
for ``carve_frames`` 2 and 0, each on a fresh copy of the stores. Reported: ms per call
(median of ``--repeats``), the ratio of 0 to 2, the frames and points reached, and how many
frames the bounding-sphere test skipped (frames too deep for the view or behind it).

    MUJOCO_GL=egl .venv/bin/python scripts/bench_carve.py --steps 600 --out F.json
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import simn_sim  # noqa: E402,F401
from simn_sim.agents import make_agent  # noqa: E402
from simn_sim.env.episodes import EpisodeSet  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary
from simn_sim.paths import envs_dir  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episode", default="nav2-ref-004")
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    es = EpisodeSet.load(envs_dir() / "episodes" / "office_nav_v2.json")
    ep = {e.episode_id: e for e in es.episodes}[args.episode]
    env = gym.make(es.env_id, config={"width": 320, "height": 240})
    d = ep.to_dict()
    obs, info = env.reset(seed=int(d.get("seed", 0)), options={"episode": d})
    # carving off while driving: every store keeps what it saw, the worst case for the timing
    agent = make_agent("simn_points", env.unwrapped, {"slam": {"stores": {"carve": False}}})
    agent.reset(obs, info)
    for _ in range(args.steps):
        obs, _, term, trunc, info = env.step(agent.act(obs))
        if term or trunc:
            break
    world = agent.world
    frame = world.slam.perception(obs["rgb"], obs["depth"])
    T_wc = world.pose @ world.T_base_cam
    base = world.frames
    out: dict = {
        "episode": args.episode,
        "steps": args.steps,
        "frames": len(base),
        "obstacle_points": int(sum(len(s.obstacles) for s in base.states.values())),
        "machine": machine_summary(),
    }
    for n in (2, 0):
        ms, removed = [], None
        for _ in range(args.repeats):
            frames = copy.deepcopy(base)
            frames.cfg = frames.cfg.replace(
                stores=frames.cfg.stores.replace(carve=True, carve_frames=n)
            )
            t = time.perf_counter()
            r = frames.carve(frame, T_wc)
            ms.append((time.perf_counter() - t) * 1e3)
            removed = r if removed is None else removed
            assert r == removed, "carving is deterministic"
        out[f"carve_frames_{n}"] = {"ms_median": float(np.median(ms)), "removed": removed}
    # the frames the bounding-sphere test lets through, for carve_frames 0
    Tcw = np.linalg.inv(T_wc)
    zmax = float(frame.depth.max())
    reached = sum(
        not base.beyond_view(fid, Tcw @ base.topo.anchor(fid), zmax)
        for fid, st in base.states.items()
        if len(st.obstacles)
    )
    out["frames_tested_point_by_point"] = reached
    out["ratio_all_to_2"] = out["carve_frames_0"]["ms_median"] / out["carve_frames_2"]["ms_median"]
    env.close()
    print(json.dumps(out, indent=1))
    if args.out:
        args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
