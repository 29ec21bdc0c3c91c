"""Route building blocks of the navigation agent, free of its episode state.

- :func:`make_planner`: the agent's RRT* (goal-vector for ``simn``, uniform in a window around
  the start, the goal and the mapped obstacles for ``rrtstar``), not yet begun;
- :func:`tree_edges`: a grown planner's tree as (E, 2, 2) child-parent segments (for rerun);
- :func:`field_route`: the cost-to-go map's own route, shortcut and pushed from obstacles where
  that does not make it dearer;
- :func:`squeezed_checker`: the collision model with the robot radius reduced by ``squeeze`` and
  no margin, for a doorway the map has narrowed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simn_sim.agents.simn_config import SimnAgentConfig
from simn_sim.planning import goal_vector_rrt_star, uniform_rrt_star
from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.costmap import CostMap
from simn_sim.planning.smoothing import push_from_obstacles, shortcut_path
from simn_sim.semantics import OBSTACLE

__all__ = ["field_route", "make_planner", "squeezed_checker", "tree_edges"]


def make_planner(
    cfg: SimnAgentConfig,
    checker: CollisionChecker,
    xy: np.ndarray,
    goal: np.ndarray,
    rng: np.random.Generator,
) -> Any:
    """The RRT* of ``cfg.planner`` on ``checker``: ``goal_vector`` (the method), else uniform
    sampling in the box around ``xy`` and ``goal`` widened by ``cfg.window`` and by the mapped
    obstacles' bounds."""
    if cfg.planner == "goal_vector":
        return goal_vector_rrt_star(checker, cfg.rrt, cfg.goal_vector, None, rng)
    lo = np.minimum(xy, goal) - cfg.window
    hi = np.maximum(xy, goal) + cfg.window
    b = checker.obstacle_bounds()
    if b is not None:
        lo = np.minimum(lo, [b[0], b[1]])
        hi = np.maximum(hi, [b[2], b[3]])
    return uniform_rrt_star(checker, (lo[0], lo[1], hi[0], hi[1]), cfg.rrt, rng)


def tree_edges(planner: Any) -> np.ndarray | None:
    """The planner's tree as (E, 2, 2) segments (child, parent); None without a tree."""
    tree = planner.tree
    if tree is None or len(tree) <= 1:
        return None
    par = np.asarray(tree.parent[: len(tree)])
    ok = par >= 0
    xy = np.asarray(tree.xy[: len(tree)])
    return np.stack([xy[ok], xy[par[ok]]], axis=1)


def field_route(
    cm: CostMap, xy: np.ndarray, obstacles: Any, clearance: float, rng: np.random.Generator
) -> tuple[np.ndarray | None, float]:
    """The cost map's route from ``xy`` and its cost: shortcut where the planning margin holds
    (a tight doorway keeps the map's cells, which run through its middle), then pushed
    ``clearance`` from obstacles (and the blind-zone shadows) when ``clearance`` > 0; the raw
    route when that made it more than 5 % dearer. (None, inf) without a route."""
    raw = cm.path(xy)
    if raw is None:
        return None, math.inf
    c_raw = cm.path_cost(raw)
    p = shortcut_path(raw, obstacles.planning, rng, iterations=30)
    if clearance > 0:
        p = push_from_obstacles(p, obstacles.safety, clearance, also_from=obstacles.shadow_model())
    c = cm.path_cost(p)
    return (p, c) if c <= 1.05 * c_raw else (raw, c_raw)


def squeezed_checker(obstacles: Any, frames: Any, squeeze: float) -> CollisionChecker:
    """The safety model with the robot radius reduced by ``squeeze`` and no margin, over the
    obstacle points of ``frames`` (the local frames)."""
    c = obstacles.safety.cfg
    sq = CollisionChecker(c.replace(robot_radius=c.robot_radius - squeeze, margin=0.0))
    pts = obstacles.model_points(frames)
    if len(pts):
        sq.update(pts, np.full(len(pts), OBSTACLE, np.int8))
    return sq
