"""Path post-processing with the collision checker (planning frame x-y): shortcutting, and
pushing a path away from obstacles where there is room (:func:`push_from_obstacles`)."""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.paths import path_length, segment_lengths
from simn_sim.planning.collision import CollisionChecker

__all__ = [
    "densify",
    "greedy_shortcut",
    "path_length",
    "push_from_obstacles",
    "random_shortcut",
    "shortcut_path",
]


def greedy_shortcut(path: np.ndarray, checker: CollisionChecker) -> np.ndarray:
    """From each kept vertex jump to the furthest later vertex that is visible (one vectorised
    visibility check per kept vertex). Returns an (K, 2) sub-polyline, K <= M, never longer."""
    p = np.asarray(path, dtype=np.float64).reshape(-1, 2)
    if len(p) <= 2:
        return p.copy()
    keep = [0]
    i = 0
    last = len(p) - 1
    while i < last:
        js = np.arange(i + 1, last + 1)
        free = checker.segments_free(np.repeat(p[i][None], len(js), axis=0), p[js])
        # furthest visible vertex; the next vertex is always reachable along the path itself
        ok = js[free]
        j = int(ok.max()) if len(ok) else i + 1
        keep.append(j)
        i = j
    return p[keep]


def random_shortcut(
    path: np.ndarray,
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 50,
) -> np.ndarray:
    """Random shortcutting between points anywhere on the polyline (not just vertices), which
    also cuts corners between vertices. Each accepted shortcut strictly shortens the path."""
    p = np.asarray(path, dtype=np.float64).reshape(-1, 2).copy()
    for _ in range(iterations):
        if len(p) < 3:
            break
        seg = segment_lengths(p)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        total = cum[-1]
        if total <= 0:
            break
        s0, s1 = np.sort(rng.uniform(0.0, total, size=2))
        i0 = int(np.searchsorted(cum, s0, side="right") - 1)
        i1 = int(np.searchsorted(cum, s1, side="right") - 1)
        i0, i1 = min(i0, len(seg) - 1), min(i1, len(seg) - 1)
        if i1 <= i0:
            continue
        q0 = p[i0] + (p[i0 + 1] - p[i0]) * ((s0 - cum[i0]) / max(seg[i0], 1e-12))
        q1 = p[i1] + (p[i1 + 1] - p[i1]) * ((s1 - cum[i1]) / max(seg[i1], 1e-12))
        if np.hypot(*(q1 - q0)) >= s1 - s0 - 1e-9:
            continue
        if checker.segment_free(q0, q1):
            p = np.concatenate([p[: i0 + 1], q0[None], q1[None], p[i1 + 1 :]])
    # drop duplicate consecutive points
    keep = np.concatenate([[True], segment_lengths(p) > 1e-9])
    return p[keep]


def shortcut_path(
    path: np.ndarray,
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 50,
) -> np.ndarray:
    """Greedy vertex shortcut, then random shortcuts, then greedy again. (M, 2) -> (K, 2)."""
    p = greedy_shortcut(path, checker)
    if iterations > 0:
        p = random_shortcut(p, checker, rng, iterations)
        p = greedy_shortcut(p, checker)
    return p


def densify(path: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline with extra vertices so that no segment is longer than ``spacing``."""
    p = np.asarray(path, dtype=np.float64).reshape(-1, 2)
    out = [p[0]]
    for a, b in zip(p[:-1], p[1:], strict=True):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / spacing)))
        t = np.arange(1, n + 1)[:, None] / n
        out.extend(a + t * (b - a))
    return np.asarray(out)


def push_from_obstacles(
    path: np.ndarray,
    checker: CollisionChecker,
    target_clearance: float,
    spacing: float = 0.1,
    step: float = 0.03,
    iterations: int = 15,
    also_from: CollisionChecker | None = None,
) -> np.ndarray:
    """Move the path's interior vertices away from the nearest obstacle until their clearance
    reaches ``target_clearance`` (m, distance to the nearest obstacle cell) or they stop being
    able to move (an elastic-band-style repair of shortcut paths, which hug the inflated
    obstacles at their corners). The path is densified to ``spacing`` first; endpoints stay.
    Each iteration moves a vertex by at most ``step`` along the direction from its nearest
    obstacle; a move is kept only where the two segments at the vertex stay free, so the result
    is free wherever the input was (segments that were not free are left to the caller). A narrow passage keeps the path at its centre line (the
    push from both sides balances), so nothing becomes impassable.

    ``also_from``: a second obstacle model the vertices are pushed away from as well (the
    nearer of the two obstacles counts), while freeness is judged by ``checker`` alone: space
    that may be occupied (occlusion shadows) is avoided where there is room, never required."""
    p = densify(path, spacing)
    if len(p) < 3 or target_clearance <= 0:
        return p
    was_free = checker.segments_free(p[:-1], p[1:])  # a move may not block a free segment
    for _ in range(iterations):
        q = p[1:-1]
        c = checker.clearance(q)
        o = checker.nearest_obstacle(q)
        if also_from is not None:
            c2 = also_from.clearance(q)
            nearer = c2 < c
            if nearer.any():
                c = np.where(nearer, c2, c)
                o[nearer] = also_from.nearest_obstacle(q[nearer])
        need = c < target_clearance
        if not need.any():
            break
        d = q - o
        n = np.hypot(d[:, 0], d[:, 1])
        ok = need & np.isfinite(n) & (n > 1e-9)
        if not ok.any():
            break
        move = np.zeros_like(q)
        amount = np.minimum(step, target_clearance - c)
        move[ok] = d[ok] / n[ok, None] * amount[ok, None]
        cand = p.copy()
        cand[1:-1] = q + move
        # keep a vertex's move only if both of its segments stay free
        seg_free = checker.segments_free(cand[:-1], cand[1:])
        keep = seg_free[:-1] & seg_free[1:] & checker.is_free(cand[1:-1])
        if not keep.any():
            break
        trial = p.copy()
        trial[1:-1][keep] = cand[1:-1][keep]
        # a kept vertex next to a reverted one can still block a segment that was free:
        # revert the vertices of such segments until none is left (each round reverts at
        # least one moved vertex, so this ends)
        bad = was_free & ~checker.segments_free(trial[:-1], trial[1:])
        while bad.any():
            idx = np.unique(np.concatenate([np.flatnonzero(bad), np.flatnonzero(bad) + 1]))
            idx = idx[(idx > 0) & (idx < len(p) - 1)]
            idx = idx[np.any(trial[idx] != p[idx], axis=1)]
            if len(idx) == 0:
                break
            trial[idx] = p[idx]
            bad = was_free & ~checker.segments_free(trial[:-1], trial[1:])
        if bad.any() or np.array_equal(trial, p):
            break
        p = trial
    return p
