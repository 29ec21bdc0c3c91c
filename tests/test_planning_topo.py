"""Topological guidance: next route node, or the goal itself when in frame / unexplored."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest

from simn_sim.geometry.se3 import planar_T
from simn_sim.planning.topo import route_subgoal


def office_graph() -> nx.Graph:
    """A -- B -- C -- D along x (5 m apart), plus a cheap detour A -- E -- D by weight."""
    g = nx.Graph()
    for name, xy in dict(A=(0, 0), B=(5, 0), C=(10, 0), D=(15, 0), E=(7, 6)).items():
        g.add_node(name, anchor_xy=np.array(xy, float))
    g.add_edge("A", "B", weight=5.0)
    g.add_edge("B", "C", weight=5.0)
    g.add_edge("C", "D", weight=5.0)
    g.add_edge("A", "E", weight=20.0)
    g.add_edge("E", "D", weight=20.0)
    return g


def test_goal_in_current_frame_is_returned_itself() -> None:
    g = office_graph()
    r = route_subgoal(g, "B", [6.0, 1.0], frame_radius=3.0)
    assert r.kind == "goal_in_frame" and r.next_node is None
    np.testing.assert_allclose(r.xy, [6.0, 1.0])


def test_next_node_on_weighted_shortest_path() -> None:
    g = office_graph()
    r = route_subgoal(g, "A", [15.5, 0.5], frame_radius=3.0)
    assert r.kind == "node" and r.next_node == "B" and r.route == ["A", "B", "C", "D"]
    np.testing.assert_allclose(r.xy, [5.0, 0.0])
    # make the main corridor expensive: the route switches to the detour through E
    g.edges["B", "C"]["weight"] = 100.0
    r = route_subgoal(g, "A", [15.5, 0.5], frame_radius=3.0)
    assert r.next_node == "E" and r.route == ["A", "E", "D"]
    np.testing.assert_allclose(r.xy, [7.0, 6.0])
    # the graph is not modified
    assert g.edges["B", "C"]["weight"] == 100.0 and set(g.nodes) == set("ABCDE")


def test_known_goal_node_overrides_nearest_anchor() -> None:
    g = office_graph()
    goal = [10.5, 2.0]
    # nearest anchor to the goal is C, but the caller knows the goal lies in E's frame
    assert route_subgoal(g, "A", goal, frame_radius=1.5).route == ["A", "B", "C"]
    r = route_subgoal(g, "A", goal, frame_radius=1.5, goal_node="E")
    assert r.next_node == "E" and r.route == ["A", "E"]
    r = route_subgoal(g, "E", goal, frame_radius=1.5, goal_node="E")
    assert r.kind == "goal_in_frame" and r.next_node is None
    np.testing.assert_allclose(r.xy, goal)
    with pytest.raises(ValueError, match="goal node"):
        route_subgoal(g, "A", goal, goal_node="Q")


def test_goal_in_unexplored_space_is_returned_itself() -> None:
    g = office_graph()
    r = route_subgoal(g, "A", [15.0, 30.0], frame_radius=3.0)
    assert r.kind == "goal_unexplored" and r.route == []
    np.testing.assert_allclose(r.xy, [15.0, 30.0])
    # within explored_radius of D it is routed
    r = route_subgoal(g, "A", [15.0, 5.0], frame_radius=3.0, explored_radius=6.0)
    assert r.kind == "node" and r.next_node == "B"


def test_no_route_and_pose_attribute() -> None:
    g = nx.Graph()
    g.add_node(0, pose=planar_T(0.0, 0.0, 0.3))
    g.add_node(1, pose=planar_T(4.0, 1.0, 1.0))
    g.add_node(2, pose=planar_T(8.0, 0.0, 0.0))
    g.add_edge(0, 1, weight=4.1)
    r = route_subgoal(g, 0, [8.5, 0.0], frame_radius=2.0)
    assert r.kind == "no_route"
    np.testing.assert_allclose(r.xy, [8.5, 0.0])
    g.add_edge(1, 2, weight=4.1)
    r = route_subgoal(g, 0, [8.5, 0.0], frame_radius=2.0)
    assert r.kind == "node" and r.next_node == 1
    np.testing.assert_allclose(r.xy, [4.0, 1.0])
    # nodes as stored by simn_sim.tracking.topomap: frame objects with T_world_anchor
    from types import SimpleNamespace

    h = nx.Graph()
    for k in range(3):
        h.add_node(k, frame=SimpleNamespace(T_world_anchor=planar_T(4.0 * k, 0.0, 0.2 * k)))
    h.add_edge(0, 1, weight=4.0)
    h.add_edge(1, 2, weight=4.0)
    r = route_subgoal(h, 0, [8.2, 0.3], frame_radius=1.0)
    assert r.next_node == 1
    np.testing.assert_allclose(r.xy, [4.0, 0.0])
    # a node's own radius overrides frame_radius
    g.nodes[0]["radius"] = 10.0
    assert route_subgoal(g, 0, [8.5, 0.0], frame_radius=2.0).kind == "goal_in_frame"


def test_bad_inputs_raise() -> None:
    g = office_graph()
    with pytest.raises(ValueError, match="goal_xy"):
        route_subgoal(g, "A", [np.nan, 0.0])
    with pytest.raises(ValueError, match="not in the graph"):
        route_subgoal(g, "Z", [1.0, 0.0])
    with pytest.raises(ValueError, match="frame_radius"):
        route_subgoal(g, "A", [1.0, 0.0], frame_radius=0.0)
    g.add_node("F")
    g.add_edge("F", "A", weight=1.0)
    with pytest.raises(ValueError, match="neither"):
        route_subgoal(g, "A", [20.0, 0.0])


def test_robot_position_skips_passed_nodes_and_goes_direct_when_the_route_cannot_help() -> None:
    g = office_graph()
    goal = [15.5, 0.5]
    # standing on B's anchor (current frame A): B is passed, the sub-goal is C
    r = route_subgoal(g, "A", goal, frame_radius=3.0, from_xy=[4.8, 0.1])
    assert r.kind == "node" and r.next_node == "C"
    np.testing.assert_allclose(r.xy, [10.0, 0.0])
    # without the position the next node is B, the anchor the robot stands on
    assert route_subgoal(g, "A", goal, frame_radius=3.0).next_node == "B"
    # past every node on the route (within reach of D): the goal itself
    r = route_subgoal(g, "C", goal, frame_radius=0.2, explored_radius=2.0, from_xy=[14.6, -0.3])
    assert r.kind == "goal_direct" and r.next_node is None
    np.testing.assert_allclose(r.xy, goal)
    # the robot is nearer the goal than the route's last node: nothing to gain by routing
    goal2 = [20.0, 0.0]
    r = route_subgoal(g, "A", goal2, frame_radius=3.0, explored_radius=6.0, from_xy=[16.0, 0.0])
    assert r.kind == "goal_direct" and r.route == ["A", "B", "C", "D"]
    np.testing.assert_allclose(r.xy, goal2)
    with pytest.raises(ValueError, match="from_xy"):
        route_subgoal(g, "A", goal, from_xy=[np.nan, 0.0])
