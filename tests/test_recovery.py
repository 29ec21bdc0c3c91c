"""The agent's recovery pieces (simn_sim.agents.recovery) against exact geometry: a wall at a
known distance, and the step counts that lost progress and map clearing are defined by."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.agents.recovery import NoRouteWatch, ProgressWatch, back_off
from simn_sim.planning import FollowerConfig
from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.collision_config import CollisionConfig

R = 0.25
CC = CollisionConfig(robot_radius=R, margin=0.1, z_min=0.06, z_max=1.0)
F = FollowerConfig(w_max=1.0)
X_WALL = 1.025


def wall_checker(margin: float) -> CollisionChecker:
    """The wall x = X_WALL (y in [-3, 3]; on the 5 cm grid's cell centres, so clearances to it
    are exact) in a checker with ``margin``."""
    ys = np.arange(-3.0, 3.0, 0.01)
    pts = np.c_[np.full_like(ys, X_WALL), ys, np.full_like(ys, 0.5)]
    ch = CollisionChecker(CC.replace(margin=margin))
    ch.update(pts, np.full(len(pts), 2, np.int8))
    return ch


def test_back_off_escapes_when_touching_and_turns_away_from_the_wall():
    planning = wall_checker(0.1)
    asked = []

    def active():
        asked.append(True)
        return wall_checker(0.03)

    # 0.225 m from the wall, facing it: nearer than the radius + 1 cm
    out = back_off(np.array([X_WALL - 0.225, 0.0, 0.0]), planning, R + 0.01, active, F)
    assert out is not None and out[0] == "escaping"
    v, w = out[1]
    assert v == 0.0 and abs(w) > 0  # the freest direction is behind: turn in place
    assert not asked  # the active model is not consulted while touching


def test_back_off_recovers_inside_the_margin_towards_free_space():
    planning, safety = wall_checker(0.1), wall_checker(0.03)
    # 0.27 m from the wall, facing away from it: not touching (0.26), inside the safety
    # inflation (0.28)
    assert planning.clearance(np.array([[X_WALL - 0.27, 0.0]]))[0] == pytest.approx(0.27, abs=0.005)
    pose = np.array([X_WALL - 0.27, 0.0, math.pi])
    out = back_off(pose, planning, R + 0.01, lambda: safety, F)
    assert out is not None and out[0] == "recovering"
    v, w = out[1]
    assert v > 0  # the nearest free point (planning inflation 0.35) lies ahead, away from x = 1


def test_back_off_is_none_in_free_space():
    planning, safety = wall_checker(0.1), wall_checker(0.03)
    assert back_off(np.array([0.0, 0.0, 0.0]), planning, R + 0.01, lambda: safety, F) is None


def test_progress_watch_stalls_after_exactly_stall_steps_without_progress():
    pw = ProgressWatch(stall_steps=5, eps=0.5)
    pw.update(10.0, 0)
    pw.update(9.6, 3)  # less than eps below the best: no progress
    assert pw.best == 10.0 and pw.best_step == 0
    assert not pw.stalled(5) and pw.stalled(6)
    pw.update(9.4, 6)  # more than eps below: progress
    assert pw.best_step == 6 and not pw.stalled(11) and pw.stalled(12)
    pw.restart(20)
    assert pw.best == math.inf and not pw.stalled(25) and pw.stalled(26)


def test_no_route_watch_clears_after_clear_after_steps_once_per_cooldown():
    nw = NoRouteWatch(clear_after=3, cooldown=10)
    assert [nw.no_route(s) for s in (1, 2, 3)] == [False, False, True]
    # the count restarted at the clear; the next 3 in a row fall inside the cooldown
    assert [nw.no_route(s) for s in (4, 5, 6, 7)] == [False, False, False, False]
    assert nw.no_route(13) is True  # 4 in a row since the clear, 10 steps after it
    nw.route()
    assert nw.count == 0
    off = NoRouteWatch(clear_after=0, cooldown=1)
    assert not any(off.no_route(s) for s in range(100))
