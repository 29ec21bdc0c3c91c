"""The grid fallback planner finds the detour around a long wall and its path is free."""

import numpy as np

from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.planning import CollisionChecker, CollisionConfig
from simn_sim.planning.gridpath import grid_shortest_path
from simn_sim.semantics import OBSTACLE


def _wall_checker():
    # a wall along y = 0 from x = -6 to x = 4 (points every 2 cm), goal behind it
    x = np.arange(-6.0, 4.0, 0.02)
    pts = np.c_[x, np.zeros_like(x), np.full_like(x, 0.5)]
    ck = CollisionChecker(CollisionConfig(robot_radius=0.25))
    ck.update(pts, np.full(len(pts), OBSTACLE))
    return ck, x


def test_detour_around_wall_is_free_and_near_exact():
    ck, x = _wall_checker()
    start, goal = np.array([0.0, -1.5]), np.array([0.0, 1.5])
    path = grid_shortest_path(ck, start, goal, np.random.default_rng(0))
    assert path is not None
    assert np.allclose(path[0], start) and np.allclose(path[-1], goal)
    assert ck.path_free(path)
    wall = np.array([[-6.0, -0.01], [4.0, -0.01], [4.0, 0.01], [-6.0, 0.01]])
    exact = FreeSpace2D([wall], robot_radius=0.25).geodesic_distance(start, goal)
    length = float(np.sum(np.hypot(*np.diff(path, axis=0).T)))
    assert exact < length < 1.15 * exact


def test_no_path_when_enclosed():
    ang = np.linspace(0, 2 * np.pi, 400)
    pts = np.c_[1.5 * np.cos(ang), 1.5 * np.sin(ang), np.full_like(ang, 0.5)]
    ck = CollisionChecker(CollisionConfig(robot_radius=0.25))
    ck.update(pts, np.full(len(pts), OBSTACLE))
    assert (
        grid_shortest_path(ck, np.zeros(2), np.array([4.0, 0.0]), np.random.default_rng(0), pad=2.0)
        is None
    )
