"""Benchmark: goal-vector RRT* vs uniform RRT* vs OMPL RRTstar vs the exact shortest path.

Synthetic office-like point maps (rooms off a corridor, doorways, furniture; seeded), one
collision checker per map shared by every planner. For each query (start/goal free, straight-line
distance in [--dmin, --dmax], exact geodesic finite):

- first solution: each planner runs with ``stop_at_first_solution`` up to --first-timeout-ms;
  time to first solution and success;
- fixed budget: each planner runs for --budget-ms; path length relative to the exact geodesic
  (``simn_sim.geometry.freespace.FreeSpace2D`` on the true footprints, robot radius = inflation)
  raw (tree path), after each planner's own smoother (ours: shortcut; OMPL: its
  PathSimplifier.simplifyMax), and after one common smoother (our shortcut on every raw path).

The protocol is :func:`run_query` (shared with ``bench_planning.py``). Times: the ratio of mean
first-solution times (speedup = mean other / mean goal_vector) beside the paired median of the
per-query ratios. OMPL's RNG is process-global and seeded once (``OmplRRTStar``), ours per query.

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


def run_query(
    c,
    m,
    start,
    goal,
    exact,
    seed,
    names,
    base,
    gv_cfg,
    ompl_cls,
    *,
    first_timeout_ms: float,
    budget_ms: float,
    repeats: int = 1,
    first_only: bool = False,
) -> dict[str, dict[str, Any]]:
    """One query, every planner in ``names``, one protocol for all of them (the benchmarks' core).

    - **First solution:** ``stop_at_first_solution``, no smoothing, at most ``first_timeout_ms``,
      ``repeats`` runs with the same seed; ``first_ms`` is the median of the runs, ``first_ok``
      means every run found a path. Ours repeat the same draw (seeded per query); OMPL's RNG is
      process-global and seeded once, so its repeats are different draws.
    - **Fixed budget:** the same ``budget_ms`` wall-clock budget for every planner (no iteration
      cap); ours shortcut-smooths its path (``base.shortcut``), OMPL runs its own
      ``PathSimplifier.simplifyMax`` (``OmplRRTStarConfig.simplify``). Lengths: ``raw_len``
      (tree path), ``smooth_len`` (each planner's own smoother), ``common_len`` (the raw path
      through our ``shortcut_path`` with the query's seed: one smoother for all), each also as
      a ratio to ``exact``. Every path is judged by the same checker; a path that is not free
      counts as a failure.
    """
    cfg1 = base.replace(
        stop_at_first_solution=True,
        shortcut=False,
        time_budget_ms=first_timeout_ms,
        max_iterations=10**7,
    )
    cfg2 = base.replace(time_budget_ms=budget_ms, max_iterations=10**7)
    row: dict[str, dict[str, Any]] = {}
    for name in names:
        times, iters = [], []
        for _ in range(max(1, repeats)):
            p, _ = run_planner(name, c, m, cfg1, gv_cfg, ompl_cls, seed, start, goal)
            st = p.stats
            if st.first_solution_time_s is not None:
                times.append(st.first_solution_time_s * 1e3)
                iters.append(st.first_solution_iteration)
        ok1 = len(times) == max(1, repeats)
        r: dict[str, Any] = dict(
            first_ok=ok1,
            first_ms=float(np.median(times)) if ok1 else None,
            first_iter=float(np.median(iters)) if ok1 else None,
            first_ms_repeats=times,
            first_iter_repeats=iters,
        )
        raw = path = None
        p2 = None
        if not first_only:
            p2, path = run_planner(name, c, m, cfg2, gv_cfg, ompl_cls, seed, start, goal)
            raw = p2.raw_path
        ok_raw = raw is not None and bool(c.path_free(raw))
        ok = path is not None and bool(c.path_free(path))
        common, common_ms = None, None
        if ok_raw:
            t0 = time.perf_counter()
            common = shortcut_path(raw, c, np.random.default_rng(seed), base.shortcut_iterations)
            common_ms = (time.perf_counter() - t0) * 1e3
        raw_len = path_length(raw) if ok_raw else None
        smooth_len = path_length(path) if ok else None
        common_len = path_length(common) if ok_raw else None
        simp = getattr(p2, "simplify_time_s", None)
        r.update(
            budget_ok=ok,
            iterations=p2.stats.iterations if p2 is not None else None,
            raw_len=raw_len,
            smooth_len=smooth_len,
            common_len=common_len,
            raw_ratio=raw_len / exact if ok_raw else None,
            smooth_ratio=smooth_len / exact if ok else None,
            common_ratio=common_len / exact if ok_raw else None,
            own_simplifier_ms=simp * 1e3 if simp is not None else None,
            common_smoother_ms=common_ms,
        )
        row[name] = r
    return row


def table(summ, names, budget_ms) -> str:
    """Markdown table of :func:`summarise` (lengths are medians of length / exact)."""
    lines = [
        "| planner | first-solution success | first solution ms, median (mean) "
        f"| iterations, median | success @{budget_ms:.0f} ms | length / exact: raw "
        "| own smoother | common smoother |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n in names:
        s_ = summ[n]
        lines.append(
            f"| {n} | {s_['first_solved']}/{s_['n']} | {s_['first_ms_median']:.2f} "
            f"({s_['first_ms_mean']:.2f}) | {s_['first_iter_median']:.0f} | "
            f"{s_['budget_solved']}/{s_['n']} | {s_['raw_ratio_median']:.3f} | "
            f"{s_['smooth_ratio_median']:.3f} | {s_['common_ratio_median']:.3f} |"
        )
    return "\n".join(lines)


def describe(cmp, a, b) -> str:
    """One paragraph for :func:`compare`."""
    t = cmp["first_solution_time"]
    out = [
        f"{a} vs {b}, {cmp['queries']} queries: first solution {cmp['first_solved'][a]} vs "
        f"{cmp['first_solved'][b]}, within the budget {cmp['budget_solved'][a]} vs "
        f"{cmp['budget_solved'][b]}."
    ]
    if t:
        out.append(
            f"First-solution time over the {t['n']} queries both solved: mean {t['mean_ms'][0]:.2f} "
            f"vs {t['mean_ms'][1]:.2f} ms, speedup (mean {b} / mean {a}) "
            f"{t['ratio_of_means']:.2f}x (every repeat: {t['ratio_of_means_all_repeats']:.2f}x); "
            f"paired median of t_{b} / t_{a} {t['median']:.2f}x, geomean {t['geomean']:.2f}x."
        )
    lr = cmp["length_ratio"]
    out.append(
        f"Length {a} / {b}, median (mean) over queries both solved: raw vs raw "
        f"{lr['raw']['median']:.3f} ({lr['raw']['mean']:.3f}, n={lr['raw']['n']}); own smoother "
        f"vs own smoother {lr['smooth']['median']:.3f} ({lr['smooth']['mean']:.3f}); common "
        f"smoother {lr['common']['median']:.3f} ({lr['common']['mean']:.3f})."
    )
    return " ".join(out)


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


def _median(v):
    return float(np.median(v)) if len(v) else math.nan


def summarise(rows, names, budget_ms):
    """Per planner: successes (counts and fractions), first-solution time and iterations,
    length / exact medians (raw, own smoother, common smoother)."""
    out = {}
    for name in names:
        r = [x[name] for x in rows]
        ok = np.array([x["first_ok"] for x in r])
        t = np.array([x["first_ms"] if x["first_ok"] else np.nan for x in r])
        okb = np.array([x["budget_ok"] for x in r])
        lr = [x["raw_ratio"] for x in r if x.get("raw_ratio") is not None]
        ls = [x["smooth_ratio"] for x in r if x.get("smooth_ratio") is not None]
        lc = [x["common_ratio"] for x in r if x.get("common_ratio") is not None]
        its = [x["first_iter"] for x in r if x["first_ok"] and x["first_iter"] is not None]
        simp = [x["own_simplifier_ms"] for x in r if x.get("own_simplifier_ms") is not None]
        out[name] = dict(
            n=len(r),
            first_solved=int(ok.sum()),
            first_success=float(ok.mean()),
            first_iter_median=_median(its),
            first_ms_median=float(np.nanmedian(t)) if ok.any() else math.nan,
            first_ms_mean=float(np.nanmean(t)) if ok.any() else math.nan,
            budget_ms=budget_ms,
            budget_solved=int(okb.sum()),
            budget_success=float(okb.mean()),
            raw_ratio_median=_median(lr),
            smooth_ratio_median=_median(ls),
            smooth_ratio_p90=float(np.percentile(ls, 90)) if len(ls) else math.nan,
            common_ratio_median=_median(lc),
            own_simplifier_ms_mean=float(np.mean(simp)) if simp else None,
        )
    return out


def paired_speedup(rows, a, b):
    """Time to first solution of ``b`` over ``a`` on the queries both solved (every repeat):
    ``ratio_of_means`` = mean t_b / mean t_a (the paper-style statistic: the speedup of ``a``
    when above 1), ``median`` and ``geomean`` of the per-query ratios t_b / t_a,
    ``ratio_of_medians``, and ``ratio_of_means_all_repeats`` (every run's time, not the
    per-query median)."""
    ta, tb, ra, rb = [], [], [], []
    for x in rows:
        if x[a]["first_ok"] and x[b]["first_ok"]:
            ta.append(x[a]["first_ms"])
            tb.append(x[b]["first_ms"])
            ra.extend(x[a].get("first_ms_repeats") or [x[a]["first_ms"]])
            rb.extend(x[b].get("first_ms_repeats") or [x[b]["first_ms"]])
    if not ta:
        return {}
    ta, tb = np.array(ta), np.array(tb)
    r = tb / np.maximum(ta, 1e-3)
    return dict(
        n=len(r),
        mean_ms=[float(ta.mean()), float(tb.mean())],
        ratio_of_means=float(tb.mean() / ta.mean()),
        median=float(np.median(r)),
        geomean=float(np.exp(np.mean(np.log(r)))),
        ratio_of_medians=float(np.median(tb) / np.median(ta)),
        ratio_of_means_all_repeats=float(np.mean(rb) / np.mean(ra)),
    )


def paired_lengths(rows, a, b):
    """Path length of ``a`` over ``b`` on the queries both solved within the budget, per pair
    of like paths: raw vs raw, own smoother vs own smoother (ours: shortcut; OMPL:
    PathSimplifier), common smoother vs common smoother. Median and mean of the per-query
    ratios, and the query count."""
    out = {}
    for key in ("raw_len", "smooth_len", "common_len"):
        q = [
            x[a][key] / x[b][key]
            for x in rows
            if x[a].get(key) is not None and x[b].get(key) is not None and x[b][key] > 0
        ]
        out[key.removesuffix("_len")] = dict(
            n=len(q),
            median=_median(q),
            mean=float(np.mean(q)) if q else math.nan,
        )
    return out


def compare(rows, a, b):
    """``a`` (ours) against ``b`` on the same queries: success counts, first-solution time
    (:func:`paired_speedup`, speedup of ``a`` = mean t_b / mean t_a) and lengths
    (:func:`paired_lengths`, a / b)."""
    return dict(
        queries=len(rows),
        first_solved={
            a: int(sum(x[a]["first_ok"] for x in rows)),
            b: int(sum(x[b]["first_ok"] for x in rows)),
        },
        budget_solved={
            a: int(sum(x[a]["budget_ok"] for x in rows)),
            b: int(sum(x[b]["budget_ok"] for x in rows)),
        },
        first_solution_time=paired_speedup(rows, a, b),
        length_ratio=paired_lengths(rows, a, b),
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
        "--repeats", type=int, default=1, help="first-solution runs per query (median time)"
    )
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
                row.update(
                    run_query(
                        c,
                        m,
                        s,
                        g,
                        exact,
                        seed,
                        names,
                        base,
                        gv_cfg,
                        ompl_cls,
                        first_timeout_ms=args.first_timeout_ms,
                        budget_ms=args.budget_ms,
                        repeats=args.repeats,
                        first_only=args.first_only,
                    )
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
        print(table(summ, names_here, args.budget_ms))
        for n, sp in speed.items():
            if sp:
                label = n if "/" in n else f"{n} / goal_vector"
                print(
                    f"first-solution time {label} over {sp['n']} queries solved by "
                    f"both: ratio of means {sp['ratio_of_means']:.2f}x, paired median "
                    f"{sp['median']:.2f}x, geomean {sp['geomean']:.2f}x"
                )
    all_rows = [r for v in results["sizes"].values() for r in v["rows"]]
    pooled = summarise(all_rows, names, args.budget_ms)
    results["pooled"] = dict(
        summary=pooled,
        speedup_vs_goal_vector={
            n: paired_speedup(all_rows, "goal_vector", n) for n in names if n != "goal_vector"
        },
    )
    if "ompl_rrtstar" in names:
        results["pooled"]["goal_vector_vs_ompl"] = compare(all_rows, "goal_vector", "ompl_rrtstar")
    print(f"\n## all maps pooled ({len(all_rows)} queries)")
    print(table(pooled, names, args.budget_ms))
    for n, sp in results["pooled"]["speedup_vs_goal_vector"].items():
        if sp:
            print(
                f"first-solution time {n} / goal_vector over {sp['n']} queries: ratio of means "
                f"{sp['ratio_of_means']:.2f}x, paired median {sp['median']:.2f}x, geomean "
                f"{sp['geomean']:.2f}x"
            )
    if "goal_vector_vs_ompl" in results["pooled"]:
        print(describe(results["pooled"]["goal_vector_vs_ompl"], "goal_vector", "ompl_rrtstar"))
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
