"""People in the dynamic office yield to the robot: exact geometry in an empty room."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.env.people import YIELD_GAP, _People
from simn_sim.env.scene import PERSON_RADIUS, ROBOT_RADIUS
from simn_sim.geometry.freespace import FreeSpace2D

DT = 0.1


def _walker(yield_to_robot: bool) -> _People:
    """One person at (1, 2) walking east at 1 m/s to (9, 2) in an empty 10 x 4 m room."""
    fs = FreeSpace2D([], robot_radius=ROBOT_RADIUS, bounds=(0.5, 0.5, 9.5, 3.5))
    p = _People(fs, 1, np.random.default_rng(0), yield_to_robot=yield_to_robot)
    p.pos[0] = (1.0, 2.0)
    p.paths[0] = np.array([[9.0, 2.0]])
    p.speed[0] = 1.0
    return p


def _gap(p: _People, robot: np.ndarray) -> float:
    return float(np.hypot(*(p.pos[0] - robot))) - ROBOT_RADIUS - PERSON_RADIUS


def test_a_person_stops_short_of_a_robot_in_its_way_then_walks_elsewhere():
    robot = np.array([5.0, 2.0])  # on the person's straight line
    p = _walker(True)
    gaps = []
    for _ in range(80):  # 8 s: about 3.1 s walking, 3 s waiting
        p.advance(DT, robot)
        gaps.append(_gap(p, robot))
    # it walked up to within one step (0.1 m) of the yield gap and never closer
    assert min(gaps) > YIELD_GAP - 0.1 - 1e-9
    assert min(gaps) <= YIELD_GAP
    # it waited 3 s (patience), then took another target: its path changed
    assert not np.allclose(p.paths[0][-1], (9.0, 2.0))


def test_a_robot_behind_or_beside_is_not_in_the_way():
    p = _walker(True)
    behind = np.array([0.6, 2.0])
    p.advance(DT, behind)
    assert p.pos[0][0] == pytest.approx(1.1)  # walked on, away from the robot
    p2 = _walker(True)
    beside = np.array([1.2, 2.0 + ROBOT_RADIUS + PERSON_RADIUS + 0.2])  # 84 deg off its way
    p2.advance(DT, beside)
    assert p2.pos[0][0] == pytest.approx(1.1)


def test_without_yielding_a_person_walks_through_the_robot_position():
    robot = np.array([5.0, 2.0])
    p = _walker(False)
    gaps = []
    for _ in range(60):
        p.advance(DT, robot)
        gaps.append(_gap(p, robot))
    assert min(gaps) < -ROBOT_RADIUS  # the capsules overlapped (a collision in the sim)
