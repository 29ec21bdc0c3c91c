"""OMPL's ``RRTstar`` as a reference baseline, judged by our :class:`CollisionChecker`.

The state space is ``RealVectorStateSpace(2)`` over the given bounds (planning frame x-y metres);
state validity is ``checker.is_free`` and motion validation is ``checker.segment_free`` (a Python
``MotionValidator``, so OMPL's own discretisation is not used). ``range`` is our step size. OMPL
chooses its own rewiring neighbourhood (k-nearest by default, or its shrinking radius capped at
``range``), so it cannot be given our fixed rewiring radius.

OMPL is optional (``pip install simn-sim[bench]``, ``ompl>=2.0``); constructing the planner without
it raises ImportError with that hint. OMPL's nanobind bindings may print reference-leak warnings
at interpreter exit; they are harmless.

Time to first solution. With ``stop_at_first_solution`` the objective's cost threshold is
infinite, so RRTstar ends its one ``solve`` call at the iteration that finds the first exact
solution: the time is exact (no slicing). Otherwise OMPL's intermediate-solution callback is not
usable from Python (the bindings do not convert a Python callable to its ``std::function``), so
the planner runs in slices of ``slice_ms`` (RRTstar keeps its tree between ``solve`` calls) and
the first slice that ends with an exact solution gives the time (resolution: one slice).

``simplify=True`` runs OMPL's own ``PathSimplifier.simplifyMax`` (vertex reduction,
shortcutting, B-spline smoothing, all through our motion validator) on the solution; the raw
tree path stays in ``raw_path`` and the simplifier's wall time in ``simplify_time_s``.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from simn_sim.config import Config, require
from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.rrt import PlanStats, check_endpoints
from simn_sim.planning.samplers import Bounds, _check_bounds
from simn_sim.planning.smoothing import path_length

_SEEDED = False


def _import_ompl():
    try:
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "OMPL is needed for OmplRRTStar: pip install 'simn-sim[bench]' (ompl>=2.0, nanobind "
            "bindings with `from ompl import base, geometric`)"
        ) from e
    return ob, og, ou


@dataclasses.dataclass(frozen=True)
class OmplRRTStarConfig(Config):
    """OMPL RRTstar settings (metres, milliseconds)."""

    range: float = 0.5
    """Maximum extension (OMPL ``setRange``), = our ``step_size``."""
    goal_bias: float = 0.05
    time_budget_ms: float = 200.0
    stop_at_first_solution: bool = False
    slice_ms: float = 1.0
    """Solve slice used to time the first solution of a budget run (a ``stop_at_first_solution``
    run solves in one call)."""
    k_nearest: bool = True
    """OMPL's default k-nearest rewiring; False = its radius rule (capped at ``range``)."""
    rewire_factor: float = 1.1
    simplify: bool = False
    """Run OMPL's PathSimplifier on the result (using our motion validator)."""
    quiet: bool = True
    """Silence OMPL's console log (warnings and errors still print)."""

    def validate(self) -> None:
        n = type(self).__name__
        require(math.isfinite(self.range) and self.range > 0, n, "range", "> 0")
        require(0 <= self.goal_bias < 1, n, "goal_bias", "in [0, 1)")
        require(
            math.isfinite(self.time_budget_ms) and self.time_budget_ms > 0,
            n,
            "time_budget_ms",
            "> 0",
        )
        require(math.isfinite(self.slice_ms) and self.slice_ms > 0, n, "slice_ms", "> 0")
        require(self.rewire_factor >= 1.0, n, "rewire_factor", ">= 1")


class OmplRRTStar:
    """OMPL RRTstar in R^2 with our collision checker.

    ``plan(start, goal) -> (M, 2) | None``; afterwards ``stats`` (a :class:`PlanStats`) holds
    the first-solution time and iterations, and ``planner_data`` OMPL's tree
    (``og.RRTstar.getPlannerData`` is wrapped as ``tree_xy`` (K, 2) node positions).
    """

    def __init__(
        self,
        checker: CollisionChecker,
        bounds: Bounds,
        cfg: OmplRRTStarConfig | None = None,
        seed: int | None = None,
    ) -> None:
        """``seed`` seeds OMPL's process-global RNG, which OMPL allows only once per process
        (later seeds are ignored), so OMPL runs are repeatable per process, not per call."""
        self._ob, self._og, self._ou = _import_ompl()
        self.checker = checker
        self.bounds = _check_bounds(bounds)
        self.cfg = cfg if cfg is not None else OmplRRTStarConfig()
        self.seed = seed
        self.stats = PlanStats()
        self.path: np.ndarray | None = None
        self.raw_path: np.ndarray | None = None
        self.simplify_time_s: float | None = None
        self.tree_xy = np.zeros((0, 2))

    def _space_information(self):
        ob = self._ob
        checker = self.checker
        space = ob.RealVectorStateSpace(2)
        b = ob.RealVectorBounds(2)
        b.setLow(0, self.bounds[0])
        b.setLow(1, self.bounds[1])
        b.setHigh(0, self.bounds[2])
        b.setHigh(1, self.bounds[3])
        space.setBounds(b)
        si = ob.SpaceInformation(space)

        # the scalar calls our planners use (same answers as is_free / segment_free)
        is_free_point, segment_free_xy = checker.is_free_point, checker.segment_free_xy

        class _Valid(ob.StateValidityChecker):
            def isValid(self, s) -> bool:  # noqa: N802 - OMPL API
                return is_free_point(s[0], s[1])

        class _Motion(ob.MotionValidator):
            def checkMotion(self, s1, s2, *args) -> bool:  # noqa: N802 - OMPL API
                return segment_free_xy(s1[0], s1[1], s2[0], s2[1])

        # keep Python-side references alive for the lifetime of si
        self._validity, self._motion = _Valid(si), _Motion(si)
        si.setStateValidityChecker(self._validity)
        si.setMotionValidator(self._motion)
        si.setup()
        return si

    def plan(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """Plan from ``start`` (2,) to ``goal`` (2,); same input checks as :class:`RRTStar`."""
        ob, og, ou = self._ob, self._og, self._ou
        start, goal = check_endpoints(self.checker, start, goal)
        cfg = self.cfg
        if cfg.quiet:
            ou.setLogLevel(ou.LOG_WARN)
        global _SEEDED
        if self.seed is not None and not _SEEDED:
            # OMPL's RNG seed is process-global and can only be set before the first sample
            ou.RNG.setSeed(int(self.seed))
            _SEEDED = True
        si = self._space_information()
        st = self.stats = PlanStats()
        self.path = self.raw_path = None
        self.simplify_time_s = None
        # timed from the problem set-up on, as RRTStar times from its begin()
        t0 = time.perf_counter()
        s, g = si.allocState(), si.allocState()
        s[0], s[1] = float(start[0]), float(start[1])
        g[0], g[1] = float(goal[0]), float(goal[1])
        pdef = ob.ProblemDefinition(si)
        pdef.setStartAndGoalStates(s, g)
        obj = ob.PathLengthOptimizationObjective(si)
        if cfg.stop_at_first_solution:
            # any exact solution satisfies the objective: RRTstar returns at the first one
            obj.setCostThreshold(ob.Cost(math.inf))
        pdef.setOptimizationObjective(obj)
        pl = og.RRTstar(si)
        pl.setRange(cfg.range)
        pl.setGoalBias(cfg.goal_bias)
        pl.setKNearest(cfg.k_nearest)
        pl.setRewireFactor(cfg.rewire_factor)
        pl.setProblemDefinition(pdef)
        pl.setup()
        budget = cfg.time_budget_ms * 1e-3
        if cfg.stop_at_first_solution:
            pl.solve(budget)
            if pdef.hasExactSolution():
                st.first_solution_time_s = time.perf_counter() - t0
                st.first_solution_iteration = int(pl.numIterations())
                st.first_solution_cost = float(pdef.getSolutionPath().length())
        while not cfg.stop_at_first_solution:
            left = budget - (time.perf_counter() - t0)
            if left <= 0:
                break
            pl.solve(min(cfg.slice_ms * 1e-3, left))
            if st.first_solution_time_s is None and pdef.hasExactSolution():
                st.first_solution_time_s = time.perf_counter() - t0
                st.first_solution_iteration = int(pl.numIterations())
                st.first_solution_cost = float(pdef.getSolutionPath().length())
        st.iterations = int(pl.numIterations())
        if pdef.hasExactSolution():
            p = pdef.getSolutionPath()
            xy = np.array([[p.getState(i)[0], p.getState(i)[1]] for i in range(p.getStateCount())])
            self.raw_path = xy
            st.cost = path_length(xy)
            if cfg.simplify:
                t1 = time.perf_counter()
                og.PathSimplifier(si, pdef.getGoal(), obj).simplifyMax(p)
                self.simplify_time_s = time.perf_counter() - t1
                xy = np.array(
                    [[p.getState(i)[0], p.getState(i)[1]] for i in range(p.getStateCount())]
                )
            self.path = xy
            st.smoothed_cost = path_length(xy)
        data = ob.PlannerData(si)
        pl.getPlannerData(data)
        self.tree_xy = np.array(
            [
                [data.getVertex(i).getState()[0], data.getVertex(i).getState()[1]]
                for i in range(data.numVertices())
            ]
        ).reshape(-1, 2)
        st.n_nodes = len(self.tree_xy)
        st.time_s = time.perf_counter() - t0
        return None if self.path is None else self.path.copy()
