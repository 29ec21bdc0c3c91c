"""Trap episodes: the route needs a doorway hidden from the start, and driving straight at the
goal loses ground. Computed exactly from a :class:`~simn_sim.env.layout.Layout`.

Definition (all in the floor plane, world x-y, metres)
------------------------------------------------------
An episode (start ``s``, goal ``g``) in a layout is a *trap* when all three hold:

(a) **detour**: ``geodesic(s, g) >= 1.5 * |g - s|`` (exact geodesic of the robot disc,
    :class:`~simn_sim.geometry.freespace.FreeSpace2D`);
(b) **hidden doorway**: the exact shortest path passes through a doorway whose opening no straight
    line of sight from ``s`` reaches. A doorway's opening is the clear gap of its wall, taken on
    the wall's centre line (between the ends of the two wall pieces beside it). Sight lines are
    blocked by walls only, each taken as its centre-line segment (walls are 2.6 m tall, so they
    hide what is behind them at any camera height; furniture is ignored, so "hidden" is never
    caused by a chair or a shelf). Visibility is decided exactly, by angle intervals: the opening
    is hidden when the directions in which walls lie in front of it cover all the directions in
    which it is seen;
(c) **greedy loses ground**: driving straight from ``s`` towards ``g`` is blocked, and at the
    last collision-free point ``h`` of that straight line (found to 1 mm) the geodesic distance
    to the goal is larger than at the start: ``geodesic(h, g) > geodesic(s, g)``. A greedy plan
    heads into a region it has to come back out of.

Rooms and the corridor are rectangles, so every doorway of the start's own room (the first one
the route passes) is always in sight from the start; the hidden doorway is a later one, typically
the one into the goal's room. The typical trap: start and goal in neighbouring rooms without a
door between them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import shapely

from simn_sim.env.layout import WALL_THICKNESS, Door, Layout
from simn_sim.geometry.freespace import FreeSpace2D

__all__ = [
    "MIN_DETOUR_RATIO",
    "TrapInfo",
    "door_opening",
    "opening_visible",
    "trap_info",
    "wall_segments",
]

MIN_DETOUR_RATIO = 1.5  # (a): geodesic / euclidean
_GREEDY_TOL = 1e-3  # (c): the last free point of the straight line is found to 1 mm
_ANG_EPS = 1e-12  # radians: angle intervals narrower than this are empty


@dataclasses.dataclass(frozen=True)
class TrapInfo:
    """What :func:`trap_info` measured; ``is_trap`` is (a) and (b) and (c)."""

    geodesic_m: float
    euclidean_m: float
    detour_ratio: float
    doors_on_path: tuple[int, ...]  # indices into layout.doors, in path order
    hidden_doors: tuple[int, ...]  # those of doors_on_path not in sight from the start
    greedy_stop: tuple[float, float] | None  # h: last free point of the straight line (None: free)
    greedy_geodesic_m: float | None  # geodesic(h, g)

    @property
    def detour(self) -> bool:
        return self.detour_ratio >= MIN_DETOUR_RATIO

    @property
    def hidden_doorway(self) -> bool:
        return len(self.hidden_doors) > 0

    @property
    def greedy_loses(self) -> bool:
        return self.greedy_geodesic_m is not None and self.greedy_geodesic_m > self.geodesic_m

    @property
    def is_trap(self) -> bool:
        return self.detour and self.hidden_doorway and self.greedy_loses


def door_opening(door: Door) -> np.ndarray:
    """(2, 2) end points of a doorway's clear opening on its wall's centre line.

    The wall pieces beside a gap reach ``WALL_THICKNESS / 2`` into it (see
    :func:`simn_sim.env.layout._wall_with_doors`), so the clear opening is that much narrower on
    each side than ``door.width``.
    """
    half = door.width / 2 - WALL_THICKNESS / 2
    if half <= 0:
        raise ValueError(f"doorway {door} has no clear opening")
    cx, cy = float(door.center[0]), float(door.center[1])
    if door.axis == "x":  # the wall runs along x
        return np.array([[cx - half, cy], [cx + half, cy]])
    if door.axis == "y":
        return np.array([[cx, cy - half], [cx, cy + half]])
    raise ValueError(f"doorway axis must be 'x' or 'y', got {door.axis!r}")


def wall_segments(layout: Layout) -> np.ndarray:
    """(N, 2, 2) centre-line segments of the layout's walls (its long axis, end to end)."""
    segs = []
    for b in layout.boxes:
        if b.kind != "wall":
            continue
        c, s = math.cos(b.yaw), math.sin(b.yaw)
        if b.half[0] >= b.half[1]:
            u = np.array([c, s]) * b.half[0]
        else:
            u = np.array([-s, c]) * b.half[1]
        m = np.asarray(b.center[:2], float)
        segs.append([m - u, m + u])
    return np.asarray(segs, float).reshape(-1, 2, 2)


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def _ray_hit(s: np.ndarray, theta: float, p: np.ndarray, q: np.ndarray) -> float:
    """Distance along the ray from ``s`` in direction ``theta`` to segment pq (inf: no hit)."""
    d = np.array([math.cos(theta), math.sin(theta)])
    e = q - p
    den = d[0] * (-e[1]) - d[1] * (-e[0])
    if abs(den) < 1e-15:
        return math.inf
    w = p - s
    t = (w[0] * (-e[1]) - w[1] * (-e[0])) / den
    u = (d[0] * w[1] - d[1] * w[0]) / den
    if t < 0 or u < -1e-12 or u > 1 + 1e-12:
        return math.inf
    return float(t)


def opening_visible(start: Sequence[float], opening: np.ndarray, walls: np.ndarray) -> bool:
    """Whether some straight line from ``start`` reaches a point of ``opening`` ((2, 2)) without
    crossing a wall segment of ``walls`` ((N, 2, 2)). Exact (angle intervals; an opening seen
    edge-on, or only through a single direction, counts as hidden)."""
    s = np.asarray(start, float)
    a, b = np.asarray(opening, float)
    ref = math.atan2(*(((a + b) / 2 - s)[::-1]))

    def rel(p: np.ndarray) -> float:
        return float(_wrap(math.atan2(p[1] - s[1], p[0] - s[0]) - ref))

    d0, d1 = sorted((rel(a), rel(b)))
    if d1 - d0 <= _ANG_EPS:
        return False
    blocked: list[tuple[float, float]] = []
    for p, q in walls:
        rp, rq = rel(p), rel(q)
        lo, hi = min(rp, rq), max(rp, rq)
        # the wall's directions: [lo, hi], or the wrap-around [hi, pi] + [-pi, lo]
        spans = [(lo, hi)] if hi - lo <= math.pi else [(hi, math.pi), (-math.pi, lo)]
        # the wall may cross the opening: split there (in front on one side, behind on the other)
        cuts = [d0, d1]
        x = _segment_cross(a, b, p, q)
        if x is not None:
            cuts.append(rel(x))
        cuts = sorted(cuts)
        for u0, u1 in spans:
            for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True):
                v0, v1 = max(u0, c0, d0), min(u1, c1, d1)
                if v1 - v0 <= _ANG_EPS:
                    continue
                mid = ref + (v0 + v1) / 2
                if _ray_hit(s, mid, p, q) < _ray_hit(s, mid, a, b):
                    blocked.append((v0, v1))
    covered = d0
    for v0, v1 in sorted(blocked):
        if v0 > covered + _ANG_EPS:
            return True
        covered = max(covered, v1)
    return covered < d1 - _ANG_EPS


def _segment_cross(a, b, p, q) -> np.ndarray | None:
    """The point where the open segments ab and pq cross (None: they do not, or are parallel)."""
    r, sv = b - a, q - p
    den = r[0] * sv[1] - r[1] * sv[0]
    if abs(den) < 1e-15:
        return None
    w = p - a
    t = (w[0] * sv[1] - w[1] * sv[0]) / den
    u = (w[0] * r[1] - w[1] * r[0]) / den
    if 1e-12 < t < 1 - 1e-12 and 1e-12 < u < 1 - 1e-12:
        return a + t * r
    return None


def doors_on_path(path: np.ndarray, openings: Sequence[np.ndarray]) -> list[int]:
    """Indices of the openings the polyline ``path`` crosses, in the order it crosses them."""
    if path is None or len(path) < 2:
        return []
    line = shapely.LineString(path)
    hits = []
    for i, op in enumerate(openings):
        x = line.intersection(shapely.LineString(op))
        if x.is_empty:
            continue
        pts = shapely.get_coordinates(x)
        hits.append((min(line.project(shapely.Point(pt)) for pt in pts), i))
    return [i for _, i in sorted(hits)]


def greedy_stop(fs: FreeSpace2D, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
    """The last collision-free point of the straight line from ``start`` towards ``goal`` (to
    1 mm); None when the whole line is free."""
    s, g = np.asarray(start, float), np.asarray(goal, float)
    if fs.segment_free(s, g):
        return None
    length = float(np.hypot(*(g - s)))
    lo, hi = 0.0, 1.0  # segment_free(s, s + lo (g - s)) holds, with hi it does not
    while (hi - lo) * length > _GREEDY_TOL:
        mid = (lo + hi) / 2
        if fs.segment_free(s, s + mid * (g - s)):
            lo = mid
        else:
            hi = mid
    return s + lo * (g - s)


def trap_info(
    layout: Layout,
    fs: FreeSpace2D,
    start: Sequence[float],
    goal: Sequence[float],
    walls: np.ndarray | None = None,
) -> TrapInfo:
    """Measure (a), (b) and (c) of the trap definition (module docstring) for one episode.

    ``fs``: the layout's free space for the robot disc (as the env builds it). ``walls``:
    :func:`wall_segments` of the layout (computed when None). Raises ValueError when the goal
    is unreachable from the start or either is not free.
    """
    s = np.asarray(start, float)[:2]
    g = np.asarray(goal, float)[:2]
    walls = wall_segments(layout) if walls is None else walls
    field = fs.distance_field_to(g)
    geo = float(field.distance(s))
    if not math.isfinite(geo):
        raise ValueError(f"goal {g.tolist()} is not reachable from start {s.tolist()}")
    eu = float(np.hypot(*(g - s)))
    path = field.path(s)
    openings = [door_opening(d) for d in layout.doors]
    on_path = doors_on_path(path, openings)
    hidden = tuple(i for i in on_path if not opening_visible(s, openings[i], walls))
    h = greedy_stop(fs, s, g)
    h_geo = None if h is None else float(field.distance(h))
    return TrapInfo(
        geodesic_m=geo,
        euclidean_m=eu,
        detour_ratio=geo / eu if eu > 0 else math.inf,
        doors_on_path=tuple(on_path),
        hidden_doors=hidden,
        greedy_stop=None if h is None else (float(h[0]), float(h[1])),
        greedy_geodesic_m=h_geo,
    )
