"""Planning benchmark on maps built in the simulator: goal-vector RRT* vs uniform RRT* vs OMPL
RRTstar vs the exact shortest path, all judged by the same collision checker.

For each layout, the oracle drives the first ``--drives`` episodes of the episode set while the
robot's own depth camera (320x240, the ``simn`` agent's perception: back-projection, floor /
obstacle labels from the floor plane) fills a :class:`CollisionChecker`, posed with the true pose
(the benchmark is about planning, not tracking). Queries are then sampled in the explored part
of that map; the exact reference is the visibility-graph shortest path
(:class:`FreeSpace2D`) around the checker's occupied cells. Timing helpers and the table come
from ``bench_planning_synthetic.py``.

The first-solution run of every planner is repeated ``--repeats`` times with the same seed (same
iterations for ours) and its median time is kept: the machine is shared, and single timings
jump by several milliseconds when another process takes the core.

Also timed per query: the closed-loop agent's call (``RRTStarConfig(time_budget_ms=0,
max_iterations=600)``, shortcut on, seed = query index), ms per plan. ``--open-rays`` adds
``goal_vector_open``, the checker-aware sampler (``GoalVectorConfig(open_rays=True)``), run
interleaved with the others on the same queries. ``--maps-cache F.pkl`` keeps the built maps
for dev runs.

Usage: python scripts/bench_planning.py [--layouts -1 1 2 3] [--queries 15] [--repeats 3]
    [--open-rays] [--maps-cache F.pkl] [--out F.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import pickle
import platform
import sys
import time
import types
from pathlib import Path

import gymnasium as gym
import numpy as np

import simn_sim  # noqa: F401
from simn_sim.agents import make_agent
from simn_sim.agents.simn import label_points_world, strided
from simn_sim.env.episodes import EpisodeSet
from simn_sim.geometry.camera import backproject
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.geometry.se3 import transform_points
from simn_sim.paths import envs_dir
from simn_sim.planning import CollisionChecker, CollisionConfig, GoalVectorConfig, RRTStarConfig

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("bps", HERE / "bench_planning_synthetic.py")
bps = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bps)


def build_map(layout_seed, episodes, drives: int, max_steps: int = 400) -> CollisionChecker:
    env = gym.make(
        "SimnOffice-v0", config={"width": 320, "height": 240, "layout_seed": layout_seed}
    )
    checker = CollisionChecker(CollisionConfig(margin=0.1, z_min=0.06, z_max=1.0))
    for ep in episodes[:drives]:
        obs, info = env.reset(options={"episode": ep.to_dict()})
        agent = make_agent("oracle", env.unwrapped)
        agent.reset(obs, info)
        intr = info["camera"].intrinsics
        for _ in range(max_steps):
            d, si = strided(obs["depth"], intr, 4)
            P = backproject(np.where(d <= 5.0, d, 0.0), si).reshape(-1, 3)
            P = P[P[:, 2] > 0].astype(np.float64)
            Pw = transform_points(info["T_world_cam"], P)
            checker.update(Pw, label_points_world(Pw, 0.06, 1.0))
            obs, _, term, trunc, info = env.step(agent.act(obs, info))
            if term or trunc:
                break
    env.close()
    return checker


def _json_cfg(cfg) -> dict:
    """Config as a dict with infinite floats as the string "inf" (strict JSON)."""
    return {
        k: ("inf" if isinstance(v, float) and math.isinf(v) else v)
        for k, v in cfg.to_dict().items()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episode-file", default=str(envs_dir() / "episodes" / "office_nav_v1.json"))
    ap.add_argument("--layouts", type=int, nargs="+", default=[-1, 1, 2, 3])
    ap.add_argument("--drives", type=int, default=3)
    ap.add_argument("--queries", type=int, default=15, help="queries per layout")
    ap.add_argument("--dmin", type=float, default=3.0)
    ap.add_argument("--dmax", type=float, default=9.0)
    ap.add_argument("--budget-ms", type=float, default=200.0)
    ap.add_argument("--first-timeout-ms", type=float, default=1000.0)
    ap.add_argument(
        "--repeats", type=int, default=3, help="first-solution runs per query (median time)"
    )
    ap.add_argument("--no-ompl", action="store_true")
    ap.add_argument(
        "--open-rays",
        action="store_true",
        help="also run goal_vector_open: the checker-aware sampler (GoalVectorConfig.open_rays)",
    )
    ap.add_argument(
        "--maps-cache",
        default=None,
        help="pickle of the built maps: loaded if it exists, else written (dev runs)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    args.first_only = False
    load0 = os.getloadavg()
    eps = EpisodeSet.load(args.episode_file).episodes
    gvs = ["goal_vector"] + (["goal_vector_open"] if args.open_rays else [])
    names = gvs + ["uniform"] + ([] if args.no_ompl else ["ompl"])
    ompl_cls = None
    if not args.no_ompl:
        from simn_sim.planning.ompl_rrtstar import OmplRRTStar, OmplRRTStarConfig

        ompl_cls = (OmplRRTStarConfig(), OmplRRTStar)
    base = RRTStarConfig()
    gv = {"goal_vector": GoalVectorConfig(), "goal_vector_open": GoalVectorConfig(open_rays=True)}
    rows = []
    closed_loop = {n: [] for n in gvs}
    rng = np.random.default_rng(args.seed)
    cache = {}
    if args.maps_cache and Path(args.maps_cache).exists():
        cache = pickle.loads(Path(args.maps_cache).read_bytes())
    for lay in args.layouts:
        seed_l = None if lay < 0 else lay
        lay_eps = [e for e in eps if e.layout_seed == seed_l]
        if not lay_eps:
            raise SystemExit(f"no episodes of layout {seed_l} in {args.episode_file}")
        if (seed_l, args.drives) not in cache:
            cache[(seed_l, args.drives)] = build_map(seed_l, lay_eps, args.drives)
        checker = cache[(seed_l, args.drives)]
        fs = FreeSpace2D(checker.obstacle_polygons(), robot_radius=checker.cfg.inflation)
        b = checker.obstacle_bounds()
        m = types.SimpleNamespace(bounds=(b[0], b[1], b[2], b[3]))
        qs = bps.make_queries(checker, fs, m, rng, args.queries, args.dmin, args.dmax)
        print(f"layout {seed_l}: map {b}, {checker.n_points} points, {len(qs)} queries")
        for qi, (s, g, exact, _) in enumerate(qs):
            row = {"layout": seed_l, "exact": exact}
            for name in names:
                cfg1 = base.replace(
                    stop_at_first_solution=True,
                    shortcut=False,
                    time_budget_ms=args.first_timeout_ms,
                    max_iterations=10**7,
                )
                times = []
                for _ in range(max(1, args.repeats)):
                    p, _ = bps.run_planner(name, checker, m, cfg1, gv, ompl_cls, qi, s, g)
                    st = getattr(p, "stats", None)
                    if st is None or st.first_solution_time_s is None:
                        times = []
                        break
                    times.append(st.first_solution_time_s * 1e3)
                t1 = float(np.median(times)) if times else None
                it1 = getattr(st, "first_solution_iteration", None) if times else None
                cfg2 = base.replace(time_budget_ms=args.budget_ms, max_iterations=10**7)
                p2, path = bps.run_planner(name, checker, m, cfg2, gv, ompl_cls, qi, s, g)
                ok = path is not None and checker.path_free(path)
                L = float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if ok else None
                if name in gvs:
                    # the closed-loop agent's call: 600 iterations, no time budget, shortcut on
                    cfg3 = base.replace(time_budget_ms=0, max_iterations=600)
                    t0 = time.perf_counter()
                    p3, path3 = bps.run_planner(name, checker, m, cfg3, gv, ompl_cls, qi, s, g)
                    closed_loop[name].append(
                        dict(ms=(time.perf_counter() - t0) * 1e3, ok=path3 is not None)
                    )
                row[name] = dict(
                    first_ok=t1 is not None,
                    first_ms=t1,
                    first_iter=it1,
                    first_ms_repeats=times,
                    budget_ok=ok,
                    raw_ratio=L / exact if ok else None,
                    smooth_ratio=L / exact if ok else None,
                )
            rows.append(row)
    if args.maps_cache and not Path(args.maps_cache).exists():
        Path(args.maps_cache).write_bytes(pickle.dumps(cache))
    summ = bps.summarise(rows, names, args.budget_ms)
    it_r = [
        r["uniform"]["first_iter"] / max(r["goal_vector"]["first_iter"], 1)
        for r in rows
        if r["uniform"]["first_ok"] and r["goal_vector"]["first_ok"]
    ]
    if it_r:
        speed_it = dict(median=float(np.median(it_r)), geomean=float(np.exp(np.mean(np.log(it_r)))))
    else:
        speed_it = {}
    speed, speed_it, loop = {}, {}, {}
    for n in gvs:
        speed[n] = bps.paired_speedup(rows, n, "uniform")
        it_r = [
            r["uniform"]["first_iter"] / max(r[n]["first_iter"], 1)
            for r in rows
            if r["uniform"]["first_ok"] and r[n]["first_ok"]
        ]
        if it_r:
            speed_it[n] = dict(
                median=float(np.median(it_r)), geomean=float(np.exp(np.mean(np.log(it_r))))
            )
        cl = closed_loop[n]
        loop[n] = dict(
            ms_per_plan_mean=float(np.mean([c["ms"] for c in cl])),
            ms_per_plan_median=float(np.median([c["ms"] for c in cl])),
            reached_goal=int(sum(c["ok"] for c in cl)),
            plans=len(cl),
        )
    out = {
        "machine": f"{platform.machine()} {os.cpu_count()} cpus, {platform.platform()}",
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "command": "python " + " ".join(sys.argv),
        "load_average_at_start": load0,
        "load_average_at_end": os.getloadavg(),
        "goal_vector_config": _json_cfg(gv["goal_vector"]),
        "queries": len(rows),
        "summary": summ,
        "goal_vector_speedup_vs_uniform": speed["goal_vector"],
        "goal_vector_iteration_ratio_vs_uniform": speed_it.get("goal_vector", {}),
        "closed_loop_600_iterations": loop["goal_vector"],
        **(
            {
                "goal_vector_open_config": _json_cfg(gv["goal_vector_open"]),
                "goal_vector_open_speedup_vs_uniform": speed["goal_vector_open"],
                "goal_vector_open_iteration_ratio_vs_uniform": speed_it.get("goal_vector_open", {}),
                "goal_vector_open_closed_loop_600_iterations": loop["goal_vector_open"],
            }
            if args.open_rays
            else {}
        ),
        "exact_length_median_m": float(np.median([r["exact"] for r in rows])),
    }
    print(json.dumps(out, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps({**out, "rows": rows}, indent=1, default=float))


if __name__ == "__main__":
    main()
