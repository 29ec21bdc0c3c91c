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


def _room_with_box_behind_start():
    """A 12 x 8 m walled room; the robot starts at (6, 4) facing +x; a 0.6 m cube stands 1.8 m
    behind it, outside the camera's view until the robot turns."""
    from simn_sim.env.layout import Box, Layout, Room

    t, g = 0.075, (0.8, 0.8, 0.8, 1)
    boxes = [
        Box("s", "wall", -1, (6.0, 0.0, 1.3), (6.0 + t, t, 1.3), 0.0, g),
        Box("n", "wall", -1, (6.0, 8.0, 1.3), (6.0 + t, t, 1.3), 0.0, g),
        Box("w", "wall", -1, (0.0, 4.0, 1.3), (t, 4.0 + t, 1.3), 0.0, g),
        Box("e", "wall", -1, (12.0, 4.0, 1.3), (t, 4.0 + t, 1.3), 0.0, g),
        Box("cube", "box", 0, (4.2, 4.0, 0.3), (0.3, 0.3, 0.3), 0.0, (0.6, 0.3, 0.2, 1)),
    ]
    return Layout(98, (12.0, 8.0), [Room("r", 0, 0, 12, 8)], [], boxes)


@pytest.mark.parametrize("scan", [0.0, 360.0])
def test_initial_scan_maps_what_stands_behind_the_start(scan):
    from test_env import _env_with_layout  # the env on a hand-made layout

    e = _env_with_layout(_room_with_box_behind_start())
    ep = {"episode_id": "scan", "layout_seed": None, "start": [6.0, 4.0, 0.0], "goal": [10.0, 4.0]}
    obs, info = e.reset(options={"episode": ep})
    agent = make_agent("simn", e, {"initial_scan_deg": scan})
    agent.reset(obs, info)
    n_scan = int(np.ceil(np.radians(scan) / (agent.cfg.scan_rate * e.dt)))
    for _ in range(n_scan):
        a = agent.act(obs)
        assert a[0] == 0.0 and a[1] > 0  # turning in place only
        obs, _, _, _, info = e.step(a)
    # the cube's centre in the agent's (start) frame: 1.8 m behind the robot
    cube_xy = np.array([[-1.8, 0.0]])
    clearance = float(agent.checker.clearance(cube_xy)[0])
    if scan:
        assert clearance < 0.1  # its faces (0.3 m from the centre) are in the collision model
        assert np.hypot(*(info["T_world_base"][:2, 3] - [6.0, 4.0])) < 0.02  # no translation
    else:
        assert clearance > 1.0  # never in view: unknown, so free
    e.close()


def _room_with_chair_ahead():
    """The room of ``_room_with_box_behind_start`` without the cube; 1.2 m ahead of the start
    a chair turned away from the robot: its back (a thin plate, z 0.47-0.93) hides its seat
    (0.44 m deep, top at z 0.5) from the camera at 1.0 m."""
    from simn_sim.env.layout import Box

    lay = _room_with_box_behind_start()
    lay.boxes = [b for b in lay.boxes if b.name != "cube"]
    c = (0.5, 0.5, 0.5, 1)
    lay.boxes += [
        Box("back", "chair", 1, (7.2, 4.0, 0.7), (0.0125, 0.22, 0.23), 0.0, c),
        Box("seat", "chair", 1, (7.4325, 4.0, 0.475), (0.22, 0.22, 0.025), 0.0, c),
    ]
    return lay


def _one_view(layout, agent_cfg: dict):
    """Env on ``layout`` (320x240), the robot at (6, 4) facing +x with the goal 5 m ahead, and
    a ``simn`` agent reset on the first view (no look-around)."""
    from test_env import _env_with_layout

    e = _env_with_layout(layout, width=320, height=240)
    ep = {"episode_id": "view", "layout_seed": None, "start": [6.0, 4.0, 0.0], "goal": [11.0, 4.0]}
    obs, info = e.reset(options={"episode": ep})
    agent = make_agent("simn", e, {"initial_scan_deg": 0.0, **agent_cfg})
    agent.reset(obs, info)
    return e, agent


@pytest.mark.parametrize("shadow_depth", [0.0, 0.3])
def test_occlusion_shadow_pushes_plans_off_a_seat_hidden_behind_its_back(shadow_depth):
    from simn_sim.planning.smoothing import push_from_obstacles

    # one view of the chair from 1.2 m
    e, agent = _one_view(_room_with_chair_ahead(), {"shadow_depth": shadow_depth})
    # agent (start) frame: the back's visible face at x = 1.1875, the seat x in [1.2125, 1.6525],
    # |y| <= 0.22; the back is mapped, the seat is not
    assert float(agent.checker.clearance(np.array([[1.2, 0.0]]))[0]) < 0.06
    # a path across the room 0.15 m behind the seat: free under the seen obstacles (0.61 m
    # from the back) though a robot on it (radius 0.25) hits the seat
    path = np.array([[1.8, -1.5], [1.8, 1.5]])
    assert agent.checker.path_free(path)
    pushed = push_from_obstacles(
        path, agent.checker, agent.cfg.path_clearance, also_from=agent._shadow_model()
    )
    assert agent.checker.path_free(pushed)  # shadows never make a plan unfree
    dx = np.maximum(np.abs(pushed[:, 0] - 1.4325) - 0.22, 0.0)
    dy = np.maximum(np.abs(pushed[:, 1]) - 0.22, 0.0)
    seat_dist = float(np.min(np.hypot(dx, dy)))  # exact distance to the seat's footprint
    if shadow_depth:
        assert len(agent.shadow) > 0
        assert seat_dist > agent.cfg.collision.robot_radius  # pushed clear of the hidden seat
    else:
        assert agent.shadow is None and agent.shadow_map is None
        assert seat_dist < agent.cfg.collision.robot_radius  # would hit the seat
    e.close()


def test_shadows_are_cast_only_within_shadow_range():
    # the back is 0.97 m from the camera: beyond 0.9 m
    e, agent = _one_view(_room_with_chair_ahead(), {"shadow_range": 0.9})
    assert float(agent.checker.clearance(np.array([[1.2, 0.0]]))[0]) < 0.06
    assert len(agent.shadow) == 0
    e.close()


def test_shadow_config_is_validated(env):
    with pytest.raises(ConfigError, match="shadow_depth"):
        make_agent("simn", env.unwrapped, {"shadow_depth": 0.01})
    with pytest.raises(ConfigError, match="blind_shadow_depth"):
        make_agent("simn", env.unwrapped, {"blind_shadow_depth": 0.01})
    # the SLAM preset's revisit settings, passed through the agent config
    for key, bad in [
        ("revisit_min_overlap", 1.5),
        ("revisit_registrations_per_frame", -1),
        ("describe_max_points", -1),
    ]:
        with pytest.raises(ConfigError, match=key):
            make_agent("simn", env.unwrapped, {"slam": {key: bad}}).reset(*env.reset(seed=0))


def _room_with_low_box_ahead():
    """The room of ``_room_with_box_behind_start`` without the cube; 0.55-1.0 m ahead of the
    start a 0.34 m box (the nav-ref-006 case): the camera (0.22 m ahead of the base centre, at
    1.0 m, lower border 45.25 deg down) sees its top only from x = 0.874 m in the start frame;
    the nearer part is below the view."""
    from simn_sim.env.layout import Box

    lay = _room_with_box_behind_start()
    lay.boxes = [b for b in lay.boxes if b.name != "cube"]
    lay.boxes.append(
        Box("low", "box", 2, (6.775, 4.0, 0.17), (0.225, 0.3, 0.17), 0.0, (0.6, 0.3, 0.2, 1))
    )
    return lay


@pytest.mark.parametrize("blind", [0.0, 0.6])
def test_blind_zone_shadow_covers_the_part_of_a_low_box_below_the_view(blind):
    e, agent = _one_view(_room_with_low_box_ahead(), {"blind_shadow_depth": blind})
    # start frame: the box x in [0.55, 1.0], |y| <= 0.3; only x >= 0.874 is in view
    assert float(agent.checker.clearance(np.array([[0.95, 0.0]]))[0]) < 0.06
    assert float(agent.checker.clearance(np.array([[0.6, 0.0]]))[0]) > 0.2  # unseen part
    gx, gy = np.meshgrid(np.arange(0.575, 0.85, 0.05), np.arange(-0.125, 0.13, 0.05))
    hidden = np.stack([gx.ravel(), gy.ravel()], 1)  # the hidden part, in the seen columns
    in_shadow = agent.shadow_map.clearance(hidden) < 1e-6
    if blind:
        assert in_shadow.mean() > 0.9
        # the robot's own footprint is known free: no shadow there
        assert float(agent.shadow_map.clearance(np.array([[0.0, 0.0]]))[0]) > 0.2
    else:
        assert not in_shadow.any()
    e.close()
