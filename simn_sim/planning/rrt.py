"""RRT* core shared by SIMN's goal-vector planner and the uniform-sampling baseline.

The two planners differ only in the sampler (:mod:`simn_sim.planning.samplers`); step size,
budget, rewiring radius, goal bias and the collision checker are the same object/config, so a
comparison between them measures the sampler alone.

Everything is in the planning frame (x-y metres). After :meth:`RRTStar.plan` the tree
(``planner.tree``: nodes, parents, costs, children) and the statistics (``planner.stats``) stay
available for inspection, plotting and tests.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from simn_sim.config import Config, require
from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.samplers import (
    Bounds,
    GoalVectorConfig,
    GoalVectorSampler,
    Sampler,
    UniformSampler,
)
from simn_sim.planning.smoothing import path_length, shortcut_path
from simn_sim.planning.tree import Tree


@dataclasses.dataclass(frozen=True)
class RRTStarConfig(Config):
    """RRT* parameters shared by all samplers (metres, milliseconds)."""

    step_size: float = 0.5
    """Maximum extension per iteration (steer distance)."""
    rewire_radius: float = 1.0
    """Choose-parent / rewiring neighbourhood radius (fixed)."""
    max_neighbours: int = 30
    """At most this many nearest nodes inside the radius are considered."""
    goal_bias: float = 0.05
    """Probability of sampling the goal itself."""
    goal_tolerance: float = 1e-6
    """The goal is reached when a node is inserted this close to it."""
    max_iterations: int = 5000
    """Iteration budget (one sample per iteration)."""
    time_budget_ms: float = 200.0
    """Wall-clock budget; 0 = iterations only."""
    stop_at_first_solution: bool = False
    """Return as soon as the goal is reached instead of improving until the budget."""
    shortcut: bool = True
    """Post-process the returned path with shortcut smoothing (the raw tree path is kept)."""
    shortcut_iterations: int = 50

    def validate(self) -> None:
        n = type(self).__name__
        require(math.isfinite(self.step_size) and self.step_size > 0, n, "step_size", "> 0")
        require(
            math.isfinite(self.rewire_radius) and self.rewire_radius >= self.step_size,
            n,
            "rewire_radius",
            ">= step_size",
        )
        require(self.max_neighbours >= 1, n, "max_neighbours", ">= 1")
        require(0 <= self.goal_bias < 1, n, "goal_bias", "in [0, 1)")
        require(self.goal_tolerance >= 0, n, "goal_tolerance", ">= 0")
        require(self.max_iterations >= 1, n, "max_iterations", ">= 1")
        require(
            math.isfinite(self.time_budget_ms) and self.time_budget_ms >= 0,
            n,
            "time_budget_ms",
            ">= 0",
        )
        require(self.shortcut_iterations >= 0, n, "shortcut_iterations", ">= 0")


@dataclasses.dataclass
class PlanStats:
    """What one :meth:`RRTStar.plan` call did."""

    iterations: int = 0
    time_s: float = 0.0
    first_solution_iteration: int | None = None
    first_solution_time_s: float | None = None
    first_solution_cost: float | None = None
    cost: float | None = None
    """Cost (length) of the raw tree path to the goal at the end."""
    smoothed_cost: float | None = None
    n_nodes: int = 0
    n_rewires: int = 0
    n_collision_rejects: int = 0


def _as_xy(x: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.shape != (2,):
        raise ValueError(f"{name}: expected an x-y pair, got shape {np.shape(x)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: not finite: {a}")
    return a


def check_endpoints(checker: CollisionChecker, start, goal) -> tuple[np.ndarray, np.ndarray]:
    """Finite (2,) start and goal, both free under ``checker``; else ValueError naming which."""
    start = _as_xy(start, "start")
    goal = _as_xy(goal, "goal")
    free = checker.is_free(np.stack([start, goal]))
    if not free[0]:
        raise ValueError(f"start {start} is in collision")
    if not free[1]:
        raise ValueError(f"goal {goal} is in collision")
    return start, goal


class RRTStar:
    """RRT* with a pluggable sampler (pyroboplan-style planner object).

    Args:
        checker: collision model; the same instance should judge every planner.
        sampler: :class:`GoalVectorSampler`, :class:`UniformSampler` or anything with
            ``reset(start, goal, rng)`` / ``sample()``.
        cfg: :class:`RRTStarConfig`.
        rng: explicit generator; each plan() draws from it (same seed -> same plan).
    """

    def __init__(
        self,
        checker: CollisionChecker,
        sampler: Sampler,
        cfg: RRTStarConfig | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.checker = checker
        self.sampler = sampler
        self.cfg = cfg if cfg is not None else RRTStarConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.tree: Tree | None = None
        self.goal_index: int | None = None
        self.raw_path: np.ndarray | None = None
        self.path: np.ndarray | None = None
        self.stats = PlanStats()
        self._it = 0
        self._busy_s = 0.0

    # ------------------------------------------------------------------ core steps
    def _insert(self, x_new: np.ndarray, extra: int = -1, d_extra: float = math.inf) -> int:
        """Choose-parent + add + rewire for a collision-free point; returns index or -1.

        ``extra`` (at distance ``d_extra`` from ``x_new``, if known) is always a candidate
        parent, even if it is not within the rewiring radius. Plain Python on the tree's
        lists: a neighbourhood holds a few dozen nodes at most, where NumPy's per-call cost
        dominates."""
        tree = self.tree
        assert tree is not None
        cfg = self.cfg
        radius = cfg.rewire_radius
        xn, yn = float(x_new[0]), float(x_new[1])
        xs, ys, costs = tree.xs, tree.ys, tree.costs
        near, d = tree.near_dist(xn, yn, radius)
        if isinstance(near, np.ndarray):  # dense part of the tree
            return self._insert_dense(x_new, near, d, extra, d_extra)
        if extra >= 0 and not d_extra < radius * (1.0 - 1e-9) and extra not in near:
            near.append(extra)
            d.append(math.hypot(xs[extra] - xn, ys[extra] - yn))
        if not near:
            return -1
        if len(near) > cfg.max_neighbours:
            sel = sorted(range(len(near)), key=d.__getitem__)[: cfg.max_neighbours]
            sel.sort()
            near = [near[m] for m in sel]
            d = [d[m] for m in sel]
        c = [costs[j] + dj for j, dj in zip(near, d, strict=True)]
        seg_free = self.checker.segment_free_xy
        k = self._first_free_parent(sorted(range(len(c)), key=c.__getitem__), near, xn, yn)
        if k < 0:
            return -1
        i_new = tree.add(x_new, near[k], d[k])
        c_new = costs[i_new]
        # rewire: neighbours that become cheaper through the new node (edge checked only then;
        # costs are read as they are now: an earlier rewire in this loop may have lowered them)
        for m, j in enumerate(near):
            if m != k and c_new + d[m] < costs[j] - 1e-12 and seg_free(xn, yn, xs[j], ys[j]):
                tree.rewire(j, i_new, d[m])
        return i_new

    def _first_free_parent(self, order: list[int], near: list[int], xn: float, yn: float) -> int:
        """Choose-parent, lazily: the first candidate ``m`` in ``order`` (cheapest cost-through
        first) whose edge from node ``near[m]`` to (xn, yn) is free; -1 if none is."""
        xs, ys = self.tree.xs, self.tree.ys
        seg_free = self.checker.segment_free_xy
        for m in order:
            j = near[m]
            if seg_free(xs[j], ys[j], xn, yn):
                return m
        return -1

    def _insert_dense(
        self, x_new: np.ndarray, near: np.ndarray, d: np.ndarray, extra: int, d_extra: float
    ) -> int:
        """:meth:`_insert` with the neighbourhood in arrays (many nodes nearby)."""
        tree = self.tree
        assert tree is not None
        cfg = self.cfg
        xn, yn = float(x_new[0]), float(x_new[1])
        xs, ys, costs = tree.xs, tree.ys, tree.costs
        if (
            extra >= 0
            and not d_extra < cfg.rewire_radius * (1.0 - 1e-9)
            and not np.any(near == extra)
        ):
            near = np.append(near, extra)
            d = np.append(d, math.hypot(xs[extra] - xn, ys[extra] - yn))
        if len(near) == 0:
            return -1
        if len(near) > cfg.max_neighbours:
            sel = np.sort(np.argpartition(d, cfg.max_neighbours - 1)[: cfg.max_neighbours])
            near, d = near[sel], d[sel]
        c = tree.cost[near] + d
        seg_free = self.checker.segment_free_xy
        near_l, d_l = near.tolist(), d.tolist()
        k = self._first_free_parent(np.argsort(c, kind="stable").tolist(), near_l, xn, yn)
        if k < 0:
            return -1
        i_new = tree.add(x_new, near_l[k], d_l[k])
        c_new = costs[i_new]
        for m in np.nonzero(c_new + d < tree.cost[near] - 1e-12)[0].tolist():
            j = near_l[m]
            if m != k and c_new + d_l[m] < costs[j] - 1e-12 and seg_free(xn, yn, xs[j], ys[j]):
                tree.rewire(j, i_new, d_l[m])
        return i_new

    def plan(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Plan from ``start`` (2,) to ``goal`` (2,) in the planning frame.

        Returns the (M, 2) path (shortcut-smoothed if ``cfg.shortcut``), first row = start,
        last row = goal, or None if no solution within the budget. Raises ValueError for
        non-finite inputs or a start/goal in collision. Same as :meth:`begin`, then
        :meth:`iterate` until :attr:`done`, then :meth:`finish`.
        """
        self.begin(start, goal)
        self.iterate(self.cfg.max_iterations)
        return self.finish()

    # ------------------------------------------------------------------ anytime interface
    def begin(self, start: np.ndarray, goal: np.ndarray) -> None:
        """Start a plan: a new tree at ``start``; grow it with :meth:`iterate` (possibly over
        several control steps), then :meth:`finish`. The same calls with the same rng give
        the same tree however the iterations are split."""
        start, goal = check_endpoints(self.checker, start, goal)
        self._start, self._goal = start, goal
        self._t0 = time.perf_counter()
        self._busy_s = 0.0
        self._it = 0
        self._coin = np.zeros(0)  # goal-bias coins, drawn in batches as iterations go
        self.sampler.reset(start, goal, self.rng)
        self.tree = tree = Tree(start, cell_size=self.cfg.rewire_radius)
        self.goal_index = None
        self.raw_path = self.path = None
        st = self.stats = PlanStats()
        if np.hypot(*(goal - start)) <= self.cfg.step_size and self.checker.segment_free(
            start, goal
        ):
            self.goal_index = tree.add(goal, 0, float(np.hypot(*(goal - start))))
            st.first_solution_iteration = 0
            st.first_solution_time_s = time.perf_counter() - self._t0
            st.first_solution_cost = float(tree.cost[self.goal_index])
        self._busy_s += time.perf_counter() - self._t0

    @property
    def done(self) -> bool:
        """The budget is spent (iterations or, when set, the wall-clock budget of the time
        spent inside :meth:`begin` / :meth:`iterate`), or a first solution was found with
        ``stop_at_first_solution``."""
        cfg = self.cfg
        if self._it >= cfg.max_iterations:
            return True
        if self.goal_index is not None and cfg.stop_at_first_solution:
            return True
        return cfg.time_budget_ms > 0 and self._busy_s * 1e3 >= cfg.time_budget_ms

    def iterate(self, n: int) -> bool:
        """Run up to ``n`` more iterations (fewer if the budget runs out); returns :attr:`done`."""
        if self.tree is None:
            raise RuntimeError("call begin() before iterate()")
        cfg = self.cfg
        rng = self.rng
        tree = self.tree
        goal = self._goal
        st = self.stats
        step = cfg.step_size
        gx, gy = goal.tolist()
        is_free = self.checker.is_free_point
        t_in = time.perf_counter()
        deadline = (
            t_in + (cfg.time_budget_ms * 1e-3 - self._busy_s)
            if cfg.time_budget_ms > 0
            else math.inf
        )
        stop = min(cfg.max_iterations, self._it + int(n))
        while self._it < stop:
            if self.goal_index is not None and cfg.stop_at_first_solution:
                break
            if time.perf_counter() > deadline:
                break
            self._it += 1
            it = self._it
            if (it - 1) % 256 == 0:
                self._coin = rng.random(256)
            if self._coin[(it - 1) % 256] < cfg.goal_bias and self.goal_index is None:
                x_rand = goal
            else:
                x_rand = self.sampler.sample(tree)
            i_near, d_near = tree.index.nearest(x_rand)
            if d_near < 1e-9:
                continue
            if d_near > step:
                x_near = tree.xy[i_near]
                x_new = x_near + (x_rand - x_near) * (step / d_near)
                d_new = step
            else:
                x_new = np.array(x_rand, dtype=np.float64)
                d_new = d_near
            xn, yn = x_new.tolist()
            if not is_free(xn, yn):
                st.n_collision_rejects += 1
                continue
            i_new = self._insert(x_new, i_near, d_new)
            if i_new < 0:
                st.n_collision_rejects += 1
                continue
            if self.goal_index is None:
                dg = math.hypot(gx - xn, gy - yn)
                if dg <= cfg.goal_tolerance:
                    self.goal_index = i_new
                elif dg <= step:
                    g = self._insert(goal.copy(), i_new, dg)
                    if g >= 0:
                        self.goal_index = g
                if self.goal_index is not None:
                    st.first_solution_iteration = it
                    st.first_solution_time_s = self._busy_s + time.perf_counter() - t_in
                    st.first_solution_cost = float(tree.cost[self.goal_index])
        self._busy_s += time.perf_counter() - t_in
        return self.done

    def finish(self) -> np.ndarray | None:
        """The path of the current tree (shortcut-smoothed if ``cfg.shortcut``) or None."""
        if self.tree is None:
            raise RuntimeError("call begin() before finish()")
        cfg = self.cfg
        tree = self.tree
        st = self.stats
        t = time.perf_counter()
        st.iterations = self._it
        st.n_nodes = len(tree)
        st.n_rewires = tree.n_rewires
        self.raw_path = self.path = None
        if self.goal_index is not None:
            self.raw_path = tree.path_to(self.goal_index)
            self.raw_path[-1] = self._goal
            st.cost = float(tree.cost[self.goal_index])
            if cfg.shortcut:
                self.path = shortcut_path(
                    self.raw_path, self.checker, self.rng, cfg.shortcut_iterations
                )
            else:
                self.path = self.raw_path.copy()
            st.smoothed_cost = path_length(self.path)
        self._busy_s += time.perf_counter() - t
        st.time_s = self._busy_s
        return None if self.path is None else self.path.copy()


def goal_vector_rrt_star(
    checker: CollisionChecker,
    cfg: RRTStarConfig | None = None,
    gv_cfg: GoalVectorConfig | None = None,
    bounds: Bounds | None = None,
    rng: np.random.Generator | None = None,
) -> RRTStar:
    """SIMN's planner: RRT* with goal-vector ray sampling (``bounds`` only feed the optional
    uniform fraction; unknown space beyond the map is free). The sampler sees the same
    ``checker`` to cast its rays only where they are open (``GoalVectorConfig.open_rays``)."""
    return RRTStar(checker, GoalVectorSampler(gv_cfg, bounds, checker=checker), cfg, rng)


def uniform_rrt_star(
    checker: CollisionChecker,
    bounds: Bounds,
    cfg: RRTStarConfig | None = None,
    rng: np.random.Generator | None = None,
) -> RRTStar:
    """Baseline: RRT* with uniform sampling over ``bounds`` (same core, checker and config)."""
    return RRTStar(checker, UniformSampler(bounds), cfg, rng)
