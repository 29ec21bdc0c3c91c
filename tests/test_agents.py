"""simn agent pieces that can be checked exactly: free-space carving, labels, config errors."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import simn_sim  # noqa: F401
from simn_sim.agents import make_agent
from simn_sim.agents.simn import label_points_world, strided
from simn_sim.config import ConfigError
from simn_sim.geometry.camera import backproject
from simn_sim.geometry.se3 import transform_points
from simn_sim.semantics import FLOOR, OBSTACLE


@pytest.fixture(scope="module")
def env():
    e = gym.make("SimnOffice-v0", config={"width": 160, "height": 120})
    yield e
    e.close()


def test_labels_floor_obstacle_unknown():
    p = np.array([[0, 0, 0.01], [0, 0, -0.03], [0, 0, 0.5], [0, 0, 1.4], [0, 0, 0.07]])
    lab = label_points_world(p, 0.06, 1.0)
    assert lab.tolist() == [FLOOR, FLOOR, OBSTACLE, 0, OBSTACLE]
    # a per-point tolerance (range-dependent) turns the last point into floor
    lab2 = label_points_world(p, np.array([0.06] * 4 + [0.1]), 1.0)
    assert lab2[-1] == FLOOR


def test_carving_removes_points_seen_through_and_keeps_visible_ones(env):
    obs, info = env.reset(seed=0)
    agent = make_agent("simn", env.unwrapped, {"carve": True})
    agent.reset(obs, info)
    T_wc = agent.T_base_est @ agent.T_base_cam
    d, intr = strided(obs["depth"], agent.intr, agent.cfg.obstacle_stride)
    P = backproject(d, intr)
    v, u = d.shape[0] // 2, d.shape[1] // 2
    z = float(d[v, u])
    assert z > 0.8
    ray = P[v, u] / z
    ghost = transform_points(
        T_wc, (ray * (z - 0.5))[None].astype(np.float64)
    )  # in front of the surface
    hidden = transform_points(T_wc, (ray * (z + 0.5))[None].astype(np.float64))  # behind it
    agent._obst_store = np.concatenate([ghost, hidden])
    agent._carve_and_store(d, intr, T_wc, np.zeros((0, 3)))
    assert agent.carved_points == 1
    np.testing.assert_allclose(agent._obst_store, hidden)


def test_bad_agent_config_is_rejected(env):
    with pytest.raises(ConfigError, match="obstacle_stride"):
        make_agent("simn", env.unwrapped, {"obstacle_stride": 0})
    with pytest.raises(ConfigError, match="unknown config key"):
        make_agent("simn", env.unwrapped, {"plnner": "uniform"})
    with pytest.raises(ConfigError, match="planner"):
        make_agent("simn", env.unwrapped, {"planner": "astar"})


def test_simn_act_is_within_bounds_and_never_reads_true_pose(env):
    obs, info = env.reset(seed=2)
    agent = make_agent("simn", env.unwrapped)
    agent.reset(obs, info)
    lo, hi = env.action_space.low, env.action_space.high
    for _ in range(15):
        a = agent.act(obs)  # no info: the agent must not need the true pose
        assert np.all(a >= lo - 1e-6) and np.all(a <= hi + 1e-6)
        obs, *_ = env.step(a)
