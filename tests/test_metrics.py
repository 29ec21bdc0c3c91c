"""Navigation metrics on hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.metrics import EpisodeMetrics, path_length, soft_spl, spl, success


def test_success_is_strict_like_habitat():
    assert success(0.19, 0.2)
    assert not success(0.2, 0.2)
    assert not success(math.inf, 0.2)


def test_spl_hand_values():
    assert spl(True, 4.0, 5.0) == pytest.approx(0.8)
    assert spl(True, 4.0, 3.0) == pytest.approx(1.0)  # shorter than geodesic: capped at 1
    assert spl(False, 4.0, 4.0) == 0.0
    assert spl(1.0, 0.0, 0.0) == 1.0  # already at the goal, did not move
    assert spl(True, 0.0, 2.0) == 0.0


def test_soft_spl_hand_values():
    # d0 = 10, final geodesic 2.5 -> soft success 0.75; path 12.5 -> efficiency 0.8.
    assert soft_spl(2.5, 10.0, 12.5) == pytest.approx(0.6)
    # Ended farther than it started: clipped to 0.
    assert soft_spl(12.0, 10.0, 3.0) == 0.0
    # Reached the goal along the geodesic.
    assert soft_spl(0.0, 10.0, 10.0) == pytest.approx(1.0)
    assert soft_spl(math.inf, 10.0, 1.0) == 0.0
    assert soft_spl(0.0, 0.0, 0.0) == 1.0
    assert soft_spl(0.5, 0.0, 1.0) == 0.0


def test_path_length():
    traj = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 0.0]])
    assert path_length(traj) == pytest.approx(9.0)
    assert path_length(traj[:1]) == 0.0
    assert path_length(np.zeros((0, 2))) == 0.0
    assert path_length(np.array([[0, 0, 0], [1, 2, 2]])) == pytest.approx(3.0)


@pytest.mark.parametrize(
    "call",
    [
        lambda: spl(True, -1.0, 2.0),
        lambda: spl(True, 1.0, float("nan")),
        lambda: spl(2.0, 1.0, 1.0),
        lambda: spl(True, math.inf, 1.0),
        lambda: soft_spl(float("nan"), 1.0, 1.0),
        lambda: soft_spl(0.5, -1.0, 1.0),
        lambda: success(-0.1, 0.2),
        lambda: success(0.1, float("nan")),
        lambda: path_length(np.array([[0.0, np.nan], [1.0, 1.0]])),
        lambda: path_length(np.zeros((3, 4))),
    ],
)
def test_bad_inputs_raise(call):
    with pytest.raises(ValueError):
        call()


def test_episode_metrics_accumulates_hand_computed_episode():
    m = EpisodeMetrics(dt=0.1)
    m.reset(np.array([0.0, 0.0]), geodesic_start=4.0)
    steps = [
        ([1.0, 0.0], False, 0.50),
        ([2.0, 0.0], True, 0.00),  # collision event 1
        ([2.0, 0.0], True, -0.01),  # still the same contact
        ([3.0, 0.0], False, 0.20),
        ([3.0, 1.0], True, 0.05),  # collision event 2
        ([4.0, 1.0], False, 0.30),
    ]
    running = []
    for xy, hit, clr in steps:
        m.step(np.array(xy), hit, clr)
        running.append(m.collisions)
    assert running == [0, 1, 1, 1, 2, 2]
    assert (m.steps, m.collided_steps, m.min_clearance_m) == (6, 3, -0.01)
    assert m.path_length_m == pytest.approx(5.0) and m.sim_time_s == pytest.approx(0.6)
    row = m.finish("success", final_distance=0.1, final_geodesic=0.1, success_distance=0.2)
    assert row["path_length_m"] == pytest.approx(5.0)
    assert row["geodesic_distance_m"] == 4.0
    assert row["success"] is True
    assert row["spl"] == pytest.approx(0.8)
    assert row["soft_spl"] == pytest.approx((1 - 0.1 / 4.0) * 0.8)
    assert row["collisions"] == 2
    assert row["collided_steps"] == 3
    assert row["min_clearance_m"] == pytest.approx(-0.01)
    assert row["steps"] == 6
    assert row["sim_time_s"] == pytest.approx(0.6)
    assert row["termination"] == "success"


def test_episode_metrics_failure_and_lifecycle():
    m = EpisodeMetrics(dt=0.05)
    with pytest.raises(RuntimeError):
        m.step(np.zeros(2), False, 1.0)
    m.reset([1.0, 1.0], 3.0)
    m.step([1.0, 2.0], False, 0.4, dt=0.2)
    row = m.finish("timeout", final_distance=2.0, final_geodesic=2.4, success_distance=0.2)
    assert row["success"] is False and row["spl"] == 0.0
    assert row["soft_spl"] == pytest.approx(1 - 2.4 / 3.0)  # p = 1 < d0 = 3: efficiency 1
    assert row["sim_time_s"] == pytest.approx(0.2)
    assert row["collisions"] == 0
    with pytest.raises(RuntimeError):
        m.finish("timeout", 1.0, 1.0, 0.2)
    m.reset([0.0, 0.0], 1.0)  # a new episode starts clean
    assert m.finish("timeout", 1.0, 1.0, 0.2)["min_clearance_m"] is None
    m.reset([0.0, 0.0], 1.0)
    with pytest.raises(ValueError):
        m.step([0.0, 0.0], False, float("nan"))
    with pytest.raises(ValueError):
        m.step([0.0, np.nan], False, 0.3)
    with pytest.raises(ValueError):
        m.reset([0.0, 0.0], -1.0)
    with pytest.raises(ValueError):
        EpisodeMetrics(dt=-0.1)
