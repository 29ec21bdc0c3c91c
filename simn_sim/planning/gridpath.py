"""Fallback planner: Dijkstra on an 8-connected grid of the collision model, then shortcuts.

Used by the navigation agents only when RRT* finds no path within its iteration budget (a long
detour around a mapped wall, say); it is complete on the grid within the window (unknown space
is free, as everywhere), so the agent does not spin in place while a path exists. The caller
counts how often it is used.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.smoothing import shortcut_path


def grid_shortest_path(
    checker: CollisionChecker,
    start: np.ndarray,
    goal: np.ndarray,
    rng: np.random.Generator,
    resolution: float = 0.1,
    pad: float = 4.0,
) -> np.ndarray | None:
    """(M, 2) path from ``start`` to ``goal`` free under ``checker``, or None.

    The grid spans the box of start, goal and the mapped obstacles, padded by ``pad`` metres.
    Start and goal must be free; their grid cells connect to them by straight free segments.
    """
    start = np.asarray(start, float)
    goal = np.asarray(goal, float)
    lo = np.minimum(start, goal) - pad
    hi = np.maximum(start, goal) + pad
    b = checker.obstacle_bounds()
    if b is not None:
        lo = np.minimum(lo, np.array(b[:2]) - 1.0)
        hi = np.maximum(hi, np.array(b[2:]) + 1.0)
    nx = int(np.ceil((hi[0] - lo[0]) / resolution)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / resolution)) + 1
    xs = lo[0] + resolution * np.arange(nx)
    ys = lo[1] + resolution * np.arange(ny)
    X, Y = np.meshgrid(xs, ys)  # (ny, nx)
    centres = np.c_[X.ravel(), Y.ravel()]
    free = checker.is_free(centres).reshape(ny, nx)
    idx = np.arange(nx * ny).reshape(ny, nx)
    rows, cols, w = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ys, yt = slice(0, ny - dy), slice(dy, ny)
        xs, xt = (
            (slice(0, nx - dx), slice(dx, nx)) if dx >= 0 else (slice(-dx, nx), slice(0, nx + dx))
        )
        ok = free[ys, xs] & free[yt, xt]
        rows.append(idx[ys, xs][ok])
        cols.append(idx[yt, xt][ok])
        w.append(np.full(int(ok.sum()), np.hypot(dx, dy) * resolution))
    r = np.concatenate(rows)
    c_ = np.concatenate(cols)
    ww = np.concatenate(w)
    G = coo_matrix((ww, (r, c_)), shape=(nx * ny, nx * ny)).tocsr()

    def snap(p: np.ndarray) -> int | None:
        d = np.hypot(centres[:, 0] - p[0], centres[:, 1] - p[1])
        d[~free.ravel()] = np.inf
        for k in np.argsort(d)[:16]:
            if np.isfinite(d[k]) and checker.segment_free(p, centres[k]):
                return int(k)
        return None

    s, g = snap(start), snap(goal)
    if s is None or g is None:
        return None
    dist, pred = dijkstra(G, directed=False, indices=s, return_predecessors=True)
    if not np.isfinite(dist[g]):
        return None
    cells = [g]
    while cells[-1] != s:
        cells.append(int(pred[cells[-1]]))
    path = np.vstack([start, centres[cells[::-1]], goal])
    return shortcut_path(path, checker, rng, iterations=30)
