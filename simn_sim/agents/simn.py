"""``simn`` and ``rrtstar`` agents: the SIMN pipeline in the closed loop.

The agent is a policy over a world model (:mod:`simn_sim.world`), a planner and a follower.
One control step (``act``), in the agent's own frame (the episode start frame, z up, the floor at
z = 0; the goal and the odometry arrive in it):

1. bumps: commanded forward motion that the wheel odometry does not show adds an obstacle arc
   ahead of the hull (:mod:`simn_sim.agents.recovery`);
2. world model: perceive -> track -> integrate -> topology (``pose_source: slam``, the method)
   or the odometry pose with the same perception and stores (``odometry``, the ablation);
3. recovery when the robot is inside the mapped obstacles or the safety margin;
4. an initial look-around (``initial_scan_deg``), then planning: topological guidance (a
   sub-goal on the route over the local frames, :mod:`simn_sim.agents.guidance`), then
   goal-vector RRT* (``simn``) or uniform RRT* (``rrtstar``) on the world's obstacle view, on a
   replanning schedule (sliced over steps) or when the follower reports the path blocked or
   stale; a budget-exhausted RRT* falls back to a grid search (counted);
5. control: pure pursuit -> ``[v, w]`` within the env's action bounds.

The agent never reads the true pose and never branches on how its world model makes the pose.
A failed plan or a lost track does not end the episode: the agent reports its state
(``state()``) and keeps acting (turning in place to look around when it has no plan).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np

from simn_sim.agents.base import register_agent
from simn_sim.agents.guidance import topo_subgoal
from simn_sim.agents.recovery import (
    BumpDetector,
    NoRouteWatch,
    ProgressWatch,
    back_off,
    nearest_free,
)
from simn_sim.agents.routes import field_route, make_planner, squeezed_checker, tree_edges
from simn_sim.agents.simn_config import SimnAgentConfig, points_ablation_config
from simn_sim.geometry.paths import path_length
from simn_sim.geometry.se3 import inv_T, planar_T, yaw_of
from simn_sim.planning import PathFollower
from simn_sim.planning.costmap import CostMap
from simn_sim.planning.gridpath import grid_shortest_path
from simn_sim.planning.smoothing import push_from_obstacles
from simn_sim.world import WorldModel, make_world


@dataclasses.dataclass
class PlanJob:
    """An RRT* plan begun at ``xy`` (``start``: the nearest free point) towards ``goal``."""

    planner: Any
    xy: np.ndarray
    start: np.ndarray
    goal: np.ndarray


class SimnAgent:
    """The SIMN navigation agent (``planner="goal_vector"``) and its RRT* baseline
    (``planner="uniform"``); see the module docstring."""

    def __init__(
        self, env: Any, config: dict[str, Any] | SimnAgentConfig | None = None, name: str = "simn"
    ):
        self.cfg = (
            config if isinstance(config, SimnAgentConfig) else SimnAgentConfig.from_dict(config)
        )
        self.name = name
        lo, hi = env.action_space.low, env.action_space.high
        f = self.cfg.follower
        self.follower_cfg = f.replace(
            v_min=max(f.v_min, float(lo[0])),
            v_max=min(f.v_max, float(hi[0])),
            w_min=max(f.w_min, float(lo[1])),
            w_max=min(f.w_max, float(hi[1])),
        )
        self.control_dt = float(getattr(env, "dt", 0.1))
        self.world: WorldModel | None = None

    def config_dict(self) -> dict[str, Any]:
        """The resolved config (with the front-end's full config)."""
        return self.cfg.to_dict()

    # ---- episode ---------------------------------------------------------------------------
    def close(self) -> None:
        """Release the world model's resources (its training thread); the runner calls it
        when an episode ends, :meth:`reset` before a new one. Idempotent."""
        if self.world is not None:
            self.world.close()

    def reset(self, obs: dict, info: dict) -> None:
        cam = info["camera"]
        T_base_cam = np.asarray(cam.T_base_cam, float)
        self.rng = np.random.default_rng(self.cfg.seed)
        self.close()  # the previous episode's world model
        self.world = make_world(
            self.cfg.pose_source, self.cfg.slam, self.cfg.obstacles, cam.intrinsics, T_base_cam
        )
        self.obstacles = self.world.obstacles
        if self.cfg.costmap.transient_weight > 0:
            self.obstacles.keep_static()  # the model the cost map prices transient cells by
        self.follower = PathFollower(self.follower_cfg, self.obstacles.safety)
        self.bump = BumpDetector(
            self.control_dt,
            min_progress=self.cfg.bump_min_progress,
            rel_progress=self.cfg.bump_rel_progress,
            yaw_tol=self.cfg.bump_yaw_tol,
        )
        self.goal = np.asarray(obs["goal"], float)
        self.T_odom_prev = self._odom_T(obs)
        self.path: np.ndarray | None = None
        self.tree_edges: np.ndarray | None = None
        self.steps = 0
        self.since_plan = 0
        self.plan_failures = 0
        self.fallback_plans = 0
        self._last_cmd = np.zeros(2)
        self._state = "starting"
        self._plan_ms: float | None = None
        self._job: PlanJob | None = None  # a scheduled plan being grown over steps
        w_scan = min(self.cfg.scan_rate, self.follower_cfg.w_max)
        self._scan_steps = int(
            math.ceil(math.radians(self.cfg.initial_scan_deg) / (w_scan * self.control_dt))
        )
        self._full_scan_steps = int(math.ceil(2 * math.pi / (w_scan * self.control_dt)))
        self._best_goal_dist = math.inf  # the robot's closest approach to the goal so far
        self._route_kind = "goal_unexplored"
        self._driven: list[np.ndarray] = []  # the estimated positions driven (known space)
        self._progress = ProgressWatch(self.cfg.stall_steps, self.cfg.progress_eps)
        self._ctg: float | None = None
        self._force_until = -1  # follow the cost map's route until this step
        self.lost_progress = 0
        self.field_routes = 0  # plans where the cost map's route was taken
        self.squeezes = 0  # routes found only with the squeezed model
        self._squeeze_until = -1
        self._squeezed = None  # the squeezed collision model while squeezing
        self._route_watch = NoRouteWatch(self.cfg.clear_after, self.cfg.clear_cooldown)
        self._step = self.world.update(0.0, obs, self.T_odom_prev)

    @staticmethod
    def _odom_T(obs: dict) -> np.ndarray:
        o = np.asarray(obs["odometry"], float)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"odometry must be a finite (x, y, yaw), got {o}")
        return planar_T(o[0], o[1], o[2])

    # ---- planning ----------------------------------------------------------------------------
    def _subgoal(self, xy: np.ndarray) -> np.ndarray:
        if not self.cfg.topo_guidance:
            return self.goal
        target, self._route_kind = topo_subgoal(
            self.world.topology,
            self.world.current_frame_id,
            self.goal,
            xy,
            self._best_goal_dist,
            self.cfg.topo_reach,
        )
        return target

    def _begin_plan(self, xy: np.ndarray) -> PlanJob | None:
        """A new RRT* plan from ``xy`` to the (sub-)goal, begun but not grown (None when the
        start or the goal cannot be made free)."""
        checker = self.obstacles.planning
        goal = self._subgoal(xy)
        if not checker.is_free(goal[None])[0]:
            alt = nearest_free(checker, goal)
            goal = alt if alt is not None else goal
        start = xy
        if not checker.is_free(xy[None])[0]:  # inside the margin: nearest free point
            alt = nearest_free(checker, xy, radius=0.5)
            start = alt if alt is not None else xy
        if not (checker.is_free(start[None])[0] and checker.is_free(goal[None])[0]):
            return None
        planner = make_planner(self.cfg, checker, xy, goal, self.rng)
        planner.begin(start, goal)
        return PlanJob(planner, xy.copy(), start, goal)

    def _finish_plan(self, job: PlanJob | None, xy: np.ndarray, scheduled: bool) -> None:
        """Take the grown plan (grid fallback when RRT* found nothing). A scheduled replan keeps
        the current path unless the new one is shorter than ``switch_gain`` x the remaining
        length or was invalidated by the map growing while it was computed; an event replan
        (blocked, stale, no path) always replaces it."""
        checker = self.obstacles.planning
        path = None
        self.tree_edges = None
        if job is not None:
            path = job.planner.finish()
            if path is None and not self.cfg.judge:  # budget exhausted: complete grid search
                path = grid_shortest_path(checker, job.start, job.goal, self.rng)
                self.fallback_plans += int(path is not None)
            if path is not None and self.cfg.path_clearance > 0:
                path = push_from_obstacles(
                    path, checker, self.cfg.path_clearance, also_from=self.obstacles.shadow_model()
                )
            if path is not None and job.start is not job.xy:
                path = np.vstack([job.xy, path])
            if path is not None and scheduled and not checker.path_free(path[1:]):
                path = None  # the map grew across it while it was grown over several steps
            self.tree_edges = tree_edges(job.planner)
        self.since_plan = 0
        if self.cfg.judge:
            self._judge(path, xy, scheduled)
            return
        if scheduled and self.path is not None:
            if path is None or path_length(path) >= self.cfg.switch_gain * path_length(
                self._remaining_path(xy)
            ):
                return
        self._take(path)

    def _take(self, path: np.ndarray | None) -> None:
        if path is None:
            self.plan_failures += 1
            self.path = None
            self._state = "no_plan"
        else:
            self.path = path
            self.follower.set_path(path)
            self._state = "following"

    # ---- around the RRT*: the cost-to-go map -------------------------------------------------
    def _costmap(self, xy: np.ndarray) -> CostMap:
        """The cost-to-go map to the goal on the current map (known space: the local frames'
        floor points and the driven path); updates the lost-progress measure."""
        known = self.world.frames.floor_points_world()[:, :2]
        if self._driven:
            known = np.vstack([known, np.asarray(self._driven)])
        ob = self.obstacles
        cm = CostMap(
            self.cfg.costmap, ob.safety, ob.planning, self.goal, xy, known, ob.static_safety
        )
        self._ctg = cm.cost_to_go(xy)
        self._progress.update(self._ctg, self.steps)
        return cm

    def _judge(self, rrt_path: np.ndarray | None, xy: np.ndarray, scheduled: bool) -> None:
        """Choose among the fresh RRT* plan, the cost map's route and the committed path, all
        judged on the same cost-to-go map (see :mod:`simn_sim.planning.costmap`)."""
        if self._squeezing():
            self._squeeze_route(xy)
            return
        cm = self._costmap(xy)
        field, c_field = field_route(cm, xy, self.obstacles, self.cfg.path_clearance, self.rng)
        c_rrt = cm.path_cost(rrt_path) if rrt_path is not None else math.inf
        if not math.isfinite(c_field) and not math.isfinite(c_rrt) and self.cfg.squeeze > 0:
            if self._squeeze_route(xy, start=True):
                return
        forced = self.steps < self._force_until
        if forced or c_rrt > self.cfg.homotopy_slack * c_field:
            new, c_new, kind = field, c_field, "field"
        else:
            new, c_new, kind = rrt_path, c_rrt, "rrt"
        if scheduled and self.path is not None:
            c_cur = cm.path_cost(self._remaining_path(xy))
            if math.isfinite(c_cur) and not c_new < self.cfg.switch_gain * c_cur:
                return  # the committed path stays
        if new is None or not math.isfinite(c_new):
            self._take(None)
            return
        self.field_routes += int(kind == "field")
        self._take(new)

    # ---- squeezing through a doorway the map has narrowed -----------------------------------
    def _squeezing(self) -> bool:
        if self._squeezed is not None and self.steps >= self._squeeze_until:
            self._squeezed = None  # back to the normal models
            self.follower.checker = self.obstacles.safety
        return self._squeezed is not None

    def _squeeze_route(self, xy: np.ndarray, start: bool = False) -> bool:
        """Plan on the squeezed model (radius - ``squeeze``, no margin; the safety model's
        margin soft). ``start``: enter squeezing when a route exists. True when a route was
        taken."""
        if start:
            sq = squeezed_checker(self.obstacles, self.world.frames, self.cfg.squeeze)
        else:
            sq = self._squeezed
        known = self.world.frames.floor_points_world()[:, :2]
        cm = CostMap(self.cfg.costmap, sq, self.obstacles.safety, self.goal, xy, known)
        raw = cm.path(xy)
        if raw is None or not math.isfinite(cm.path_cost(raw)):
            if not start:
                self._take(None)
            return False
        if start:
            self.squeezes += 1
            self._squeezed = sq
            self._squeeze_until = self.steps + self.cfg.force_steps
            self.follower.checker = sq
        self._take(raw)
        return True

    def _remaining_path(self, xy: np.ndarray) -> np.ndarray:
        """The current path from the robot on: ``xy``, then the path from its nearest vertex."""
        p = self.path
        k = int(np.argmin(np.hypot(*(p - xy).T)))
        return np.vstack([xy, p[k:]])

    def _plan(self, xy: np.ndarray, scheduled: bool = False) -> None:
        """Plan now, the whole iteration budget in this control step (cancels a sliced plan)."""
        t = time.perf_counter()
        self._job = None
        job = self._begin_plan(xy)
        if job is not None:
            job.planner.iterate(self.cfg.rrt.max_iterations)
        self._finish_plan(job, xy, scheduled)
        self._plan_ms = (self._plan_ms or 0.0) + (time.perf_counter() - t) * 1e3

    def _plan_sliced(self, xy: np.ndarray) -> None:
        """A scheduled replan spread over control steps: ``plan_slice`` RRT* iterations per
        step while the robot keeps following its current path (the same rng and budget give
        the same tree as one call; the control step stays short)."""
        t = time.perf_counter()
        if self._job is None:
            self._job = self._begin_plan(xy)
            if self._job is None:
                self._finish_plan(None, xy, scheduled=True)
                self._plan_ms = (time.perf_counter() - t) * 1e3
                return
        job = self._job
        if job.planner.iterate(self.cfg.plan_slice):
            self._job = None
            self._finish_plan(job, xy, scheduled=True)
        self._plan_ms = (time.perf_counter() - t) * 1e3

    # ---- act ---------------------------------------------------------------------------------
    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:  # info ignored: no true pose
        a = self._act(obs)
        self._last_cmd = np.asarray(a, float)
        return a

    def _look_around(self) -> np.ndarray:
        return np.array([0.0, 0.6 * self.follower_cfg.w_max], np.float32)

    def _no_route(self) -> np.ndarray:
        """No route to the goal on the map: look around (turning reveals more of the map); after
        ``clear_after`` such steps in a row, clear the map and look all the way round."""
        if self._route_watch.no_route(self.steps):
            self.obstacles.forget(self.world.frames.current_id)
            self._scan_steps = self._full_scan_steps
            self._progress.restart(self.steps)
        return self._look_around()

    def _act(self, obs: dict) -> np.ndarray:
        self.steps += 1
        T_odom = self._odom_T(obs)
        v, w = float(self._last_cmd[0]), float(self._last_cmd[1])
        if self.bump.update(v, inv_T(self.T_odom_prev) @ T_odom, w):
            self.obstacles.add_bump(
                self.world.pose,
                self.cfg.obstacles.collision.robot_radius,
                self.bump.contact_angle,
            )
            self.path = None
        self.T_odom_prev = T_odom
        self._plan_ms = None
        self._step = self.world.update(self.steps * self.control_dt, obs, T_odom)
        T = self._step.T_world_base
        pose = np.array([T[0, 3], T[1, 3], yaw_of(T)])
        xy = pose[:2]
        self._best_goal_dist = min(self._best_goal_dist, float(np.hypot(*(xy - self.goal))))
        if not self._driven or np.hypot(*(self._driven[-1] - xy)) > 0.1:
            self._driven.append(xy.copy())
        if (
            self.cfg.judge
            and self._ctg is not None
            and self._scan_steps == 0
            and self._progress.stalled(self.steps)
        ):
            # lost progress: the cost-to-go on the agent's own map has not fallen for
            # stall_steps; look around, then follow the cost map's route for a while
            self.lost_progress += 1
            self._scan_steps = self._full_scan_steps
            self._force_until = self.steps + self._full_scan_steps + self.cfg.force_steps
            self._progress.restart(self.steps)
            self.path = None
            self._job = None
        touch = (
            self.cfg.obstacles.collision.robot_radius
            + 0.01
            - (self.cfg.squeeze + 0.02 if self._squeezed is not None else 0.0)
        )
        backing = back_off(
            pose,
            self.obstacles.planning,
            touch,
            lambda: self._squeezed if self._squeezing() else self.obstacles.safety,
            self.follower_cfg,
        )
        if backing is not None:  # touching the map, or inside the safety margin
            self._state, a = backing
            self.path = None
            return a
        if self._scan_steps > 0:  # initial look-around (turning in place sweeps no new space)
            self._scan_steps -= 1
            self._state = "scanning"
            return np.array([0.0, min(self.cfg.scan_rate, self.follower_cfg.w_max)], np.float32)
        self.since_plan += 1
        if self.path is None:
            self._plan(xy)
        elif self._job is not None or self.since_plan >= self.cfg.replan_every:
            if self.cfg.plan_slice > 0:
                self._plan_sliced(xy)
            else:
                self._plan(xy, scheduled=True)
        if self.path is None:  # look around: turning reveals more of the map
            return self._no_route()
        cmd = self.follower.step(pose)
        if cmd.status in ("blocked", "stale"):
            self._plan(xy)
            if self.path is None:
                return self._no_route()
            cmd = self.follower.step(pose)
        if cmd.status == "reached" and float(np.hypot(*(self.goal - xy))) > 0.2:
            self._plan(xy)  # reached a sub-goal: plan on towards the goal
            if self.path is not None:
                cmd = self.follower.step(pose)
        if cmd.status in ("blocked", "stale") and self.cfg.refused_plan_no_route:
            # the fresh plan is one the follower will not take (its next metre cuts the safety
            # model): no route either
            return self._no_route()
        self._route_watch.route()
        if cmd.status in ("blocked", "stale"):
            return np.array([0.0, 0.0], np.float32)  # stand still
        return np.array([cmd.v, cmd.w], np.float32)

    # ---- reporting ---------------------------------------------------------------------------
    def state(self) -> str:
        return self._state

    def counters(self) -> dict[str, int]:
        out = {
            "plan_failures": self.plan_failures,
            "fallback_plans": self.fallback_plans,
            "bumps": self.bump.bumps if self.world is not None else 0,
            "lost_progress": getattr(self, "lost_progress", 0),
            "field_routes": getattr(self, "field_routes", 0),
            "squeezes": getattr(self, "squeezes", 0),
            "map_clears": self.obstacles.clears if self.world is not None else 0,
        }
        if self.world is not None:
            out.update(self.world.counters())
        return out

    def revisit_events(self) -> dict[str, Any] | None:
        """The world model's revisit events with each frame's opening as the index of the
        ``act()`` call whose observation opened it (0: the first; ``reset`` processes that
        same observation at t = 0), for judging them against the true poses
        (:func:`simn_sim.eval.revisits.revisit_truth`); None without revisit checks."""
        ev = None if self.world is None else self.world.revisit_events()
        if ev is None:
            return None
        idx = [max(round(t / self.control_dt) - 1, 0) for t in ev.pop("t_open")]
        return {**ev, "frame_obs": idx}

    def debug(self) -> dict[str, Any]:
        step = getattr(self, "_step", None)
        d: dict[str, Any] = {}
        if self.world is not None:
            d.update(self.world.debug())
        d.update(
            {
                "frame": "start",  # everything here is in the agent's own (episode start) frame
                "T_world_base_est": None if step is None else step.T_world_base,
                "path": getattr(self, "path", None),
                "tree_edges": getattr(self, "tree_edges", None),
                "plan_ms": getattr(self, "_plan_ms", None),
                "map_ms": None if step is None else step.map_ms,
                "track_ms": None if step is None else step.track_ms,
                "route": getattr(self, "_route_kind", None),
                "cost_to_go": getattr(self, "_ctg", None),
            }
        )
        return d


def _make_simn(env: Any, config: dict[str, Any]) -> SimnAgent:
    return SimnAgent(env, config, name="simn")


def _make_simn_points(env: Any, config: dict[str, Any]) -> SimnAgent:
    """The point-store ablation (:func:`points_ablation_config`)."""
    return SimnAgent(env, points_ablation_config(config), name="simn_points")


def _make_rrtstar(env: Any, config: dict[str, Any]) -> SimnAgent:
    return SimnAgent(env, {"planner": "uniform", **config}, name="rrtstar")


register_agent("simn", _make_simn)
register_agent("simn_points", _make_simn_points)
register_agent("rrtstar", _make_rrtstar)
