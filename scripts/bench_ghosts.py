"""Ghosts of moving people in the collision model, with and without free-space carving.

In ``SimnOfficeDynamic-v0`` (4 people walking at 0.8-1.3 m/s) the ``simn`` agent runs seeded
episodes with carving of the local frames' stores (``slam.stores.carve``) off and on. Every 25 steps and at the end, each occupied cell of the
agent's collision model is mapped to the world with the true start pose (measurement only) and
called a *ghost* when it is more than ``--static-margin`` from every true static obstacle and
more than ``--person-margin`` from every person's current position: an obstacle that is no
longer there. Reports ghost area (m^2), success, collisions (with people separately).

Usage: python scripts/bench_ghosts.py [--episodes 4] [--seed 0] [--sensing realistic|ideal]
(``--sensing``: the env's sensing condition, default realistic like the env's.)
"""

from __future__ import annotations

import argparse
import json

import gymnasium as gym
import numpy as np

import simn_sim  # noqa: F401
from simn_sim.agents import make_agent


def ghost_area(env, agent, T_world_start, static_margin: float, person_margin: float) -> float:
    u = env.unwrapped
    c = agent.obstacles.planning.occupied_centres()
    if len(c) == 0:
        return 0.0
    w = c @ T_world_start[:2, :2].T + T_world_start[:2, 3]
    far_static = u.free_space.clearance(w) > static_margin
    people = u._people.pos
    if len(people):
        d = np.min(
            np.hypot(w[:, None, 0] - people[None, :, 0], w[:, None, 1] - people[None, :, 1]), axis=1
        )
        far_people = d > person_margin
    else:
        far_people = np.ones(len(w), bool)
    res = agent.obstacles.planning.cfg.resolution
    return float(np.count_nonzero(far_static & far_people)) * res * res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--static-margin", type=float, default=0.3)
    ap.add_argument("--person-margin", type=float, default=0.6)
    ap.add_argument("--sensing", choices=["realistic", "ideal"], default="realistic")
    a = ap.parse_args()
    env = gym.make(
        "SimnOfficeDynamic-v0", config={"width": 320, "height": 240, "sensing": a.sensing}
    )
    out = {}
    for carve in (False, True):
        rows = []
        for i in range(a.episodes):
            obs, info = env.reset(seed=a.seed + i)
            T_ws = info["T_world_base"].copy()
            agent = make_agent("simn", env.unwrapped, {"slam": {"stores": {"carve": carve}}})
            agent.reset(obs, info)
            areas = []
            step = 0
            while True:
                obs, _, term, trunc, info = env.step(agent.act(obs, info))
                step += 1
                if step % 25 == 0:
                    areas.append(ghost_area(env, agent, T_ws, a.static_margin, a.person_margin))
                if term or trunc:
                    break
            ep = info["episode"]
            rows.append(
                dict(
                    seed=a.seed + i,
                    success=ep["success"],
                    steps=ep["steps"],
                    collisions=ep["collisions"],
                    collisions_with_people=ep["collisions_with_people"],
                    ghost_m2_final=ghost_area(env, agent, T_ws, a.static_margin, a.person_margin),
                    ghost_m2_mean=float(np.mean(areas)) if areas else 0.0,
                    carved_points=agent.counters()["carved_points"],
                )
            )
            print(json.dumps({"carve": carve, **rows[-1]}))
        out[f"carve={carve}"] = {
            k: float(np.mean([r[k] for r in rows]))
            for k in (
                "success",
                "collisions",
                "collisions_with_people",
                "ghost_m2_final",
                "ghost_m2_mean",
            )
        }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
