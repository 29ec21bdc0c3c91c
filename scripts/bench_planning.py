"""Planning benchmark on maps built in the simulator: goal-vector RRT* vs uniform RRT* vs OMPL
RRTstar vs the exact shortest path, all judged by the same collision checker.

For each layout, the oracle drives the first ``--drives`` episodes of the episode set while the
robot's own depth camera (320x240, ideal sensing, every 4th pixel back-projected, floor / obstacle
labels from the height above the floor) fills a :class:`CollisionChecker`, posed with the true pose
(the benchmark is about planning, not tracking). Queries are then sampled in the explored part
of that map; the exact reference is the visibility-graph shortest path
(:class:`FreeSpace2D`) around the checker's occupied cells.

Protocol (``bench_planning_synthetic.run_query``, the same for every planner): same queries
(start, goal), same collision checker (OMPL's validity and motion checks call it), same step /
range 0.5 m and goal bias 0.05, seed ``1000 * layout index + query index + 1`` for ours (OMPL's
RNG is process-global and takes only the first seed, see ``OmplRRTStar``).

- First solution: ``stop_at_first_solution``, no smoothing, at most ``--first-timeout-ms``,
  ``--repeats`` runs per query and the median time (the machine is shared and single timings jump
  by milliseconds; ours repeat the same draw, OMPL's repeats are new draws).
- Fixed budget: ``--budget-ms`` wall clock for every planner, no iteration cap. Lengths are
  compared raw vs raw (tree paths), own smoother vs own smoother (our shortcut smoothing vs
  OMPL's ``PathSimplifier.simplifyMax``) and through one common smoother (our shortcut on every
  raw path).
- Times are reported as the ratio of mean first-solution times (speedup = mean other / mean
  goal-vector, the paper-style statistic) beside the paired median of the per-query ratios, on
  the queries both solved; success counts of each planner on all queries.

Also timed per query: the closed-loop agent's call (``RRTStarConfig(time_budget_ms=0,
max_iterations=600)``, shortcut on), ms per plan. ``--open-rays`` adds ``goal_vector_open``, the
checker-aware sampler (``GoalVectorConfig(open_rays=True)``), run interleaved with the others on
the same queries. ``--maps-cache F.pkl`` keeps the built maps for dev runs.

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
from simn_sim.env.episodes import EpisodeSet
from simn_sim.experiments.batch_files import machine_summary
from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.geometry.se3 import transform_points
from simn_sim.paths import envs_dir
from simn_sim.planning import CollisionChecker, CollisionConfig, GoalVectorConfig, RRTStarConfig
from simn_sim.semantics import FLOOR, OBSTACLE

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("bps", HERE / "bench_planning_synthetic.py")
bps = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bps)


def strided(depth: np.ndarray, intr: Intrinsics, stride: int) -> tuple[np.ndarray, Intrinsics]:
    """Every ``stride``-th pixel of ``depth`` and the intrinsics of that sub-image."""
    d = depth[::stride, ::stride]
    return d, Intrinsics(
        d.shape[1],
        d.shape[0],
        intr.fx / stride,
        intr.fy / stride,
        intr.cx / stride,
        intr.cy / stride,
    )


def label_points_world(points_world: np.ndarray, floor_tol: float, robot_height: float):
    """Floor (|z| < floor_tol) / obstacle (floor_tol <= z <= robot_height) / unknown labels of
    (N, 3) world points (true pose, floor at z = 0)."""
    z = points_world[:, 2]
    lab = np.zeros(len(z), np.int8)
    lab[np.abs(z) < floor_tol] = FLOOR
    lab[(z >= floor_tol) & (z <= robot_height)] = OBSTACLE
    return lab


def build_map(layout_seed, episodes, drives: int, max_steps: int = 400) -> CollisionChecker:
    env = gym.make(
        "SimnOffice-v0",
        # ideal sensing: exact depth and actuation (the map is built at the true pose; the
        # benchmark is about planning, and noise would make the maps depend on the env's draws)
        config={"width": 320, "height": 240, "layout_seed": layout_seed, "sensing": "ideal"},
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
    load0 = os.getloadavg()
    eps = EpisodeSet.load(args.episode_file).episodes
    gvs = ["goal_vector"] + (["goal_vector_open"] if args.open_rays else [])
    names = gvs + ["uniform"] + ([] if args.no_ompl else ["ompl"])
    base = RRTStarConfig()
    ompl_cls = None
    if not args.no_ompl:
        from simn_sim.planning.ompl_rrtstar import OmplRRTStar, OmplRRTStarConfig

        # same range and goal bias as ours; OMPL's own simplifier on the budget runs
        ompl_cls = (
            OmplRRTStarConfig(range=base.step_size, goal_bias=base.goal_bias, simplify=True),
            OmplRRTStar,
        )
    gv = {"goal_vector": GoalVectorConfig(), "goal_vector_open": GoalVectorConfig(open_rays=True)}
    rows = []
    closed_loop = {n: [] for n in gvs}
    rng = np.random.default_rng(args.seed)
    cache = {}
    if args.maps_cache and Path(args.maps_cache).exists():
        cache = pickle.loads(Path(args.maps_cache).read_bytes())
    for li, lay in enumerate(args.layouts):
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
        print(f"layout {seed_l}: map {b}, {checker.n_points} points, {len(qs)} queries", flush=True)
        for qi, (s, g, exact, visible) in enumerate(qs):
            seed = 1000 * li + qi + 1  # OMPL rejects seed 0
            row = dict(
                layout=seed_l,
                start=s.tolist(),
                goal=g.tolist(),
                exact=exact,
                line_of_sight=visible,
                seed=seed,
            )
            row.update(
                bps.run_query(
                    checker,
                    m,
                    s,
                    g,
                    exact,
                    seed,
                    names,
                    base,
                    gv,
                    ompl_cls,
                    first_timeout_ms=args.first_timeout_ms,
                    budget_ms=args.budget_ms,
                    repeats=args.repeats,
                )
            )
            for name in gvs:
                # the closed-loop agent's call: 600 iterations, no time budget, shortcut on
                cfg3 = base.replace(time_budget_ms=0, max_iterations=600)
                t0 = time.perf_counter()
                _, path3 = bps.run_planner(name, checker, m, cfg3, gv, ompl_cls, seed, s, g)
                closed_loop[name].append(
                    dict(ms=(time.perf_counter() - t0) * 1e3, ok=path3 is not None)
                )
            rows.append(row)
    if args.maps_cache and not Path(args.maps_cache).exists():
        Path(args.maps_cache).write_bytes(pickle.dumps(cache))
    summ = bps.summarise(rows, names, args.budget_ms)
    versus, iter_ratio, loop = {}, {}, {}
    for n in gvs:
        for other in [o for o in names if o not in gvs]:
            versus[f"{n}_vs_{other}"] = bps.compare(rows, n, other)
            it_r = [
                r[other]["first_iter"] / max(r[n]["first_iter"], 1)
                for r in rows
                if r[other]["first_ok"] and r[n]["first_ok"]
            ]
            if it_r:
                iter_ratio[f"{other} / {n}"] = dict(
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
        "machine": f"{machine_summary()}, {platform.platform()}",
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "command": "python " + " ".join(sys.argv),
        "load_average_at_start": load0,
        "load_average_at_end": os.getloadavg(),
        "protocol": dict(
            first_solution=f"stop at the first solution, no smoothing, timeout "
            f"{args.first_timeout_ms:g} ms, median of {args.repeats} runs",
            budget=f"{args.budget_ms:g} ms wall clock for every planner, no iteration cap",
            lengths="raw vs raw; own smoother (ours: shortcut, OMPL: PathSimplifier.simplifyMax); "
            "common smoother (our shortcut on every raw path)",
            time_statistic="ratio_of_means = mean t_other / mean t_ours (speedup of ours); "
            "median = paired median of t_other / t_ours; on queries both solved",
            seeds="ours: 1000 * layout index + query index + 1; OMPL: process-global RNG, "
            "seeded once with the first query's seed",
            collision=checker.cfg.to_dict(),
            rrt=_json_cfg(base),
            ompl=ompl_cls[0].to_dict() if ompl_cls else None,
        ),
        "goal_vector_config": _json_cfg(gv["goal_vector"]),
        "queries": len(rows),
        "summary": summ,
        "comparisons": versus,
        "first_iteration_ratio": iter_ratio,
        "closed_loop_600_iterations": loop,
        "exact_length_median_m": float(np.median([r["exact"] for r in rows])),
    }
    print(json.dumps(out, indent=1))
    print()
    print(bps.table(summ, names, args.budget_ms))
    for k, v in versus.items():
        a_, b_ = k.split("_vs_")
        print()
        print(bps.describe(v, a_, b_))
    print(json.dumps(out, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps({**out, "rows": rows}, indent=1, default=float))


if __name__ == "__main__":
    main()
