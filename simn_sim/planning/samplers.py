"""Samplers for RRT*: uniform over bounds, and SIMN's goal-vector rays.

The goal-vector ray distribution (:class:`GoalVectorConfig`, :func:`sample_goal_vector`) is in
:mod:`simn_sim.planning.goal_vector`; this module holds the stateful samplers the planner calls.
All samplers draw in batches from an explicit ``np.random.Generator`` (one RNG call per batch).
"""

from __future__ import annotations

import bisect
import heapq
import math
from typing import TYPE_CHECKING, Protocol

import numpy as np

from simn_sim.planning.goal_vector import GoalVectorConfig, RaySamples, sample_goal_vector
from simn_sim.planning.tree import Tree

if TYPE_CHECKING:
    from simn_sim.planning.collision import CollisionChecker

__all__ = [
    "Bounds",
    "GoalVectorConfig",
    "GoalVectorSampler",
    "RaySamples",
    "Sampler",
    "UniformSampler",
    "sample_goal_vector",
]

Bounds = tuple[float, float, float, float]
"""(xmin, ymin, xmax, ymax) in the planning frame, metres."""


class Sampler(Protocol):
    """What the RRT* core needs from a sampler."""

    def reset(self, start: np.ndarray, goal: np.ndarray, rng: np.random.Generator) -> None: ...

    def sample(self, tree: Tree | None = None) -> np.ndarray:
        """One (2,) sample (the sampler may look at the current tree)."""
        ...


class _Batched:
    batch: int = 256

    def __init__(self) -> None:
        self._buf = np.zeros((0, 2))
        self._k = 0
        self._rng: np.random.Generator | None = None

    def _draw(self, n: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, tree: Tree | None = None) -> np.ndarray:
        if self._k >= len(self._buf):
            self._buf = self._draw(self.batch)
            self._k = 0
        x = self._buf[self._k]
        self._k += 1
        return x


def _check_bounds(bounds: Bounds) -> Bounds:
    b = tuple(float(v) for v in bounds)
    if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[2] <= b[0] or b[3] <= b[1]:
        raise ValueError(f"bounds must be finite (xmin, ymin, xmax, ymax) with min < max: {bounds}")
    return b  # type: ignore[return-value]


class UniformSampler(_Batched):
    """Uniform samples over axis-aligned bounds (the baseline RRT* sampler)."""

    def __init__(self, bounds: Bounds) -> None:
        super().__init__()
        self.bounds = _check_bounds(bounds)

    def reset(self, start: np.ndarray, goal: np.ndarray, rng: np.random.Generator) -> None:
        self._rng = rng
        self._buf = np.zeros((0, 2))
        self._k = 0

    def _draw(self, n: int) -> np.ndarray:
        assert self._rng is not None, "call reset() first"
        lo = np.array(self.bounds[:2])
        hi = np.array(self.bounds[2:])
        return self._rng.uniform(lo, hi, size=(n, 2))


class GoalVectorSampler:
    """Goal-vector ray samples (plus an optional uniform fraction over a local window).

    The rays start at an *anchor*: the frontier with probability ``cfg.frontier_anchor_fraction``,
    a random tree node with ``cfg.tree_anchor_fraction``, else the start (the robot, as in the
    paper), so the goal vector is also re-cast from places the tree has already reached (around a
    wall, through a doorway).

    The frontier is chosen best-first: the tree node with the smallest
    ``distance to the goal + visit_penalty * visits``, where ``visits`` counts the samples cast
    from that node that brought the tree no closer to the goal (the node's extension was
    blocked, or only grew sideways). A node stuck against a wall therefore hands over to its
    neighbours along the wall and, in a dead end, to nodes farther back, instead of drawing every
    frontier sample into the wall. With ``cfg.adaptive_rays`` the fan cast from an anchor has the
    rays ``|k| <= initial_rays + visits // stall_samples``: rays from a fresh node point at the
    goal, and the fan widens as that node's samples keep failing. ``visit_penalty = 0`` keeps the
    frontier at the node nearest the goal; both anchor fractions 0, ``adaptive_rays=False`` and
    ``window_stall=0`` is the paper's sampler.

    When the whole tree stops getting nearer the goal (``cfg.window_stall`` samples in a row),
    the uniform fraction rises to ``cfg.stall_uniform_fraction`` and the local uniform window
    doubles its margin per further ``window_stall`` samples, up to the planner's bounds: a
    goal-directed sampler in a trap (a long detour, a door behind the robot) gets uniform
    sampling's Voronoi bias until the tree makes progress again.

    With a ``checker`` (and ``cfg.open_rays``) the sampler also looks at the map before casting:
    for each anchor it tests its rays in the order 0, -1, 1, -2, 2, ... and keeps the open ones
    (first ``cfg.open_step`` metres free), so the fan is the ``2 level + 1`` open rays nearest
    the goal direction; and it marches each open ray on the checker's distance transform to its
    first blocked point, drawing the distance along the ray only up to that point plus
    ``cfg.ray_overshoot``. A ray's test is done once per anchor (the anchor and goal are fixed
    during a plan), when the fan first needs it; random tree anchors stay blind unless
    ``cfg.open_tree_anchors``, and an anchor with ``cfg.open_visits`` fruitless samples falls
    back to the blind fan. Off by default: on the simulator maps it cuts iterations to the
    first solution but not time (``docs/planning.md``).

    Failure is observed, not told: the planner passes its tree to :meth:`sample`, and a sample
    whose iteration added no node nearer the goal than its anchor (by ``progress_min``) counts
    as a visit of that anchor. Random numbers are drawn in batches from the generator given to
    :meth:`reset`; the sampler is deterministic for a given generator and tree. If ``record`` is
    set, every sample is logged in ``self.log`` as ``(anchor (2,), ray k, t, lateral, dtheta)``
    (ray ``UNIFORM_RAY`` for uniform samples).
    """

    UNIFORM_RAY = -999
    batch = 256
    first_batch = 16

    def __init__(
        self,
        cfg: GoalVectorConfig | None = None,
        bounds: Bounds | None = None,
        record: bool = False,
        checker: CollisionChecker | None = None,
    ) -> None:
        self.cfg = cfg if cfg is not None else GoalVectorConfig()
        self.bounds = _check_bounds(bounds) if bounds is not None else None
        self.checker = checker
        self.record = record
        self.log: list[tuple[np.ndarray, int, float, float, float]] = []
        self.start = np.zeros(2)
        self.goal = np.zeros(2)
        self._gx = self._gy = 0.0
        self._rng: np.random.Generator | None = None
        self._k = self._n = 0
        ks = self.cfg.ray_offsets()
        w = self.cfg.ray_decay ** np.abs(ks).astype(np.float64)
        self._ks = ks.tolist()
        # cumulative ray weights for each number of open ray pairs L (rays |k| <= L)
        self._cdf = [
            (np.cumsum(w[: 2 * L + 1]) / w[: 2 * L + 1].sum()).tolist() for L in range(len(ks))
        ]
        # the same weights by rank for a fan of m open rays (m = 1 .. len(ks))
        self._cdf_open = [[1.0]] + [
            (np.cumsum(w[:m]) / w[:m].sum()).tolist() for m in range(1, len(ks) + 1)
        ]
        self._batch_next = self.first_batch
        self._alpha = math.radians(self.cfg.alpha_deg)
        self._spread = math.radians(self.cfg.angular_spread_deg)
        self._clear()

    def _clear(self) -> None:
        self.level = self.cfg.n_rays
        """Open ray pairs of the last ray sample (rays |k| <= level)."""
        self.best_index = 0
        """Tree node nearest the goal so far."""
        self.best_distance = math.inf
        self._mark = math.inf
        self.stall = 0
        """Samples since the tree last got nearer the goal by ``progress_min`` (0 once a node
        is within ``progress_min`` of the goal)."""
        self.anchor_index = -1
        """Tree node the last ray sample was cast from (-1: uniform sample, or no tree)."""
        self.h: list[float] = []
        """Distance to the goal of every tree node seen so far (index = node index)."""
        self.visits: list[int] = []
        """Per tree node: samples cast from it that brought the tree no closer to the goal."""
        self._xy: list[list[float]] = []
        self._heap: list[tuple[float, int]] = []
        self._seen = 0
        self._rays: dict[int, tuple[list[int], list[float], list[int]]] = {}
        """Per anchor: (positions in ``ks`` of its open rays found so far, their free extents,
        [next position to test])."""
        self.n_ray_tests = 0
        """Rays tested against the checker during this plan."""

    def reset(self, start: np.ndarray, goal: np.ndarray, rng: np.random.Generator) -> None:
        self._rng = rng
        self.start = np.asarray(start, dtype=np.float64).copy()
        self.goal = np.asarray(goal, dtype=np.float64).copy()
        self._gx, self._gy = self.goal.tolist()
        self._k = self._n = 0
        self._batch_next = self.first_batch
        self.log = []
        self._win = self._window(self.cfg.uniform_margin)
        self._clear()

    def _window(self, margin: float) -> tuple[float, float, float, float]:
        """Lower corner and size (x0, y0, w, h) of the local uniform window with this margin
        (plain floats: computed once per plan and on growth)."""
        sx, sy = self.start.tolist()
        gx, gy = self._gx, self._gy
        x0, y0 = min(sx, gx) - margin, min(sy, gy) - margin
        x1, y1 = max(sx, gx) + margin, max(sy, gy) + margin
        if self.bounds is not None:
            bx0, by0, bx1, by1 = self.bounds
            x0, y0 = min(max(x0, bx0), bx1), min(max(y0, by0), by1)
            x1, y1 = min(max(x1, bx0), bx1), min(max(y1, by0), by1)
        x1, y1 = max(x1, x0 + 1e-6), max(y1, y0 + 1e-6)
        return x0, y0, x1 - x0, y1 - y0

    @property
    def frontier(self) -> int:
        """The best-first frontier node: smallest ``h + visit_penalty * visits`` (0 if none)."""
        heap, pen = self._heap, self.cfg.visit_penalty
        while heap:
            score, i = heap[0]
            if score == self.h[i] + pen * self.visits[i]:
                return i
            heapq.heappop(heap)  # stale entry (the node was visited since)
        return 0

    def _refill(self) -> None:
        """Draw the next batch of random numbers: one generator call of (9, n) uniforms. The
        batch doubles from ``first_batch`` up to ``batch`` (short plans draw little)."""
        assert self._rng is not None, "call reset() first"
        cfg = self.cfg
        n = self._batch_next
        self._batch_next = min(2 * n, self.batch)
        u = self._rng.random((9, n))
        u[1] **= cfg.radial_power
        u[2] = (2.0 * u[2] - 1.0) * cfg.lateral_spread
        u[3] = (2.0 * u[3] - 1.0) * self._spread
        (
            self._ray_u,
            self._f,
            self._lat,
            self._jit,
            self._anchor_u,
            self._node_u,
            self._unif_u,
            self._ux,
            self._uy,
        ) = u.tolist()
        self._k, self._n = 0, n

    def sample(self, tree: Tree | None = None) -> np.ndarray:
        """One (2,) sample; ``tree`` (the planner's tree) enables tree anchors and the
        best-first frontier."""
        if self._k >= self._n:
            self._refill()
        k = self._k
        self._k += 1
        cfg = self.cfg
        if tree is not None:
            self._track(tree)
        elif not self.h:  # no tree: the start stands for node 0
            self._add_node(0, self.start.tolist())
        else:
            self._visit(self.anchor_index)
        if self.best_distance < self._mark - cfg.progress_min:
            self._mark = self.best_distance
            self.stall = 0
        elif self.best_distance > cfg.progress_min:  # (at the goal: refining, not stalled)
            self.stall += 1
        grow = self.stall // cfg.window_stall if cfg.window_stall > 0 else 0
        if self._unif_u[k] < (cfg.uniform_fraction if grow == 0 else cfg.stall_uniform_fraction):
            self.anchor_index = -1
            x = self._uniform(k, grow)
            if self.record:
                self.log.append((x.copy(), self.UNIFORM_RAY, 0.0, 0.0, 0.0))
            return x
        u = self._anchor_u[k]
        a = 0
        aware = self.checker is not None and cfg.open_rays
        if tree is not None and tree.n > 1:
            if u < cfg.frontier_anchor_fraction:
                a = self.frontier
            elif u < cfg.frontier_anchor_fraction + cfg.tree_anchor_fraction:
                a = int(self._node_u[k] * tree.n)
                aware = aware and cfg.open_tree_anchors
        aware = aware and self.visits[a] < cfg.open_visits
        self.anchor_index = a
        level = cfg.n_rays
        if cfg.adaptive_rays:
            init = cfg.open_initial_rays if aware else cfg.initial_rays
            level = min(level, init + self.visits[a] // cfg.stall_samples)
        self.level = level
        ax, ay = self._xy[a]
        dist = self.h[a]
        if dist > 1e-12:
            th = math.atan2(self._gy - ay, self._gx - ax)
        else:
            th = 0.0
        t_max = max(cfg.min_range, cfg.range_scale * dist)
        cdf = self._cdf[level]
        m = min(bisect.bisect_left(cdf, self._ray_u[k]), len(cdf) - 1)
        if aware:
            # rank m among the open rays nearest the goal direction (tested only up to rank m)
            pos, ext = self._open_fan(a, m + 1, ax, ay, th, t_max)
            if len(pos) <= m and pos:  # fewer open rays than the fan: draw among those
                cdf = self._cdf_open[len(pos)]
                m = min(bisect.bisect_left(cdf, self._ray_u[k]), len(cdf) - 1)
            if pos:
                ray = self._ks[pos[m]]
                t_max = min(t_max, ext[m] + cfg.ray_overshoot)
            else:  # no open ray from this anchor: the whole fan, blocked or not
                cdf = self._cdf[cfg.n_rays]
                ray = self._ks[min(bisect.bisect_left(cdf, self._ray_u[k]), len(cdf) - 1)]
        else:
            ray = self._ks[m]
        jit = self._jit[k]
        th += ray * self._alpha + jit
        t = self._f[k] * t_max
        lat = self._lat[k]
        c, s = math.cos(th), math.sin(th)
        x = np.array([ax + t * c - lat * s, ay + t * s + lat * c])
        if self.record:
            self.log.append((np.array([ax, ay]), ray, t, lat, jit))
        return x

    def _uniform(self, k: int, grow: int) -> np.ndarray:
        """Uniform sample k over the local window, its margin doubled ``grow`` times."""
        if grow == 0:
            x0, y0, w, h = self._win
        else:
            m = self.cfg.uniform_margin * 2.0 ** min(grow, 30)
            if self.bounds is None:
                m = min(m, 4.0 * self.cfg.uniform_margin)
            x0, y0, w, h = self._window(m)
        return np.array([x0 + self._ux[k] * w, y0 + self._uy[k] * h])

    def _open_fan(
        self, a: int, m: int, ax: float, ay: float, th: float, t_max: float
    ) -> tuple[list[int], list[float]]:
        """The first ``m`` open rays of anchor ``a`` (positions in ``ks``, i.e. nearest the
        goal direction first) and their free extents; fewer if the anchor has fewer."""
        st = self._rays.get(a)
        if st is None:
            st = self._rays[a] = ([], [], [0])
        pos, ext, nxt = st
        ks = self._ks
        cfg = self.cfg
        reach = t_max if cfg.ray_overshoot < math.inf else cfg.open_step
        while len(pos) < m and nxt[0] < len(ks):
            p = nxt[0]
            nxt[0] += 1
            a_th = th + ks[p] * self._alpha
            e = self._free_extent(ax, ay, math.cos(a_th), math.sin(a_th), reach)
            self.n_ray_tests += 1
            if e >= cfg.open_step:
                pos.append(p)
                ext.append(e)
        return pos[:m], ext[:m]

    def _free_extent(self, ax: float, ay: float, c: float, s: float, reach: float) -> float:
        """Distance along the ray (ax, ay) + t (c, s) to its first blocked cell (``inf`` if
        none up to ``reach``), marched on the checker's distance transform: from a point whose
        cell is ``d`` from the nearest obstacle, no blocked cell is nearer than
        ``d - inflation - 1.5 resolution`` (at least half a cell is stepped)."""
        ch = self.checker
        assert ch is not None
        blocked = ch.blocked
        nx, ny = blocked.shape
        if nx == 0:
            return math.inf
        dist = ch.dist
        r = ch.cfg.resolution
        ox, oy = int(ch.cell_offset[0]), int(ch.cell_offset[1])
        margin = ch.cfg.inflation + 1.5 * r
        far = ch.cfg.max_clearance - margin
        t = 0.0
        while t <= reach:
            i = math.floor((ax + t * c) / r) - ox
            j = math.floor((ay + t * s) / r) - oy
            if i < 0 or j < 0 or i >= nx or j >= ny:
                d = far  # unknown space beyond the grid: free, >= max_clearance from obstacles
            elif blocked[i, j]:
                return t
            else:
                d = float(dist[i, j]) - margin
            t += d if d > 0.5 * r else 0.5 * r
        return math.inf

    def _add_node(self, i: int, xy: list[float]) -> float:
        h = math.hypot(xy[0] - self._gx, xy[1] - self._gy)
        self._xy.append(xy)
        self.h.append(h)
        self.visits.append(0)
        heapq.heappush(self._heap, (h, i))
        if h < self.best_distance:
            self.best_index, self.best_distance = i, h
        return h

    def _visit(self, a: int) -> None:
        """One more fruitless sample cast from node ``a`` (raises its frontier score)."""
        if a < 0:
            return
        self.visits[a] += 1
        heapq.heappush(self._heap, (self.h[a] + self.cfg.visit_penalty * self.visits[a], a))

    def _track(self, tree: Tree) -> None:
        """Take in the nodes added since the last call; charge the last anchor a visit unless
        one of them got closer to the goal than the anchor (by ``progress_min``)."""
        n = tree.n
        a = self.anchor_index
        if n <= self._seen:
            self._visit(a)
            return
        h_min = math.inf
        xs, ys = tree.xs, tree.ys
        for i in range(self._seen, n):
            h_min = min(h_min, self._add_node(i, [xs[i], ys[i]]))
        self._seen = n
        if a >= 0 and not h_min < self.h[a] - self.cfg.progress_min:
            self._visit(a)
