"""Exact geodesic distance field to a fixed goal in a :class:`~simn_sim.geometry.freespace.FreeSpace2D`
(Dijkstra once from the goal over the tangent graph; see the model in
:mod:`simn_sim.geometry.freespace`)."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from simn_sim.geometry.footprints import _BATCH, _KEY, _as_point, _as_points

if TYPE_CHECKING:
    from simn_sim.geometry.freespace import FreeSpace2D

__all__ = ["GoalField"]


@dataclass
class _Best:
    value: float
    kind: str  # "goal", "tangent", "none"
    corner: int = -1
    rel: float = 0.0
    point: np.ndarray | None = None
    node: int = -1  # index into the field's sorted node arrays


class GoalField:
    """Exact geodesic distance to a fixed goal from any query point (build via
    :meth:`FreeSpace2D.distance_field_to`).

    Holds Dijkstra distances from the goal to every tangent node. A query point's distance is
    the minimum of ``|xy - goal|`` (if the goal is visible) and, over tangent points t of xy on
    corner circles, ``|xy - t| + arc(t, neighbour node) + d(neighbour)``; candidates are
    visited in increasing order of that value and the first whose segment is free wins, so
    usually only a few visibility tests are needed.
    """

    def __init__(self, space: FreeSpace2D, goal: np.ndarray) -> None:
        t_start = time.perf_counter()
        self.space = space
        self.goal = goal
        r = space.robot_radius
        nb = space.n_nodes
        # Tangent nodes from the goal.
        gc, grel, gpts, glen = space._point_tangents(goal)
        vis = space._segments_free(np.broadcast_to(goal, gpts.shape), gpts)
        gc, grel, gpts, glen = gc[vis], grel[vis], gpts[vis], glen[vis]
        ng = len(gc)
        corner = np.concatenate([space._node_corner, gc])
        rel = np.concatenate([space._node_rel, grel])
        xy = np.concatenate([space._node_xy, gpts]) if ng else space._node_xy
        n = nb + ng
        goal_idx = n
        # Arc edges between consecutive nodes (by angle) on the same circle.
        order = np.lexsort((rel, corner))
        same = corner[order[1:]] == corner[order[:-1]]
        a, b = order[:-1][same], order[1:][same]
        arc_ok = space._arcs_free(corner[a], rel[a], rel[b])
        a, b = a[arc_ok], b[arc_ok]
        arc_w = np.maximum(r * (rel[b] - rel[a]), 1e-12)
        seg_a = np.arange(0, nb, 2)
        rows = np.concatenate([seg_a, a, np.full(ng, goal_idx)])
        cols = np.concatenate([seg_a + 1, b, nb + np.arange(ng)])
        wts = np.concatenate([np.maximum(space._seg_len, 1e-12), arc_w, np.maximum(glen, 1e-12)])
        graph = coo_matrix((wts, (rows, cols)), shape=(n + 1, n + 1)).tocsr()
        dist, pred = dijkstra(graph, directed=False, indices=goal_idx, return_predecessors=True)
        # Sorted views for point queries.
        self._order = order
        self._keys = corner[order] * _KEY + rel[order]
        self._s_corner = corner[order]
        self._s_rel = rel[order]
        self._s_dist = dist[order]
        self._corner = corner
        self._rel = rel
        self._xy = xy
        self._dist = dist
        self._pred = pred
        self._goal_idx = goal_idx
        self.n_nodes = n + 1
        self.n_edges = graph.nnz
        self.build_time_s = time.perf_counter() - t_start

    # ------------------------------------------------------------------ internals

    def _query(self, p: np.ndarray) -> _Best:
        sp = self.space
        if not bool(sp._free_unchecked(p)):
            return _Best(math.inf, "none")
        d_goal = float(np.hypot(*(p - self.goal)))
        if d_goal < 1e-12:
            return _Best(0.0, "goal")
        c, rel, pts, tlen = sp._point_tangents(p)
        r = sp.robot_radius
        lb = np.full(len(c), np.inf)
        nbr = np.full(len(c), -1, dtype=np.int64)
        if len(c) and len(self._keys):
            key = c * _KEY + rel
            pos = np.searchsorted(self._keys, key)
            nk = len(self._keys)
            left = pos - 1
            right = pos
            has_l = (left >= 0) & (self._s_corner[np.clip(left, 0, nk - 1)] == c)
            has_r = (right < nk) & (self._s_corner[np.clip(right, 0, nk - 1)] == c)
            li, ri = np.clip(left, 0, nk - 1), np.clip(right, 0, nk - 1)
            d_l = np.where(has_l, self._s_dist[li] + r * (rel - self._s_rel[li]), np.inf)
            d_r = np.where(has_r, self._s_dist[ri] + r * (self._s_rel[ri] - rel), np.inf)
            # Arc-free tests only where they can matter (finite candidate).
            fl = np.isfinite(d_l)
            if fl.any():
                idx = np.nonzero(fl)[0]
                okl = sp._arcs_free(c[idx], self._s_rel[li[idx]], rel[idx])
                d_l[idx[~okl]] = np.inf
            fr = np.isfinite(d_r)
            if fr.any():
                idx = np.nonzero(fr)[0]
                okr = sp._arcs_free(c[idx], rel[idx], self._s_rel[ri[idx]])
                d_r[idx[~okr]] = np.inf
            use_r = d_r < d_l
            lb = tlen + np.where(use_r, d_r, d_l)
            nbr = np.where(use_r, ri, li)
        # Candidate -1 is the straight segment to the goal.
        vals = np.concatenate([[d_goal], lb])
        order = np.argsort(vals, kind="stable")
        order = order[np.isfinite(vals[order])]
        ends = np.concatenate([self.goal[None], pts])
        for k0 in range(0, len(order), _BATCH):
            chunk = order[k0 : k0 + _BATCH]
            free = sp._segments_free(np.broadcast_to(p, (len(chunk), 2)), ends[chunk])
            hit = np.nonzero(free)[0]
            if len(hit):
                j = int(chunk[hit[0]])
                if j == 0:
                    return _Best(d_goal, "goal")
                j -= 1
                return _Best(
                    float(vals[j + 1]), "tangent", int(c[j]), float(rel[j]), pts[j], int(nbr[j])
                )
        return _Best(math.inf, "none")

    def _arc_points(self, corner: int, rel_a: float, rel_b: float) -> np.ndarray:
        """Waypoints replacing the arc from rel_a to rel_b (either order) of a corner circle.

        The vertices of the tangent (circumscribed) polygon with steps of at most
        ``pi / (2 quad_segs)``: the polyline from the arc's start through these points to its end
        stays outside the circle, is tangent to it at both ends, and is at most
        ``tan(x) / x - 1`` (x = half step; 0.08 % for quad_segs = 16) longer than the arc.
        """
        sp = self.space
        span = rel_b - rel_a
        if abs(span) < 1e-9:
            return np.zeros((0, 2))
        k = max(1, int(math.ceil(abs(span) / (math.pi / (2 * sp.quad_segs)) - 1e-9)))
        half = 0.5 * span / k
        rels = rel_a + (np.arange(k) + 0.5) * (span / k)
        ang = sp._theta0[corner] + rels
        rad = sp.robot_radius / math.cos(half)
        return sp.corner_xy[corner] + rad * np.stack([np.cos(ang), np.sin(ang)], axis=1)

    # ------------------------------------------------------------------ public

    def distance(self, xy: np.ndarray | Sequence, snap: float = 0.0) -> float | np.ndarray:
        """Exact geodesic distance (metres) from ``xy`` to the goal.

        Args:
            xy: (2,) one point -> float; or (N, 2) -> (N,) float64. World x-y.
            snap: metres. A point that is not free but within ``snap`` of free space (e.g. a
                robot that physics let penetrate an obstacle by a few mm) is first moved to
                the nearest free point q (:meth:`FreeSpace2D.nearest_free`); the result is then
                ``|xy - q| + distance(q)``. 0 (default): no snapping.

        Returns:
            ``math.inf`` for points that are not free (beyond ``snap``) or cannot reach the goal.
        """
        p = _as_points(xy, "xy")
        snap = float(snap)
        if not (math.isfinite(snap) and snap >= 0.0):
            raise ValueError(f"snap must be finite and >= 0, got {snap!r}")
        flat = p.reshape(-1, 2)
        out = np.array([self._query(q).value for q in flat], dtype=np.float64)
        if snap > 0.0:
            for k in np.nonzero(~self.space._free_unchecked(flat))[0]:
                try:
                    q = self.space.nearest_free(flat[k])
                except RuntimeError:
                    continue
                off = float(np.hypot(*(q - flat[k])))
                if off <= snap:
                    out[k] = off + self._query(q).value
        if p.shape == (2,):
            return float(out[0])
        return out.reshape(p.shape[:-1])

    def path(self, xy: np.ndarray | Sequence[float]) -> np.ndarray | None:
        """Shortest path from ``xy`` (2,) to the goal: (M, 2) waypoints incl. both ends, or None.

        Arcs are replaced by their circumscribed polygon (see :meth:`FreeSpace2D.shortest_path`).
        """
        p = _as_point(xy, "xy")
        best = self._query(p)
        if best.kind == "none":
            return None
        pts: list[np.ndarray] = [p]
        if best.kind == "tangent":
            assert best.point is not None
            pts.append(best.point)
            node = int(self._order[best.node])
            pts.extend(self._arc_points(best.corner, best.rel, float(self._rel[node])))
            pts.append(self._xy[node])
            while True:
                nxt = int(self._pred[node])
                if nxt < 0:  # unreachable; cannot happen for a finite distance
                    return None
                if nxt == self._goal_idx:
                    break
                if self._corner[nxt] == self._corner[node]:
                    pts.extend(
                        self._arc_points(
                            int(self._corner[node]), float(self._rel[node]), float(self._rel[nxt])
                        )
                    )
                pts.append(self._xy[nxt])
                node = nxt
        pts.append(self.goal)
        out = np.asarray(pts, dtype=np.float64)
        keep = np.ones(len(out), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(out, axis=0), axis=1) > 1e-9
        keep[-1] = True
        out = out[keep]
        if len(out) >= 2 and np.linalg.norm(out[-1] - out[-2]) <= 1e-9:
            out = np.delete(out, -2, axis=0)
        return out
