"""The navigator's cost-to-go on its own map: what is around the goal-vector RRT*.

:class:`CostMap` is a Dijkstra field from the goal over a grid of the agent's map, in which a
metre costs

- ``1`` in known free space (cells within ``known_radius`` of a seen floor point or of the
  driven path),
- ``unknown_weight`` in space never seen (it may hide a wall: a route through it is a guess),
- times ``margin_weight`` inside the planning margin (free only under the tight safety margin:
  a narrow doorway whose jambs depth noise has thickened stays passable, at a price),

and cells blocked under the safety margin are impassable, but for those blocked only by
transient obstacles (given a ``static`` safety model without them, and ``transient_weight`` > 0):
a person is there for seconds, so a route through them costs ``transient_weight`` per metre (the
wait) instead of closing the way. The path follower still stops at them. The field gives:

- ``cost_to_go(xy)``: the path length to the goal on the agent's own map, weighted as above
  (the lost-progress measure);
- ``path(xy)``: the field's own route to the goal (one homotopy class, always available while
  the goal is reachable on the map);
- ``path_cost(path)``: any candidate path judged on the same weights (a committed path,
  re-judged every planning cycle against the current map; a fresh RRT* plan; the field's
  route), plus the cost-to-go from its end when it ends short of the goal.

Exact on its grid: in known free space with no margins, ``cost_to_go`` is the 8-connected
grid geodesic (within ``resolution`` x (sqrt(2) - 1) per diagonal turn of the true one).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage
from skimage.graph import MCP_Geometric

from simn_sim.config import Config, require
from simn_sim.planning.collision import CollisionChecker


@dataclasses.dataclass(frozen=True)
class CostMapConfig(Config):
    """resolution: grid cell (m). pad: the grid spans the robot, the goal and the mapped
    obstacles padded by this (m). unknown_weight: cost per metre in never-seen space relative
    to known free space (1: unknown space is free, the old behaviour). margin_weight: cost
    multiplier inside the planning margin (free only under the safety margin). known_radius: a
    cell is known within this distance (m) of a seen floor point or the driven path.
    goal_snap: when the goal cell is blocked, cells within this distance (m) of it serve as
    goal. transient_weight: see the field's comment."""

    resolution: float = 0.1
    pad: float = 3.0
    unknown_weight: float = 2.0
    margin_weight: float = 4.0
    known_radius: float = 0.2
    goal_snap: float = 0.5
    # path_cost also applies the path follower's exact segment test (segments_free); off: the
    # 5 cm samples only (office_nav_v2: see docs/navigation.md, "A plan the follower refuses")
    exact_segments: bool = False
    # cost per metre through cells blocked only by transient obstacles (a person: wait for
    # them); 0: they block like any obstacle. Acts only with transient cells on (the static
    # safety model of simn_sim.world.obstacles)
    transient_weight: float = 0.0

    def validate(self) -> None:
        n = type(self).__name__
        require(0.02 <= self.resolution <= 0.5, n, "resolution", "must be in [0.02, 0.5] m")
        require(self.pad >= 0, n, "pad", "must be >= 0")
        require(self.unknown_weight >= 1, n, "unknown_weight", "must be >= 1")
        require(self.margin_weight >= 1, n, "margin_weight", "must be >= 1")
        require(self.known_radius >= 0, n, "known_radius", "must be >= 0")
        require(self.goal_snap >= 0, n, "goal_snap", "must be >= 0")
        require(
            self.transient_weight == 0 or self.transient_weight >= 1,
            n,
            "transient_weight",
            "must be 0 (off) or >= 1",
        )


class CostMap:
    """A cost-to-go field to one goal on one snapshot of the map (see the module docstring).
    Build a new one when the map or the goal changes; ``reachable`` says whether the goal could
    be reached from anywhere on the grid at all."""

    def __init__(
        self,
        cfg: CostMapConfig,
        safety: CollisionChecker,
        planning: CollisionChecker | None,
        goal: np.ndarray,
        robot_xy: np.ndarray,
        known_xy: np.ndarray | None = None,
        static: CollisionChecker | None = None,
    ) -> None:
        self.cfg = cfg
        self.safety = safety
        # the safety model without transient obstacles; None: nothing is soft
        self.static = static if cfg.transient_weight > 0 else None
        self.goal = np.asarray(goal, float).reshape(2)
        robot_xy = np.asarray(robot_xy, float).reshape(2)
        r = cfg.resolution
        lo = np.minimum(robot_xy, self.goal) - cfg.pad
        hi = np.maximum(robot_xy, self.goal) + cfg.pad
        b = safety.obstacle_bounds()
        if b is not None:
            lo = np.minimum(lo, np.array(b[:2]) - 1.0)
            hi = np.maximum(hi, np.array(b[2:]) + 1.0)
        self.lo = lo
        self.nx = int(math.ceil((hi[0] - lo[0]) / r)) + 1
        self.ny = int(math.ceil((hi[1] - lo[1]) / r)) + 1
        ix, iy = np.meshgrid(np.arange(self.nx), np.arange(self.ny), indexing="ij")
        self.centres = np.c_[lo[0] + r * ix.ravel(), lo[1] + r * iy.ravel()]
        free = safety.is_free(self.centres).reshape(self.nx, self.ny)
        wide = (
            planning.is_free(self.centres).reshape(self.nx, self.ny)
            if planning is not None
            else np.ones_like(free)
        )
        known = np.zeros((self.nx, self.ny), bool)
        if known_xy is not None and len(known_xy):
            ij = np.floor((np.asarray(known_xy, float)[:, :2] - lo) / r + 0.5).astype(np.int64)
            ok = (ij[:, 0] >= 0) & (ij[:, 0] < self.nx) & (ij[:, 1] >= 0) & (ij[:, 1] < self.ny)
            known[ij[ok, 0], ij[ok, 1]] = True
            k = int(round(cfg.known_radius / r))
            if k > 0:
                yy, xx = np.mgrid[-k : k + 1, -k : k + 1]
                known = ndimage.binary_dilation(known, structure=(xx**2 + yy**2) <= k * k)
        self.free = free
        self.known = known
        w = np.where(known, 1.0, cfg.unknown_weight) * np.where(wide, 1.0, cfg.margin_weight)
        self.weight = np.where(free, w, np.inf)
        if self.static is not None:
            # blocked only by transient obstacles: passable at the wait's price
            soft = ~free & self.static.is_free(self.centres).reshape(self.nx, self.ny)
            self.weight[soft] = cfg.transient_weight
            self.free = free | soft
        self.dist = self._solve()

    # ---- the field ---------------------------------------------------------------------------
    def _idx(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return i * self.ny + j

    def _solve(self) -> np.ndarray:
        """Dijkstra from the goal cells over the 8-connected grid (scikit-image's minimum-cost
        path: a step costs the mean of its two cells' weights times its length)."""
        self._src = self._goal_cells()
        if len(self._src) == 0:
            self._mcp = None
            return np.full((self.nx, self.ny), np.inf)
        r = self.cfg.resolution
        self._mcp = MCP_Geometric(self.weight * r, fully_connected=True)
        starts = [divmod(int(k), self.ny) for k in self._src]
        d, _ = self._mcp.find_costs(starts)
        return np.where(self.free, d, np.inf)

    def _goal_cells(self) -> np.ndarray:
        g = self.goal
        d = np.hypot(*(self.centres - g).T)
        near = np.flatnonzero((d <= self.cfg.resolution) & self.free.ravel())
        if len(near) == 0:
            near = np.flatnonzero((d <= self.cfg.goal_snap) & self.free.ravel())
            if len(near):
                near = near[[int(np.argmin(d[near]))]]
        return near

    @property
    def reachable(self) -> bool:
        return bool(np.isfinite(self.dist).any())

    def _entry(self, xy: np.ndarray, radius: float = 0.4) -> tuple[int, float]:
        """The free cell near ``xy`` with the least (distance to it + its cost-to-go), and that
        total; (-1, inf) when none is finite."""
        r = self.cfg.resolution
        c = np.floor((np.asarray(xy, float) - self.lo) / r + 0.5).astype(int)
        k = int(math.ceil(radius / r))
        i0, i1 = max(c[0] - k, 0), min(c[0] + k + 1, self.nx)
        j0, j1 = max(c[1] - k, 0), min(c[1] + k + 1, self.ny)
        if i0 >= i1 or j0 >= j1:
            return -1, math.inf
        ii, jj = np.meshgrid(np.arange(i0, i1), np.arange(j0, j1), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        cen = self.lo + r * np.c_[ii, jj]
        dd = np.hypot(*(cen - xy).T)
        with np.errstate(invalid="ignore"):
            tot = self.dist[ii, jj] + dd * self.weight[ii, jj]
        tot[(dd > radius) | ~np.isfinite(tot)] = np.inf
        m = int(np.argmin(tot))
        if not np.isfinite(tot[m]):
            return -1, math.inf
        return int(self._idx(ii[m], jj[m])), float(tot[m])

    def cost_to_go(self, xy: np.ndarray) -> float:
        """Weighted path length (m) from ``xy`` to the goal on the map; inf if unreachable."""
        return self._entry(np.asarray(xy, float).reshape(2))[1]

    def path(self, xy: np.ndarray) -> np.ndarray | None:
        """(M, 2) the field's route from ``xy`` to the goal (cell centres, steepest descent),
        or None when the goal is unreachable from ``xy``."""
        xy = np.asarray(xy, float).reshape(2)
        k, _ = self._entry(xy)
        if k < 0 or self._mcp is None:
            return None
        cells = np.asarray(self._mcp.traceback(divmod(k, self.ny)))[::-1]
        return np.vstack([xy, self.lo + self.cfg.resolution * cells, self.goal])

    def path_cost(self, path: np.ndarray, spacing: float = 0.05) -> float:
        """Weighted length of ``path`` (M, 2) plus the cost-to-go from its last vertex (0 at the
        goal); inf when any point of it is blocked under the safety margin (with
        ``exact_segments``: when any segment passes a blocked cell)."""
        p = np.asarray(path, float)
        if len(p) < 2:
            return self.cost_to_go(p[0]) if len(p) else math.inf
        seg = np.diff(p, axis=0)
        L = np.hypot(*seg.T)
        n = np.maximum(np.ceil(L / spacing).astype(int), 1)
        t = np.concatenate([(np.arange(m) + 0.5) / m for m in n])
        a = np.repeat(p[:-1], n, axis=0)
        d = np.repeat(seg, n, axis=0)
        q = a + t[:, None] * d
        # exact_segments: the grid traversal (the path follower's test); a diagonal step between
        # two free cells can pass a blocked cell between the samples
        blocked = ~self.safety.is_free(q)
        if self.static is not None and blocked.any():
            blocked &= ~self.static.is_free(q)  # transient obstacles are priced, not walls
        if blocked.any() or (
            self.cfg.exact_segments and not self.safety.segments_free(p[:-1], p[1:]).all()
        ):
            return math.inf
        r = self.cfg.resolution
        ij = np.floor((q - self.lo) / r + 0.5).astype(int)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.nx) & (ij[:, 1] >= 0) & (ij[:, 1] < self.ny)
        wq = np.full(len(q), self.cfg.unknown_weight)
        wi = self.weight[ij[inside, 0], ij[inside, 1]]
        # a cell blocked on the grid but free at the exact point: weigh it as the margin
        wq[inside] = np.where(np.isfinite(wi), wi, self.cfg.unknown_weight * self.cfg.margin_weight)
        cost = float(np.sum(wq * np.repeat(L / n, n)))
        end = p[-1]
        if np.hypot(*(end - self.goal)) <= self.cfg.resolution:
            return cost
        return cost + self.cost_to_go(end)
