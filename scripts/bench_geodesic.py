"""Benchmark FreeSpace2D on a synthetic office (~150 rectangles incl. walls with doorways).

Usage: python scripts/bench_geodesic.py [--seed 0] [--queries 20] [--steps 500]

Prints: graph size and build time, single start-goal query time (fresh goal: goal field
+ one query), and per-step GoalField.distance query times. Targets: build < 3 s, single query
< 50 ms, per-step query typically < 2 ms.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from simn_sim.geometry.freespace import FreeSpace2D


def rect(cx: float, cy: float, w: float, h: float, yaw: float = 0.0) -> np.ndarray:
    """(4, 2) corners of a w x h rectangle centred at (cx, cy), rotated by yaw (rad)."""
    half = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2.0
    c, s = math.cos(yaw), math.sin(yaw)
    return half @ np.array([[c, s], [-s, c]]) + np.array([cx, cy])


def wall_with_doors(
    a: tuple[float, float], b: tuple[float, float], doors: list[tuple[float, float]], t: float
) -> list[np.ndarray]:
    """Axis-aligned wall from a to b, thickness t, with doorways (centre offset, width)."""
    ax, ay = a
    bx, by = b
    length = math.hypot(bx - ax, by - ay)
    ux, uy = (bx - ax) / length, (by - ay) / length
    cuts = sorted((c - w / 2, c + w / 2) for c, w in doors)
    pieces, s0 = [], 0.0
    for lo, hi in [*cuts, (length, length)]:
        if lo - s0 > 1e-6:
            m = (s0 + lo) / 2
            cx, cy = ax + ux * m, ay + uy * m
            if abs(ux) > 0.5:
                pieces.append(rect(cx, cy, lo - s0, t))
            else:
                pieces.append(rect(cx, cy, t, lo - s0))
        s0 = hi
    return pieces


def synthetic_office(
    rng: np.random.Generator, size: tuple[float, float] = (26.0, 16.0), n_furniture: int = 130
) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """Office: outer walls, two partition walls with doorways, random furniture.

    Returns:
        footprints (list of (4, 2) arrays, world x-y metres) and bounds (xmin, ymin, xmax, ymax).
    """
    sx, sy = size
    t = 0.15
    obs = [
        rect(sx / 2, 0, sx, t),
        rect(sx / 2, sy, sx, t),
        rect(0, sy / 2, t, sy),
        rect(sx, sy / 2, t, sy),
    ]
    walls = []
    walls += wall_with_doors((9.0, 0.0), (9.0, sy), [(3.0, 1.0), (12.0, 1.2)], t)
    walls += wall_with_doors((17.0, 0.0), (17.0, sy), [(5.0, 1.0), (13.5, 0.9)], t)
    walls += wall_with_doors((0.0, 8.0), (9.0, 8.0), [(4.5, 1.0)], t)
    walls += wall_with_doors((17.0, 8.0), (sx, 8.0), [(2.0, 1.0), (6.5, 1.0)], t)
    obs += walls
    door_zones = [
        (9.0, 3.0),
        (9.0, 12.0),
        (17.0, 5.0),
        (17.0, 13.5),
        (4.5, 8.0),
        (19.0, 8.0),
        (23.5, 8.0),
    ]
    kinds = [("desk", 1.6, 0.8), ("chair", 0.5, 0.5), ("shelf", 0.4, 1.2), ("box", 0.6, 0.4)]
    placed = 0
    while placed < n_furniture:
        kind, w, h = kinds[int(rng.integers(len(kinds)))]
        cx, cy = rng.uniform(0.6, sx - 0.6), rng.uniform(0.6, sy - 0.6)
        if min(math.hypot(cx - dx, cy - dy) for dx, dy in door_zones) < 1.8:
            continue
        yaw = float(rng.uniform(0, math.pi)) if kind in ("chair", "box") else 0.0
        if kind == "desk" and rng.random() < 0.3:  # a table: four legs instead of a top
            for lx, ly in [(-1, -1), (1, -1), (1, 1), (-1, 1)]:
                obs.append(rect(cx + lx * (w / 2 - 0.05), cy + ly * (h / 2 - 0.05), 0.06, 0.06))
            placed += 4
            continue
        obs.append(rect(cx, cy, w, h, yaw))
        placed += 1
    return obs, (0.0, 0.0, sx, sy)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--queries", type=int, default=20)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--radius", type=float, default=0.25)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    obs, bounds = synthetic_office(rng)

    t0 = time.perf_counter()
    fs = FreeSpace2D(obs, args.radius, bounds=bounds)
    build = time.perf_counter() - t0
    print(f"office: {len(obs)} rectangles, bounds {bounds}, robot radius {args.radius} m")
    print(
        f"graph: {fs.n_corners} corner circles, {fs.n_bitangent_candidates} tangent candidates, "
        f"{fs.n_bitangents} visible bitangents, {fs.n_nodes} nodes"
    )
    print(f"build: {build * 1e3:.0f} ms")

    pts = fs.sample_free(rng, 2 * args.queries)
    times, dists, eucl = [], [], []
    for k in range(args.queries):
        s, g = pts[2 * k], pts[2 * k + 1]
        fs._field_cache.clear()
        t0 = time.perf_counter()
        d = fs.geodesic_distance(s, g)
        times.append(time.perf_counter() - t0)
        dists.append(d)
        eucl.append(float(np.linalg.norm(s - g)))
    times_ms = np.array(times) * 1e3
    fin = np.isfinite(dists)
    print(
        f"single query (fresh goal field + query), {args.queries} pairs: "
        f"median {np.median(times_ms):.1f} ms, max {times_ms.max():.1f} ms; "
        f"{fin.sum()} reachable, geodesic/euclidean median "
        f"{np.median(np.array(dists)[fin] / np.array(eucl)[fin]):.3f}"
    )

    goal = pts[1]
    t0 = time.perf_counter()
    field = fs.distance_field_to(goal)
    print(
        f"goal field: {field.n_nodes} nodes, {field.n_edges} edges, "
        f"built in {(time.perf_counter() - t0) * 1e3:.1f} ms"
    )
    # Per-step queries along a random-walk-like trajectory and at random free points.
    qs = fs.sample_free(rng, args.steps)
    step_t, step_cpu = [], []
    for q in qs:
        t0, c0 = time.perf_counter(), time.thread_time()
        field.distance(q)
        step_t.append(time.perf_counter() - t0)
        step_cpu.append(time.thread_time() - c0)
    st = np.array(step_t) * 1e3
    sc = np.array(step_cpu) * 1e3
    print(
        f"per-step GoalField.distance, {args.steps} random free points: wall median {np.median(st):.2f} ms, "
        f"p95 {np.percentile(st, 95):.2f} ms, max {st.max():.2f} ms; thread CPU median "
        f"{np.median(sc):.2f} ms, p95 {np.percentile(sc, 95):.2f} ms, max {sc.max():.2f} ms"
    )
    path = fs.shortest_path(pts[0], goal)
    t0 = time.perf_counter()
    n_path = 0
    if path is not None:
        # Dense per-step positions along the optimal path (what a robot would visit).
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        s_along = np.linspace(0, seg.sum(), 200)
        cum = np.concatenate([[0], np.cumsum(seg)])
        xs = np.interp(s_along, cum, path[:, 0])
        ys = np.interp(s_along, cum, path[:, 1])
        on_path = np.stack([xs, ys], 1)
        free = fs.is_free(on_path)
        tt = []
        for q in on_path[free]:
            t1 = time.perf_counter()
            field.distance(q)
            tt.append(time.perf_counter() - t1)
        n_path = len(tt)
        tt_ms = np.array(tt) * 1e3
        print(
            f"per-step GoalField.distance, {n_path} points along a shortest path: "
            f"median {np.median(tt_ms):.2f} ms, p95 {np.percentile(tt_ms, 95):.2f} ms"
        )


if __name__ == "__main__":
    main()
