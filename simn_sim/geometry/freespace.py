"""Exact 2-D free space of a disc robot and exact geodesic (shortest-path) distances.

All coordinates are world x-y in metres (the floor plane, z dropped); angles in radians.

Model
-----
Obstacles are 2-D footprints (polygons). A disc robot of radius ``r`` is collision-free when its
centre is at distance ``>= r`` from every obstacle, i.e. outside the Minkowski sum of the
obstacles and the disc. The boundary of that inflated set consists of straight offset edges and
circular arcs of radius ``r`` centred on the *convex corners* of the original footprints.

A shortest path of the centre is a sequence of straight segments tangent to those corner
circles, joined by arcs along them (the classic tangent / reduced visibility graph; only
corners where the free space is locally non-convex can be touched). This module builds that
graph **analytically**: nodes are tangent points on corner circles, edges are

* bitangent segments between two corner circles (outer and inner tangents, length exact),
* arcs of a corner circle between consecutive tangent points (length ``r * dtheta``, exact),
* for a query point or goal, tangent segments from the point to each circle.

Path *lengths* are therefore exact up to floating point, whatever ``quad_segs`` is.

Collision predicates (``is_free``, ``segment_free`` and the visibility tests of the graph) use
the union of shapely buffers of the footprints with radius ``r - 1e-5`` m. Shapely places buffer
vertices ON the circle, so this polygon lies between ``(r - 1e-5) * cos(pi / (4 quad_segs))`` and
``r - 1e-5`` of the footprints: the predicates may accept a centre up to
``r * (1 - cos(pi / (4 quad_segs))) + 1e-5`` closer than ``r`` (0.31 mm for r = 0.25 m,
quad_segs = 16), never farther. We deliberately do NOT inflate conservatively (by
``1 / cos``): the exact tangent points lie at distance exactly ``r`` and must count as free.
Arcs are tested against the other obstacles at 1-degree samples along the arc.
Consequence: a gap between obstacles is passable when it is at least ``2 r - 2e-5`` m wide, so
a gap of exactly ``2 r`` (the robot touching both sides, which generated layouts do contain)
is passable, and one 0.1 mm narrower is not.

``clearance`` is exact: the Euclidean distance to the nearest un-inflated footprint.
"""

import math
import time
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import shapely

from simn_sim.geometry.footprints import (
    _ARC_STEP,
    _CORE_SHRINK,
    _as_point,
    _as_points,
    _as_polygonal,
    _rel_angle,
    _ring_corners,
)
from simn_sim.geometry.geodesic import GoalField

__all__ = ["FreeSpace2D", "GoalField"]


# --------------------------------------------------------------------------- main class


class FreeSpace2D:
    """Free space of a disc robot among polygonal obstacles, with exact geodesic distances.

    Args:
        obstacles: 2-D footprints in world x-y (metres): each a (K, 2) polygon vertex array
            (K >= 3, either orientation) or a shapely geometry (points and lines are thickened
            by 1e-6 m). Obstacles may overlap.
        robot_radius: disc radius r > 0 (metres).
        bounds: (xmin, ymin, xmax, ymax): the robot *centre* must stay inside this box
            (closed). ``None``: unbounded.
        quad_segs: segments per quarter circle of the polygonal inflation used by the collision
            predicates (see the module docstring for the resulting tolerance).

    The tangent graph is built in the constructor (see ``build_time_s``).
    """

    def __init__(
        self,
        obstacles: Sequence[np.ndarray | shapely.Geometry],
        robot_radius: float,
        bounds: tuple[float, float, float, float] | None = None,
        quad_segs: int = 16,
    ) -> None:
        t_start = time.perf_counter()
        r = float(robot_radius)
        if not math.isfinite(r) or r <= 0.0:
            raise ValueError(f"robot_radius must be a finite number > 0, got {robot_radius!r}")
        if isinstance(quad_segs, bool) or not isinstance(quad_segs, (int, np.integer)):
            raise ValueError(f"quad_segs must be an integer >= 1, got {quad_segs!r}")
        if quad_segs < 1:
            raise ValueError(f"quad_segs must be an integer >= 1, got {quad_segs!r}")
        if bounds is not None:
            b = np.asarray(bounds, dtype=np.float64)
            if b.shape != (4,) or not np.all(np.isfinite(b)) or b[0] >= b[2] or b[1] >= b[3]:
                raise ValueError(
                    f"bounds must be finite (xmin, ymin, xmax, ymax) with xmin < xmax and "
                    f"ymin < ymax, got {bounds!r}"
                )
            bounds = (float(b[0]), float(b[1]), float(b[2]), float(b[3]))
        if isinstance(obstacles, np.ndarray) and obstacles.ndim == 2:
            raise ValueError(
                "obstacles must be a sequence of footprints; wrap a single (K, 2) array in a list"
            )
        self.robot_radius = r
        self.bounds = bounds
        self.quad_segs = int(quad_segs)

        obstacles = list(obstacles)
        polys: list[shapely.Polygon] = []
        for i, ob in enumerate(obstacles):
            polys.extend(_as_polygonal(ob, i))
        self._polys = np.array(polys, dtype=object)
        self._tree = shapely.STRtree(self._polys)
        self.n_obstacles = len(obstacles)

        core_r = r - _CORE_SHRINK
        if len(polys):
            self._core = shapely.union_all(shapely.buffer(self._polys, core_r, quad_segs=quad_segs))
        else:
            self._core = shapely.Polygon()
        shapely.prepare(self._core)

        self._build_corners()
        self._build_bitangents()
        self._field_cache: OrderedDict[tuple[float, float], GoalField] = OrderedDict()
        self.build_time_s = time.perf_counter() - t_start

    # ------------------------------------------------------------------ predicates

    def _in_bounds(self, xy: np.ndarray) -> np.ndarray:
        if self.bounds is None:
            return np.ones(xy.shape[:-1], dtype=bool)
        x0, y0, x1, y1 = self.bounds
        x, y = xy[..., 0], xy[..., 1]
        return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)

    def _free_unchecked(self, xy: np.ndarray) -> np.ndarray:
        inside = shapely.intersects_xy(self._core, xy[..., 0], xy[..., 1])
        return self._in_bounds(xy) & ~np.asarray(inside, dtype=bool)

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        """Whether the robot centre at ``xy`` is collision-free (and inside ``bounds``).

        Args:
            xy: (N, 2) (or (..., 2)) centre positions, world x-y, metres.

        Returns:
            (N,) bool (shape ``xy.shape[:-1]``).
        """
        p = _as_points(xy, "xy")
        return self._free_unchecked(p)

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Exact distance from ``xy`` to the nearest un-inflated obstacle footprint.

        Args:
            xy: (N, 2) (or (..., 2)) points, world x-y, metres.

        Returns:
            (N,) float64 metres (0 inside a footprint, inf without obstacles).
        """
        p = _as_points(xy, "xy")
        flat = p.reshape(-1, 2)
        out = np.full(len(flat), np.inf)
        if len(self._polys) and len(flat):
            (qi, _ti), dist = self._tree.query_nearest(
                shapely.points(flat), return_distance=True, all_matches=False
            )
            out[qi] = dist
        return out.reshape(p.shape[:-1])

    def _segments_free(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(N, 2), (N, 2) endpoints assumed in bounds -> (N,) bool: segment misses the core."""
        if len(a) == 0:
            return np.zeros(0, dtype=bool)
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        return ~np.asarray(shapely.intersects(self._core, lines), dtype=bool)

    def segment_free(
        self, a: np.ndarray | Sequence[float], b: np.ndarray | Sequence[float]
    ) -> bool:
        """Whether the robot can slide straight from centre ``a`` to centre ``b`` (both (2,))."""
        pa, pb = _as_point(a, "a"), _as_point(b, "b")
        ends = np.stack([pa, pb])
        if not np.all(self._in_bounds(ends)):
            return False
        if np.allclose(pa, pb, rtol=0.0, atol=1e-12):
            return bool(self._free_unchecked(pa))
        return bool(self._segments_free(pa[None], pb[None])[0])

    def nearest_free(self, xy: np.ndarray, margin: float = 1e-4) -> np.ndarray:
        """Free points nearest to ``xy`` (e.g. a robot centre that physics pushed a few mm into
        an obstacle, where :meth:`GoalField.distance` would return inf).

        Args:
            xy: (N, 2) (or (..., 2)) points, world x-y, metres.
            margin: how far (metres) past the inflated boundary a projected point is placed.

        Returns:
            Same shape: free points are returned unchanged; others are moved to the nearest
            point of the inflated boundary (then clipped to ``bounds``) plus ``margin`` outwards.
            Raises RuntimeError when no free point is found nearby (e.g. a fully enclosed spot).
        """
        p = _as_points(xy, "xy")
        if not (math.isfinite(margin) and margin > 0):
            raise ValueError(f"margin must be finite and > 0, got {margin!r}")
        flat = p.reshape(-1, 2).copy()
        bad = np.nonzero(~self._free_unchecked(flat))[0]
        if len(bad):
            boundary = shapely.boundary(self._core)
            for k in bad:
                q = flat[k]
                if self.bounds is not None:
                    x0, y0, x1, y1 = self.bounds
                    q = np.clip(q, [x0, y0], [x1, y1])
                    if bool(self._free_unchecked(q)):
                        flat[k] = q
                        continue
                line = shapely.shortest_line(shapely.Point(q), boundary)
                b = np.asarray(line.coords)[1]
                u = b - q
                norm = float(np.hypot(*u))
                for push in (margin, 10 * margin, 100 * margin):
                    cand = b + (u / norm) * push if norm > 1e-12 else b
                    if bool(self._free_unchecked(cand)):
                        flat[k] = cand
                        break
                else:
                    raise RuntimeError(f"nearest_free: no free point found near {q.tolist()}")
        return flat.reshape(p.shape)

    # ------------------------------------------------------------------ graph building

    def _build_corners(self) -> None:
        """Corner circles and the free-ness of 1-degree samples along their valid arcs."""
        cs, t0s, ws, owner = [], [], [], []
        for k, poly in enumerate(self._polys):
            for ring in [poly.exterior, *poly.interiors]:
                c, t0, w = _ring_corners(np.asarray(ring.coords))
                cs.append(c)
                t0s.append(t0)
                ws.append(w)
                owner.append(np.full(len(c), k))
        if cs:
            centres = np.concatenate(cs)
            theta0 = np.concatenate(t0s)
            width = np.concatenate(ws)
        else:
            centres, theta0, width = np.zeros((0, 2)), np.zeros(0), np.zeros(0)

        r = self.robot_radius
        nseg = np.maximum(1, np.ceil(width / _ARC_STEP)).astype(np.int64)
        step = width / nseg
        counts = nseg + 1
        off = np.concatenate([[0], np.cumsum(counts)])
        corner_of = np.repeat(np.arange(len(centres)), counts)
        k_in = np.arange(off[-1]) - off[corner_of]
        ang = theta0[corner_of] + k_in * step[corner_of]
        pts = centres[corner_of] + r * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        free = self._free_unchecked(pts) if len(pts) else np.zeros(0, dtype=bool)

        # Keep only corners with at least one free sample; re-pack the sample arrays.
        any_free = np.zeros(len(centres), dtype=bool)
        np.logical_or.at(any_free, corner_of, free)
        keep_s = any_free[corner_of]
        self.corner_xy = centres[any_free]
        self._theta0 = theta0[any_free]
        self._width = width[any_free]
        self._step = step[any_free]
        counts_k = counts[any_free]
        self._samp_off = np.concatenate([[0], np.cumsum(counts_k)]).astype(np.int64)
        blocked = ~free[keep_s]
        self._blocked_cum = np.concatenate([[0], np.cumsum(blocked)]).astype(np.int64)
        self.n_corners = len(self.corner_xy)

    def _arcs_free(self, corner: np.ndarray, rel_a: np.ndarray, rel_b: np.ndarray) -> np.ndarray:
        """Whether arcs of corner circles between relative angles rel_a <= rel_b are free.

        Tested at the circle's 1-degree samples strictly between the two ends (the ends are
        tangent points whose free-ness is established by the segments touching them).
        """
        if len(corner) == 0:
            return np.zeros(0, dtype=bool)
        s = self._step[corner]
        ka = np.ceil(rel_a / s + 1e-6).astype(np.int64)
        kb = np.floor(rel_b / s - 1e-6).astype(np.int64)
        ka = np.maximum(ka, 0)
        kb = np.minimum(kb, self._samp_off[corner + 1] - self._samp_off[corner] - 1)
        base = self._samp_off[corner]
        hi = np.maximum(kb + 1, ka)
        n_blocked = self._blocked_cum[base + hi] - self._blocked_cum[base + ka]
        return n_blocked == 0

    def _circle_point(self, corner: np.ndarray, rel: np.ndarray) -> np.ndarray:
        ang = self._theta0[corner] + rel
        return self.corner_xy[corner] + self.robot_radius * np.stack(
            [np.cos(ang), np.sin(ang)], axis=-1
        )

    def _build_bitangents(self) -> None:
        """Visible bitangent segments between all pairs of corner circles -> base graph."""
        r = self.robot_radius
        m = self.n_corners
        c_xy, t0, w = self.corner_xy, self._theta0, self._width
        node_corner, node_rel, edge_len = [], [], []
        n_candidates = 0
        rows_per_chunk = max(1, 400_000 // max(m, 1))
        for i0 in range(0, m, rows_per_chunk):
            ii, jj = np.nonzero(
                np.triu(np.ones((min(rows_per_chunk, m - i0), m), dtype=bool), k=i0 + 1)
            )
            ii = ii + i0
            d = c_xy[jj] - c_xy[ii]
            dist = np.hypot(d[:, 0], d[:, 1])
            ok = dist > 1e-9
            ii, jj, d, dist = ii[ok], jj[ok], d[ok], dist[ok]
            base = np.arctan2(d[:, 1], d[:, 0])
            # Outer tangents: both touch points on the same side (normal base +- pi/2).
            # Inner tangents (dist > 2r): touch angles base +- acos(2r/dist) on i, +pi on j.
            inner = dist > 2.0 * r
            beta = np.arccos(np.clip(2.0 * r / np.where(inner, dist, 1.0), -1.0, 1.0))
            cand_i = [base + 0.5 * np.pi, base - 0.5 * np.pi, base + beta, base - beta]
            cand_j = [
                base + 0.5 * np.pi,
                base - 0.5 * np.pi,
                base + beta + np.pi,
                base - beta + np.pi,
            ]
            inner_len = np.sqrt(np.maximum(dist**2 - 4.0 * r * r, 0.0))
            lens = [dist, dist, inner_len, inner_len]
            masks = [np.ones_like(inner), np.ones_like(inner), inner, inner]
            for phi_i, phi_j, ln, msk in zip(cand_i, cand_j, lens, masks, strict=True):
                rel_i, v_i = _rel_angle(phi_i, t0[ii], w[ii])
                rel_j, v_j = _rel_angle(phi_j, t0[jj], w[jj])
                sel = np.nonzero(msk & v_i & v_j)[0]
                n_candidates += len(sel)
                if len(sel) == 0:
                    continue
                ci, cj = ii[sel], jj[sel]
                ri, rj = rel_i[sel], rel_j[sel]
                pa = self._circle_point(ci, ri)
                pb = self._circle_point(cj, rj)
                inb = self._in_bounds(pa) & self._in_bounds(pb)
                sel2 = np.nonzero(inb)[0]
                vis = self._segments_free(pa[sel2], pb[sel2])
                sel2 = sel2[vis]
                node_corner.append(np.stack([ci[sel2], cj[sel2]], axis=1).ravel())
                node_rel.append(np.stack([ri[sel2], rj[sel2]], axis=1).ravel())
                edge_len.append(ln[sel][sel2])
        if node_corner:
            self._node_corner = np.concatenate(node_corner).astype(np.int64)
            self._node_rel = np.concatenate(node_rel)
            self._seg_len = np.concatenate(edge_len)
        else:
            self._node_corner = np.zeros(0, dtype=np.int64)
            self._node_rel = np.zeros(0)
            self._seg_len = np.zeros(0)
        self._node_xy = self._circle_point(self._node_corner, self._node_rel)
        self.n_bitangent_candidates = n_candidates
        self.n_bitangents = len(self._seg_len)

    def _point_tangents(
        self, p: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tangents from point p (2,) to every corner circle, restricted to valid arcs.

        Returns:
            corner (T,), rel (T,) relative angle, touch points (T, 2), segment length (T,).
            Visibility is NOT tested here.
        """
        r = self.robot_radius
        q = p[None, :] - self.corner_xy
        dist = np.hypot(q[:, 0], q[:, 1])
        base = np.arctan2(q[:, 1], q[:, 0])
        alpha = np.arccos(np.clip(r / np.maximum(dist, 1e-300), -1.0, 1.0))
        corner = np.arange(self.n_corners)
        tan_len = np.sqrt(np.maximum(dist**2 - r * r, 0.0))
        cs, rels = [], []
        for sgn in (1.0, -1.0):
            rel, valid = _rel_angle(base + sgn * alpha, self._theta0, self._width)
            cs.append(corner[valid])
            rels.append(rel[valid])
        c = np.concatenate(cs)
        rel = np.concatenate(rels)
        pts = self._circle_point(c, rel)
        inb = self._in_bounds(pts)
        c, rel, pts = c[inb], rel[inb], pts[inb]
        return c, rel, pts, tan_len[c]

    # ------------------------------------------------------------------ queries

    @property
    def n_nodes(self) -> int:
        """Tangent points in the base graph (two per visible bitangent)."""
        return len(self._node_corner)

    def distance_field_to(self, goal: np.ndarray | Sequence[float]) -> GoalField:
        """Precompute exact geodesic distances to ``goal`` (2,) (Dijkstra once from the goal).

        Raises:
            ValueError: the goal is not a finite (2,) point or is not free.
        """
        g = _as_point(goal, "goal")
        key = (float(g[0]), float(g[1]))
        if key in self._field_cache:
            self._field_cache.move_to_end(key)
            return self._field_cache[key]
        if not bool(self._free_unchecked(g)):
            raise ValueError(f"goal {g.tolist()} is not in free space")
        field = GoalField(self, g)
        self._field_cache[key] = field
        if len(self._field_cache) > 8:
            self._field_cache.popitem(last=False)
        return field

    def shortest_path(
        self, start: np.ndarray | Sequence[float], goal: np.ndarray | Sequence[float]
    ) -> np.ndarray | None:
        """Shortest collision-free path of the robot centre.

        Returns:
            (M, 2) waypoints, world x-y, from ``start`` to ``goal`` inclusive, or ``None`` when the
            goal is unreachable or start / goal is not free. Arcs around corners are replaced by
            their circumscribed polygon (``quad_segs`` steps per quarter turn), so the polyline
            keeps clearance >= r around the corner and is at most 0.08 % longer than the arc
            (quad_segs = 16); use :meth:`geodesic_distance` for the exact length.
        """
        s, g = _as_point(start, "start"), _as_point(goal, "goal")
        if not (bool(self._free_unchecked(s)) and bool(self._free_unchecked(g))):
            return None
        return self.distance_field_to(g).path(s)

    def geodesic_distance(
        self, start: np.ndarray | Sequence[float], goal: np.ndarray | Sequence[float]
    ) -> float:
        """Exact shortest-path length (metres) from ``start`` to ``goal``; ``math.inf`` when
        unreachable or when start / goal is not free."""
        s, g = _as_point(start, "start"), _as_point(goal, "goal")
        if not (bool(self._free_unchecked(s)) and bool(self._free_unchecked(g))):
            return math.inf
        return float(self.distance_field_to(g).distance(s))

    def sample_free(
        self, rng: np.random.Generator, n: int, min_clearance: float = 0.0
    ) -> np.ndarray:
        """Uniform samples of free robot-centre positions.

        Args:
            rng: explicit random generator.
            n: number of samples.
            min_clearance: also require ``clearance(xy) >= min_clearance`` (distance to the
                un-inflated footprints, so values <= robot_radius add nothing).

        Returns:
            (n, 2) float64 world x-y, drawn uniformly in ``bounds`` (or the obstacles' bounding
            box when ``bounds`` is None).
        """
        if not isinstance(rng, np.random.Generator):
            raise ValueError("rng must be a numpy.random.Generator")
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"n must be an integer >= 0, got {n!r}")
        mc = float(min_clearance)
        if not math.isfinite(mc) or mc < 0:
            raise ValueError(f"min_clearance must be finite and >= 0, got {min_clearance!r}")
        if self.bounds is not None:
            x0, y0, x1, y1 = self.bounds
        elif len(self._polys):
            x0, y0, x1, y1 = shapely.total_bounds(self._polys)
        else:
            raise ValueError("sample_free needs bounds or at least one obstacle")
        out: list[np.ndarray] = []
        got = 0
        batch = max(64, 4 * n)
        for _ in range(1000):
            if got >= n:
                break
            xy = np.stack([rng.uniform(x0, x1, batch), rng.uniform(y0, y1, batch)], axis=1)
            ok = self._free_unchecked(xy)
            if mc > 0:
                ok &= self.clearance(xy) >= mc
            out.append(xy[ok])
            got += int(ok.sum())
        if got < n:
            raise RuntimeError(
                f"sample_free: found only {got} of {n} free points with clearance >= {mc}"
            )
        return np.concatenate(out)[:n]
