"""push_from_obstacles: shortcut paths pushed away from obstacles where there is room."""

from __future__ import annotations

import numpy as np

from simn_sim.planning import CollisionChecker, CollisionConfig, RRTStarConfig, goal_vector_rrt_star
from simn_sim.planning.smoothing import densify, path_length, push_from_obstacles
from simn_sim.planning.synthetic_maps import doorway_map


def _checker(m, margin=0.1):
    c = CollisionChecker(CollisionConfig(margin=margin))
    c.update(m.points, m.labels)
    return c


def test_nearest_obstacle_is_the_feature_of_the_distance_transform():
    m = doorway_map(door_width=1.0)
    c = _checker(m)
    q = np.array([[4.0, 2.0], [5.0, 4.0], [-50.0, -50.0]])
    o = c.nearest_obstacle(q)
    np.testing.assert_allclose(np.hypot(*(q[:2] - o[:2]).T), c.clearance(q[:2]), atol=1e-9)
    assert abs(o[0, 0] - 5.0) < 0.05  # the wall x = 5 is the nearest obstacle of (4, 2)...
    assert np.isnan(o[2]).all()  # ... and outside the grid there is none


def test_push_keeps_the_path_free_and_centres_it_in_the_doorway():
    m = doorway_map(door_width=1.0)  # wall at x = 5, door y in [3.5, 4.5]
    c = _checker(m)
    planner = goal_vector_rrt_star(c, RRTStarConfig(time_budget_ms=0, max_iterations=1500),
                                   rng=np.random.default_rng(0))  # fmt: skip
    path = planner.plan(np.array([2.0, 1.5]), np.array([8.0, 1.5]))
    assert path is not None
    # the shortcut path grazes the door jamb at the inflation radius
    jamb = c.clearance(densify(path, 0.05)).min()
    assert jamb < c.cfg.inflation + 0.06
    pushed = push_from_obstacles(path, c, target_clearance=0.45)
    assert c.path_free(pushed)
    np.testing.assert_allclose(pushed[[0, -1]], path[[0, -1]])
    dense = densify(pushed, 0.05)
    # through the door it passes near the centre line (clearance about half the width)
    at_door = dense[np.abs(dense[:, 0] - 5.0) < 0.05]
    assert len(at_door) and np.all(np.abs(at_door[:, 1] - 4.0) < 0.1)
    # every point of it now has (about) the target clearance: the door's half width allows it
    assert c.clearance(dense).min() > 0.42
    # elsewhere it keeps the target clearance where the room allows, and gets only a bit longer
    assert path_length(pushed) < 1.15 * path_length(path)


def test_push_without_obstacles_or_target_changes_nothing_but_density():
    c = CollisionChecker()
    path = np.array([[0.0, 0.0], [3.0, 0.0]])
    out = push_from_obstacles(path, c, target_clearance=0.5)
    np.testing.assert_allclose(out[:, 1], 0.0)
    np.testing.assert_allclose(out[[0, -1]], path)


def test_push_terminates_on_a_path_that_is_not_free():
    """A path through a wall (the map grew across it): the push ends, moves no vertex into a
    new blocked segment, and leaves the blocked part to the caller."""
    m = doorway_map(door_width=1.0)
    c = _checker(m)
    path = np.array([[2.0, 1.5], [8.0, 1.5]])  # straight through the wall at x = 5
    out = push_from_obstacles(path, c, target_clearance=0.5)
    before = densify(path, 0.1)
    assert len(out) == len(before)
    free_before = c.segments_free(before[:-1], before[1:])
    assert not free_before.all()
    assert np.all(c.segments_free(out[:-1], out[1:])[free_before])
