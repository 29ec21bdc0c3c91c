"""Benchmark: goal-vector RRT* vs uniform RRT* vs OMPL RRTstar vs the exact shortest path.

Synthetic office-like point maps (rooms off a corridor, doorways, furniture; seeded), one
collision checker per map shared by every planner. For each query (start/goal free, straight-line
distance in [--dmin, --dmax], exact geodesic finite):

- first solution: each planner runs with ``stop_at_first_solution`` up to --first-timeout-ms;
  time to first solution and success;
- fixed budget: each planner runs for --budget-ms; path length (raw tree path, and after
  shortcutting for ours / OMPL's PathSimplifier) relative to the exact geodesic
  (``simn_sim.geometry.freespace.FreeSpace2D`` on the true footprints, robot radius = inflation).

Usage:
    python scripts/bench_planning_synthetic.py --sizes 3x2,8x2 --maps 3 --queries 10 \
        --out results/bench_planning.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from typing import Any

import numpy as np

from simn_sim.planning import (
    CollisionChecker,
    CollisionConfig,
    GoalVectorConfig,
    RRTStarConfig,
    goal_vector_rrt_star,
    uniform_rrt_star,
)
from simn_sim.planning.smoothing import path_length, shortcut_path
from simn_sim.planning.synthetic_maps import office_map, open_office_map
from simn_sim.planning.topo import route_subgoal


def parse_kv(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for it in items:
        k, v = it.split("=", 1)
        out[k] = json.loads(v)
    return out


def make_queries(c, fs, m, rng, n, dmin, dmax, max_tries=20000):
    qs = []
    for _ in range(max_tries):
        if len(qs) >= n:
            break
        a = rng.uniform(m.bounds[:2], m.bounds[2:], size=(2, 2))
        d = float(np.hypot(*(a[1] - a[0])))
        if not (dmin <= d <= dmax) or not c.is_free(a).all():
            continue
        exact = math.nan
        if fs is not None:
            exact = fs.geodesic_distance(a[0], a[1])
            if not math.isfinite(exact):
                continue
        qs.append((a[0], a[1], exact, bool(c.segment_free(a[0], a[1]))))
    return qs


def run_planner(name, c, m, cfg, gv_cfg, ompl_cls, seed, start, goal):
    if name.startswith("goal_vector"):
        p = goal_vector_rrt_star(
            c, cfg, gv_cfg[name], bounds=m.bounds, rng=np.random.default_rng(seed)
        )
    elif name == "uniform":
        p = uniform_rrt_star(c, m.bounds, cfg, rng=np.random.default_rng(seed))
    else:
        ocfg, cls = ompl_cls
        p = cls(
            c,
            m.bounds,
            ocfg.replace(
                time_budget_ms=cfg.time_budget_ms, stop_at_first_solution=cfg.stop_at_first_solution
            ),
            seed=seed,
        )
    path = p.plan(start, goal)
    return p, path


def run_route(c, m, base, gv_cfg, seed, start, goal, exact, args):
    """SIMN pipeline on an office map: route_subgoal over the map's topological graph gives the
    legs (start -> next node anchor -> ... -> goal); each leg is planned by goal-vector RRT*.
    First solution = sum of the legs' first-solution times; the budget run gives each leg an
    equal share of --budget-ms and shortcuts the joined path."""
    legs = [np.asarray(start, float)]
    cur, gnode = m.node_at(start), m.node_at(goal)
    t0 = time.perf_counter()
    for _ in range(50):
        sg = route_subgoal(m.graph, cur, goal, frame_radius=1.0, goal_node=gnode)
        legs.append(sg.xy)
        if sg.next_node is None:
            break
        cur = sg.next_node
    route_ms = (time.perf_counter() - t0) * 1e3  # counted in the first-solution time
    n_legs = len(legs) - 1
    first_ms, ok, iters = route_ms, True, 0
    cfg1 = base.replace(
        stop_at_first_solution=True,
        shortcut=False,
        time_budget_ms=args.first_timeout_ms,
        max_iterations=10**7,
    )
    cfg2 = base.replace(time_budget_ms=args.budget_ms / n_legs, max_iterations=10**7)
    joined = [legs[0][None]]
    raw_len = 0.0
    okb = True
    for k in range(n_legs):
        p = goal_vector_rrt_star(
            c, cfg1, gv_cfg, bounds=m.bounds, rng=np.random.default_rng([seed, k])
        )
        p.plan(legs[k], legs[k + 1])
        if p.stats.first_solution_time_s is None:
            ok = False
        else:
            first_ms += p.stats.first_solution_time_s * 1e3
        if not args.first_only:
            p2 = goal_vector_rrt_star(
                c, cfg2, gv_cfg, bounds=m.bounds, rng=np.random.default_rng([seed, k])
            )
            path = p2.plan(legs[k], legs[k + 1])
            iters += p2.stats.iterations
            if path is None:
                okb = False
            else:
                joined.append(path[1:])
                raw_len += p2.stats.cost
    okb = okb and not args.first_only
    smooth = None
    if okb:
        full = shortcut_path(np.concatenate(joined), c, np.random.default_rng(seed), 50)
        assert c.path_free(full)
        smooth = path_length(full)
    return dict(
        first_ok=ok,
        first_ms=first_ms if ok else None,
        first_iter=None,
        budget_ok=okb,
        raw_len=raw_len if okb else None,
        smooth_len=smooth,
        raw_ratio=raw_len / exact if okb else None,
        smooth_ratio=smooth / exact if okb else None,
        iterations=iters,
        legs=n_legs,
    )


def summarise(rows, names, budget_ms):
    out = {}
    for name in names:
        r = [x[name] for x in rows]
        ok = np.array([x["first_ok"] for x in r])
        t = np.array([x["first_ms"] if x["first_ok"] else np.nan for x in r])
        okb = np.array([x["budget_ok"] for x in r])
        lr = np.array([x["raw_ratio"] for x in r if x["budget_ok"]])
        ls = np.array([x["smooth_ratio"] for x in r if x["budget_ok"]])
        its = [x["first_iter"] for x in r if x["first_ok"] and x["first_iter"] is not None]
        out[name] = dict(
            n=len(r),
            first_iter_median=float(np.median(its)) if its else math.nan,
            first_success=float(ok.mean()),
            first_ms_median=float(np.nanmedian(t)) if ok.any() else math.nan,
            first_ms_mean=float(np.nanmean(t)) if ok.any() else math.nan,
            budget_success=float(okb.mean()),
            raw_ratio_median=float(np.median(lr)) if len(lr) else math.nan,
            smooth_ratio_median=float(np.median(ls)) if len(ls) else math.nan,
            smooth_ratio_p90=float(np.percentile(ls, 90)) if len(ls) else math.nan,
        )
    return out


def paired_speedup(rows, a, b):
    """Median and geometric mean over queries both solved of t_b / t_a, and of the means."""
    ta, tb = [], []
    for x in rows:
        if x[a]["first_ok"] and x[b]["first_ok"]:
            ta.append(x[a]["first_ms"])
            tb.append(x[b]["first_ms"])
    if not ta:
        return {}
    ta, tb = np.array(ta), np.array(tb)
    r = tb / np.maximum(ta, 1e-3)
    return dict(
        n=len(r),
        median=float(np.median(r)),
        geomean=float(np.exp(np.mean(np.log(r)))),
        ratio_of_means=float(tb.mean() / ta.mean()),
        ratio_of_medians=float(np.median(tb) / np.median(ta)),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--sizes",
        default="office:3x2,office:8x2,open:30x20",
        help="maps: office:<rooms along x>x<rows> (4 m rooms off a 2 m corridor) or "
        "open:<width>x<height> (open-plan hall, metres)",
    )
    ap.add_argument(
        "--route",
        action="store_true",
        help="office maps: also plan with goal-vector RRT* leg by leg along the "
        "topological route (route_subgoal), the SIMN pipeline",
    )
    ap.add_argument("--maps", type=int, default=3, help="seeded maps per size")
    ap.add_argument("--queries", type=int, default=10, help="queries per map")
    ap.add_argument("--dmin", type=float, default=3.0)
    ap.add_argument("--dmax", type=float, default=8.0)
    ap.add_argument("--budget-ms", type=float, default=200.0)
    ap.add_argument("--first-timeout-ms", type=float, default=1000.0)
    ap.add_argument("--no-ompl", action="store_true")
    ap.add_argument("--first-only", action="store_true", help="skip the fixed-budget runs")
    ap.add_argument(
        "--paper-sampler",
        action="store_true",
        help="also run the paper's sampler (rays from the start only, fixed fan)",
    )
    ap.add_argument("--gv", nargs="*", default=[], help="GoalVectorConfig overrides k=v (JSON)")
    ap.add_argument("--rrt", nargs="*", default=[], help="RRTStarConfig overrides k=v (JSON)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write the JSON results here")
    args = ap.parse_args()

    base = RRTStarConfig.from_dict(parse_kv(args.rrt))
    gv_cfg = {"goal_vector": GoalVectorConfig.from_dict(parse_kv(args.gv))}
    names = ["goal_vector"]
    if args.paper_sampler:
        gv_cfg["goal_vector_paper"] = gv_cfg["goal_vector"].replace(
            tree_anchor_fraction=0.0,
            frontier_anchor_fraction=0.0,
            adaptive_rays=False,
            window_stall=0,  # no stall widening: the paper's fixed fan only
        )
        names.append("goal_vector_paper")
    names.append("uniform")
    ompl_cls = None
    if not args.no_ompl:
        from simn_sim.planning.ompl_rrtstar import OmplRRTStar, OmplRRTStarConfig

        ompl_cls = (
            OmplRRTStarConfig(range=base.step_size, goal_bias=base.goal_bias, simplify=True),
            OmplRRTStar,
        )
        names.append("ompl_rrtstar")
    try:
        from simn_sim.geometry.freespace import FreeSpace2D
    except ImportError:
        FreeSpace2D = None  # noqa: N806
        print("FreeSpace2D not available: no exact reference lengths")

    ccfg = CollisionConfig()
    results: dict[str, Any] = {"sizes": {}}
    for size in args.sizes.split(","):
        kind, dims = size.split(":")
        a_, b_ = (int(v) for v in dims.split("x"))
        rows = []
        map_info = []
        for mi in range(args.maps):
            rng = np.random.default_rng([args.seed, a_, b_, mi, kind == "open"])
            if kind == "office":
                m = office_map(rng, nx=a_, ny=b_)
            else:
                m = open_office_map(rng, width=float(a_), height=float(b_))
            c = CollisionChecker(ccfg)
            t = time.perf_counter()
            c.update(m.points, m.labels)
            t_map = time.perf_counter() - t
            fs = None
            if FreeSpace2D is not None:
                fs = FreeSpace2D(m.footprints, robot_radius=ccfg.inflation, bounds=m.bounds)
            qs = make_queries(c, fs, m, rng, args.queries, args.dmin, args.dmax)
            map_info.append(
                dict(
                    bounds=m.bounds,
                    n_points=len(m.points),
                    checker_build_ms=t_map * 1e3,
                    grid=list(c.shape),
                )
            )
            for qi, (s, g, exact, visible) in enumerate(qs):
                row: dict[str, Any] = dict(
                    start=s.tolist(), goal=g.tolist(), exact=exact, line_of_sight=visible
                )
                seed = 1000 * mi + qi + 1  # OMPL rejects seed 0
                for name in names:
                    cfg1 = base.replace(
                        stop_at_first_solution=True,
                        shortcut=False,
                        time_budget_ms=args.first_timeout_ms,
                        max_iterations=10**7,
                    )
                    p, _ = run_planner(name, c, m, cfg1, gv_cfg, ompl_cls, seed, s, g)
                    st = p.stats
                    ok = st.first_solution_time_s is not None
                    cfg2 = base.replace(time_budget_ms=args.budget_ms, max_iterations=10**7)
                    if args.first_only:
                        p2, path2 = p, None
                    else:
                        p2, path2 = run_planner(name, c, m, cfg2, gv_cfg, ompl_cls, seed, s, g)
                    okb = path2 is not None
                    if okb:
                        assert c.path_free(path2), f"{name} returned a colliding path"
                    row[name] = dict(
                        first_ok=ok,
                        first_ms=st.first_solution_time_s * 1e3 if ok else None,
                        first_iter=st.first_solution_iteration,
                        budget_ok=okb,
                        raw_len=p2.stats.cost if okb else None,
                        smooth_len=path_length(path2) if okb else None,
                        raw_ratio=p2.stats.cost / exact if okb else None,
                        smooth_ratio=path_length(path2) / exact if okb else None,
                        iterations=p2.stats.iterations,
                    )
                if args.route and m.graph is not None:
                    row["goal_vector+route"] = run_route(
                        c, m, base, gv_cfg["goal_vector"], seed, s, g, exact, args
                    )
                rows.append(row)
        names_here = names + (["goal_vector+route"] if "goal_vector+route" in rows[0] else [])
        summ = summarise(rows, names_here, args.budget_ms)
        speed = {
            n: paired_speedup(rows, "goal_vector", n) for n in names_here if n != "goal_vector"
        }
        if "goal_vector+route" in names_here:
            speed["uniform / goal_vector+route"] = paired_speedup(
                rows, "goal_vector+route", "uniform"
            )
        results["sizes"][size] = dict(
            maps=map_info,
            rows=rows,
            summary=summ,
            speedup_vs_goal_vector=speed,
            line_of_sight_fraction=float(np.mean([r["line_of_sight"] for r in rows])),
        )
        b = map_info[0]["bounds"]
        print(
            f"\n## {size} ({b[2] - b[0]:.0f} x {b[3] - b[1]:.0f} m), "
            f"{len(rows)} queries, {args.dmin}-{args.dmax} m, "
            f"line of sight {results['sizes'][size]['line_of_sight_fraction']:.0%}"
        )
        print(
            "| planner | first-solution success | first solution median / mean ms "
            "| median iterations "
            f"| success @{args.budget_ms:.0f} ms | length/exact raw (median) "
            "| smoothed median / p90 |"
        )
        print("|---|---|---|---|---|---|---|")
        for n in names_here:
            s_ = summ[n]
            print(
                f"| {n} | {s_['first_success']:.0%} | {s_['first_ms_median']:.1f} / "
                f"{s_['first_ms_mean']:.1f} | {s_['first_iter_median']:.0f} | "
                f"{s_['budget_success']:.0%} | "
                f"{s_['raw_ratio_median']:.3f} | {s_['smooth_ratio_median']:.3f} / "
                f"{s_['smooth_ratio_p90']:.3f} |"
            )
        for n, sp in speed.items():
            if sp:
                print(
                    f"first-solution time {n} / goal_vector over {sp['n']} queries solved by "
                    f"both: median {sp['median']:.2f}x, geomean {sp['geomean']:.2f}x, "
                    f"ratio of means {sp['ratio_of_means']:.2f}x"
                )
    all_rows = [r for v in results["sizes"].values() for r in v["rows"]]
    pooled = summarise(all_rows, names, args.budget_ms)
    results["pooled"] = dict(
        summary=pooled,
        speedup_vs_goal_vector={
            n: paired_speedup(all_rows, "goal_vector", n) for n in names if n != "goal_vector"
        },
    )
    print(f"\n## all maps pooled ({len(all_rows)} queries)")
    for n in names:
        s_ = pooled[n]
        print(
            f"| {n} | {s_['first_success']:.0%} | {s_['first_ms_median']:.1f} / "
            f"{s_['first_ms_mean']:.1f} | {s_['first_iter_median']:.0f} | "
            f"{s_['budget_success']:.0%} | {s_['raw_ratio_median']:.3f} | "
            f"{s_['smooth_ratio_median']:.3f} / {s_['smooth_ratio_p90']:.3f} |"
        )
    for n, sp in results["pooled"]["speedup_vs_goal_vector"].items():
        if sp:
            print(
                f"first-solution time {n} / goal_vector over {sp['n']} queries: median "
                f"{sp['median']:.2f}x, geomean {sp['geomean']:.2f}x, ratio of means "
                f"{sp['ratio_of_means']:.2f}x"
            )
    results["config"] = dict(
        rrt=base.to_dict(),
        goal_vector=gv_cfg["goal_vector"].to_dict(),
        collision=ccfg.to_dict(),
        args=vars(args),
    )
    results["machine"] = dict(
        platform=platform.platform(),
        processor=platform.processor(),
        cpus=os.cpu_count(),
        python=platform.python_version(),
    )
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(results, f, indent=1, default=float)
        print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
