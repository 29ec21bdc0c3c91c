"""Transient cells in a closed-loop episode: how many height slabs appear and expire.

Drives the default ``simn`` agent with ``obstacles.transient.keep_views`` set, realistic
sensing, and prints every ``--every`` steps the appear events so far (slabs that received
obstacle points after they and their neighbours were seen free), the slabs appeared now and
those of them expired (left out of the planning models); ``grown``: the appear events by blob
growth (``transient.grow_share``), and the mean time of ``TransientCells.observe`` per view.
In a static office (office_nav_v2)
every appear event is a false one: nothing moves there.

    OMP_NUM_THREADS=1 MUJOCO_GL=egl .venv/bin/python scripts/bench_transient.py \\
        --episode-file envs/episodes/office_nav_v2.json --episode nav2-ref-004 --steps 175
"""

from __future__ import annotations

import argparse
import json
import time

import gymnasium as gym
import numpy as np

import simn_sim  # noqa: F401
from simn_sim.agents import make_agent
from simn_sim.env.episodes import EpisodeSet


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episode-file", required=True)
    ap.add_argument("--episode", required=True, help="episode_id")
    ap.add_argument("--steps", type=int, default=175)
    ap.add_argument("--keep-views", type=int, default=30)
    ap.add_argument("--every", type=int, default=25)
    ap.add_argument(
        "--grow-share",
        type=float,
        default=None,
        help="transient.grow_share (default: the config's)",
    )
    ap.add_argument(
        "--point-share",
        type=float,
        default=None,
        help="transient.point_share (default: the config's; 0: the slab rule alone)",
    )
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    a = ap.parse_args()
    if a.keep_views < 1 or a.steps < 1 or a.every < 1:
        ap.error("--keep-views, --steps and --every must be >= 1")
    es = EpisodeSet.load(a.episode_file)
    eps = {e.episode_id: e for e in es.episodes}
    if a.episode not in eps:
        ap.error(f"episode {a.episode!r} is not in {a.episode_file}")
    ep = eps[a.episode]
    env = gym.make(es.env_id, config={"width": a.width, "height": a.height})
    obs, info = env.reset(seed=ep.seed, options={"episode": ep})
    tr = {"keep_views": a.keep_views}
    if a.grow_share is not None:
        tr["grow_share"] = a.grow_share
    if a.point_share is not None:
        tr["point_share"] = a.point_share
    cfg = {"obstacles": {"transient": tr}}
    agent = make_agent("simn", env.unwrapped, cfg)
    agent.reset(obs, info)
    tc = agent.world.obstacles.transient
    observe, spent = tc.observe, []

    def timed(*args, **kw):
        t0 = time.perf_counter()
        observe(*args, **kw)
        spent.append(time.perf_counter() - t0)

    tc.observe = timed
    for k in range(1, a.steps + 1):
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        if k % a.every == 0 or term or trunc or k == a.steps:
            appeared, expired = tc.counts()
            row = {
                "step": k,
                "appear_events": tc.n_appeared,
                "grown": tc.n_grown,
                "appeared_now": appeared,
                "expired_now": expired,
                "observe_ms_mean": round(1e3 * float(np.mean(spent)), 2),
            }
            print(json.dumps(row), flush=True)
        if term or trunc:
            break
    agent.close()
    env.close()


if __name__ == "__main__":
    main()
