"""Topological guidance: which point the local planner should aim at.

The topological map is a networkx graph whose nodes are local frames with an anchor position and
whose edges carry a traversal ``weight``. When the goal lies beyond the current frame, the local
planner (goal-vector RRT*) aims at the next node on the graph's shortest path towards the node
nearest the goal; when the goal is inside the current frame, or in space no frame has explored,
it aims at the goal itself (unknown space is free; the plan is repaired as the map grows).
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import networkx as nx
import numpy as np


class RouteSubgoal(NamedTuple):
    """Result of :func:`route_subgoal` (positions in the graph's common frame, x-y metres)."""

    xy: np.ndarray
    """(2,) point to plan towards."""
    kind: Literal["goal_in_frame", "goal_unexplored", "node", "no_route", "goal_direct"]
    """Why this point: the goal is in the current frame / in unexplored space (xy = goal),
    the next node on the route (xy = its anchor), no graph path exists (xy = goal), or (with
    ``from_xy``) the route has nothing left to offer: the robot is no farther from the goal
    than the route's last node, or has passed every node on it (xy = goal)."""
    next_node: Any
    """The node whose anchor is xy (None when xy is the goal)."""
    route: list
    """Node sequence from the current node to the node nearest the goal ([] if none)."""


def node_xy(graph: nx.Graph, node: Any, pos_attr: str = "anchor_xy") -> np.ndarray:
    """(2,) position of a node: its ``pos_attr`` (x, y[, ...]), the translation of its 4x4
    ``pose`` (``T_common_frame``), or of ``frame.T_world_anchor`` (the tracking topological map's
    node attribute)."""
    data = graph.nodes[node]
    if pos_attr in data:
        p = np.asarray(data[pos_attr], dtype=np.float64).reshape(-1)
        if p.shape[0] < 2:
            raise ValueError(f"node {node!r}: {pos_attr} must have at least x, y")
        return p[:2]
    if "pose" in data:
        T = np.asarray(data["pose"], dtype=np.float64)
        if T.shape == (4, 4):
            return T[:2, 3].copy()
        if T.shape == (3, 3):  # SE(2) homogeneous
            return T[:2, 2].copy()
        raise ValueError(f"node {node!r}: pose must be 4x4 or 3x3, got {T.shape}")
    frame = data.get("frame")
    T = getattr(frame, "T_world_anchor", None)
    if T is not None:  # simn_sim.tracking.topomap nodes: frame=LocalFrame(T_world_anchor=...)
        return np.asarray(T, dtype=np.float64)[:2, 3].copy()
    raise ValueError(f"node {node!r} has neither '{pos_attr}', 'pose' nor 'frame.T_world_anchor'")


def route_subgoal(
    graph: nx.Graph,
    current_node: Any,
    goal_xy: np.ndarray,
    frame_radius: float = 3.0,
    explored_radius: float | None = None,
    pos_attr: str = "anchor_xy",
    weight: str = "weight",
    goal_node: Any = None,
    from_xy: np.ndarray | None = None,
    reach: float = 0.6,
) -> RouteSubgoal:
    """Where the local planner should aim next.

    Args:
        graph: topological map; nodes have ``pos_attr`` (or ``pose``), edges ``weight``.
        current_node: the frame the robot is in.
        goal_xy: (2,) goal in the graph's common frame.
        frame_radius: a node's region is the disk of this radius around its anchor, unless the
            node has its own ``radius`` attribute. The goal is "in the current frame" if it is
            in the current node's region.
        explored_radius: the goal is "unexplored" if it is farther than this from every anchor
            (default: ``2 * frame_radius``).
        goal_node: the node whose frame holds the goal, when the caller knows it (e.g. the goal
            was localised in a frame); default: the node with the nearest anchor.
        from_xy: the robot's position, when known. Route nodes within ``reach`` of it count as
            passed (the next one is returned), and when the robot is no farther from the goal
            than the route's last node the goal itself is returned (``"goal_direct"``): a robot
            standing on a node's anchor is never sent to that anchor again.
    Returns:
        :class:`RouteSubgoal`. Pure function: the graph is not modified.
    """
    goal = np.asarray(goal_xy, dtype=np.float64).reshape(-1)
    if goal.shape != (2,) or not np.all(np.isfinite(goal)):
        raise ValueError(f"goal_xy must be a finite x-y pair, got {goal_xy!r}")
    if current_node not in graph:
        raise ValueError(f"current node {current_node!r} is not in the graph")
    if not (np.isfinite(frame_radius) and frame_radius > 0):
        raise ValueError(f"frame_radius must be > 0, got {frame_radius}")
    explored = 2.0 * frame_radius if explored_radius is None else float(explored_radius)

    def radius(n: Any) -> float:
        return float(graph.nodes[n].get("radius", frame_radius))

    cur_xy = node_xy(graph, current_node, pos_attr)
    if np.hypot(*(goal - cur_xy)) <= radius(current_node):
        return RouteSubgoal(goal.copy(), "goal_in_frame", None, [current_node])
    if goal_node is not None:
        if goal_node not in graph:
            raise ValueError(f"goal node {goal_node!r} is not in the graph")
        target = goal_node
    else:
        nodes = list(graph.nodes)
        xy = np.stack([node_xy(graph, n, pos_attr) for n in nodes])
        d = np.hypot(*(xy - goal).T)
        k = int(np.argmin(d))
        if d[k] > explored:
            return RouteSubgoal(goal.copy(), "goal_unexplored", None, [])
        target = nodes[k]
    try:
        route = nx.shortest_path(graph, current_node, target, weight=weight)
    except nx.NetworkXNoPath:
        return RouteSubgoal(goal.copy(), "no_route", None, [])
    if len(route) == 1:
        # the node nearest the goal is the current one but the goal is outside its region
        return RouteSubgoal(goal.copy(), "goal_in_frame", None, route)
    if from_xy is not None:
        here = np.asarray(from_xy, dtype=np.float64).reshape(-1)
        if here.shape != (2,) or not np.all(np.isfinite(here)):
            raise ValueError(f"from_xy must be a finite x-y pair, got {from_xy!r}")
        last = node_xy(graph, route[-1], pos_attr)
        if np.hypot(*(goal - here)) <= np.hypot(*(goal - last)):
            return RouteSubgoal(goal.copy(), "goal_direct", None, route)
        for n in route[1:]:
            p = node_xy(graph, n, pos_attr)
            if np.hypot(*(p - here)) > reach:
                return RouteSubgoal(p, "node", n, route)
        return RouteSubgoal(goal.copy(), "goal_direct", None, route)
    nxt = route[1]
    return RouteSubgoal(node_xy(graph, nxt, pos_attr), "node", nxt, route)
