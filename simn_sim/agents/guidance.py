"""Topological guidance: which (sub-)goal the planner aims at, from the topological map."""

from __future__ import annotations

import numpy as np

from simn_sim.planning.topo import route_subgoal
from simn_sim.tracking.topomap import TopoMap


def topo_subgoal(
    topo: TopoMap,
    current: int,
    goal: np.ndarray,
    xy: np.ndarray,
    best_goal_dist: float,
    reach: float,
) -> tuple[np.ndarray, str]:
    """(target xy, route kind). When the goal lies in the region of an earlier local frame but
    not in the current one, aim at the next frame on the route over the topological map towards
    that frame; when no frame covers the goal (unexplored space), aim at the goal itself.

    Only frames whose anchor is nearer the goal (by ``reach``) than the robot has ever been
    (``best_goal_dist``) are route targets: guidance leads to explored places that are
    progress, and a robot that reached the explored place nearest the goal and has to detour
    from there is not sent back to it (without this rule it oscillated between nearby anchors).
    """
    if current < 0:
        return goal, "goal_unexplored"
    covering = topo.frames_containing(goal)
    if not covering or current in covering:
        return goal, "goal_unexplored" if not covering else "goal_in_frame"
    dist = {f: float(np.hypot(*(topo.anchor(f)[:2, 3] - goal))) for f in covering}
    cands = [f for f in covering if dist[f] < best_goal_dist - reach]
    if not cands:
        return goal, "goal_direct"
    r = route_subgoal(
        topo.graph,
        current,
        goal,
        frame_radius=reach,
        goal_node=min(cands, key=dist.__getitem__),
        from_xy=xy,
        reach=reach,
    )
    return np.asarray(r.xy, float), r.kind
