"""SimnOffice-v0: Gymnasium conventions, determinism, camera geometry, collisions, bad input."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simn_sim  # noqa: F401  (registers the env ids)
from simn_sim.config import ConfigError
from simn_sim.env.episodes import EpisodeSpec
from simn_sim.env.layout import Box, Layout, Room
from simn_sim.env.office import SimnOfficeEnv
from simn_sim.geometry.camera import backproject
from simn_sim.geometry.se3 import transform_points

# ideal sensing: these tests check exact geometry (depth on known planes, exact odometry, exact
# speeds); realistic sensing, the default, is tested in tests/test_sensing.py
FAST = {"width": 160, "height": 120, "sensing": "ideal"}


def _reference_episode(env) -> EpisodeSpec:
    """A start in the corridor facing along +x (free straight ahead for a few metres)."""
    lay = env.unwrapped.layout
    ys = sorted({d.center[1] for d in lay.doors if d.axis == "x"})
    y_mid = 0.5 * (ys[0] + ys[-1])
    return EpisodeSpec("corridor", None, (2.0, y_mid, 0.0), (lay.size[0] - 2.0, y_mid))


@pytest.fixture(scope="module")
def env():
    e = gym.make("SimnOffice-v0", config=FAST)
    yield e
    e.close()


def test_check_env_passes():
    e = gym.make("SimnOffice-v0", config=FAST).unwrapped
    check_env(e, skip_render_check=True)
    e.close()


def test_intrinsics_are_d435i_at_640x480():
    e = SimnOfficeEnv()
    K = e.camera_info.intrinsics
    assert K.fx == pytest.approx(617.16, abs=0.01) and K.fy == pytest.approx(617.16, abs=0.01)
    assert (K.cx, K.cy) == (319.5, 239.5)
    obs, info = e.reset(seed=0)
    assert obs["rgb"].shape == (480, 640, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (480, 640) and obs["depth"].dtype == np.float32
    assert info["camera"].intrinsics == K
    e.close()


def test_same_seed_same_observations_over_50_steps():
    runs = []
    for _ in range(2):
        e = gym.make(
            "SimnOffice-v0",
            config={
                **FAST,
                "depth_noise": {"model": "d435i"},
                "odom_noise_trans": 0.05,
                "odom_noise_rot": 0.05,
            },
        )
        obs, _ = e.reset(seed=123)
        e.action_space.seed(5)
        seq = [obs]
        for _ in range(50):
            obs, *_ = e.step(e.action_space.sample())
            seq.append(obs)
        runs.append(seq)
        e.close()
    for a, b in zip(*runs, strict=True):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
    # and a different seed gives a different episode
    e = gym.make("SimnOffice-v0", config=FAST)
    o2, _ = e.reset(seed=124)
    assert not np.array_equal(o2["goal"], runs[0][0]["goal"])
    e.close()


def test_env_pickles_and_continues_identically(env):
    env.reset(seed=7)
    env.step(np.array([0.3, 0.2], np.float32))
    clone = pickle.loads(pickle.dumps(env))
    a = env.step(np.array([0.5, -0.1], np.float32))
    b = clone.step(np.array([0.5, -0.1], np.float32))
    np.testing.assert_array_equal(a[0]["depth"], b[0]["depth"])
    np.testing.assert_allclose(a[4]["T_world_base"], b[4]["T_world_base"])
    clone.close()


def test_async_vector_env_steps():
    # "spawn": a forked child must not inherit the parent's EGL contexts (fork after GL init hangs)
    venv = gym.vector.AsyncVectorEnv(
        [lambda: gym.make("simn_sim:SimnOffice-v0", config=FAST)] * 2, context="spawn"
    )
    obs, _ = venv.reset(seed=[1, 2])
    assert obs["rgb"].shape == (2, 120, 160, 3)
    for _ in range(3):
        obs, r, term, trunc, info = venv.step(np.array([[0.2, 0.0], [0.0, 0.5]], np.float32))
    assert obs["depth"].shape == (2, 120, 160)
    venv.close()


def _wall_layout() -> Layout:
    """A 20 x 14 m room whose walls are known planes (inner faces at x=0.075, x=19.925, ...)."""
    t = 0.075
    boxes = [
        Box("s", "wall", -1, (10.0, 0.0, 1.3), (10.0 + t, t, 1.3), 0.0, (0.8, 0.8, 0.8, 1)),
        Box("n", "wall", -1, (10.0, 14.0, 1.3), (10.0 + t, t, 1.3), 0.0, (0.8, 0.8, 0.8, 1)),
        Box("w", "wall", -1, (0.0, 7.0, 1.3), (t, 7.0 + t, 1.3), 0.0, (0.8, 0.8, 0.8, 1)),
        Box("e", "wall", -1, (20.0, 7.0, 1.3), (t, 7.0 + t, 1.3), 0.0, (0.8, 0.8, 0.8, 1)),
    ]
    return Layout(99, (20.0, 14.0), [Room("r", 0, 0, 20, 14)], [], boxes)


def _env_with_layout(layout: Layout, **cfg) -> SimnOfficeEnv:
    e = SimnOfficeEnv(config={**FAST, **cfg})
    e.layout = None
    e._scene = None
    import simn_sim.env.office as office

    orig = office.load_layout
    office.load_layout = lambda seed: layout
    try:
        e._layout_key = object()
        e._load_layout(None)
    finally:
        office.load_layout = orig
    return e


def test_noise_free_depth_backprojects_onto_wall_planes_within_1mm():
    e = _env_with_layout(_wall_layout(), width=320, height=240)
    # face the east wall (inner face x = 19.925) from 3 m away, then the north wall at an angle
    for start, plane_axis, plane_val in [
        ((16.9, 7.0, 0.0), 0, 19.925),
        ((10.0, 11.0, 1.2), 1, 13.925),
    ]:
        obs, info = e.reset(
            options={
                "episode": {
                    "episode_id": "w",
                    "layout_seed": None,
                    "start": list(start),
                    "goal": [3.0, 3.0],
                }
            }
        )
        pts = backproject(obs["depth"], e.camera_info.intrinsics).reshape(-1, 3)
        valid = obs["depth"].reshape(-1) > 0
        pw = transform_points(info["T_world_cam"], pts[valid].astype(np.float64))
        # every point lies on the wall plane or on the floor (z = 0): a point off the floor by
        # more than 1 mm must be on the wall within 1 mm, and all others on the floor within 1 mm
        on_wall = pw[:, 2] > 1e-3
        assert on_wall.sum() > 1000
        err = np.abs(pw[on_wall, plane_axis] - plane_val)
        assert err.max() < 1e-3, f"max plane error {err.max() * 1000:.2f} mm"
        floor = pw[~on_wall]
        if len(floor):
            assert np.abs(floor[:, 2]).max() < 1e-3
    e.close()


def test_driving_into_wall_is_a_collision_and_does_not_pass_through():
    e = _env_with_layout(_wall_layout())
    e.reset(
        options={
            "episode": {
                "episode_id": "w",
                "layout_seed": None,
                "start": [18.5, 7.0, 0.0],
                "goal": [3.0, 3.0],
            }
        }
    )
    n_coll = 0
    for _ in range(40):
        _, _, term, trunc, info = e.step(np.array([1.0, 0.0], np.float32))
        n_coll += info["collided"]
        x = info["T_world_base"][0, 3]
        # hull radius 0.25, wall face at 19.925: the centre may not get past 19.675 (+ contact softness)
        assert x < 19.925 - 0.25 + 0.02
        if term or trunc:
            break
    assert n_coll >= 10
    assert e.metrics.collisions == 1  # one continuous contact is one collision event
    e.close()


def test_straight_drive_matches_commanded_speed_and_odometry_exact_without_noise(env):
    ep = _reference_episode(env)
    obs, info = env.reset(options={"episode": ep.to_dict()})
    x0 = info["T_world_base"][0, 3]
    for _ in range(20):
        obs, _, _, _, info = env.step(np.array([0.5, 0.0], np.float32))
    dx = info["T_world_base"][0, 3] - x0
    assert dx == pytest.approx(0.5 * 2.0, abs=0.03)  # 20 steps at 10 Hz
    np.testing.assert_allclose(obs["odometry"][:2], [dx, 0.0], atol=1e-4)


@pytest.mark.parametrize(
    "action,match",
    [
        ([np.nan, 0.0], "NaN"),
        ([np.inf, 0.0], "NaN or inf"),
        ([0.1, 0.2, 0.3], "shape"),
        ([5.0, 0.0], "out of bounds"),
        ([0.0, -9.0], r"w in \[-1.5, 1.5\]"),
    ],
)
def test_bad_actions_raise_naming_the_bounds(env, action, match):
    env.reset(seed=1)
    with pytest.raises(ValueError, match=match):
        env.step(np.array(action, np.float32))


def test_clip_action_wrapper_clips(env):
    w = gym.wrappers.ClipAction(env)
    w.reset(seed=1)
    w.step(np.array([5.0, 0.0], np.float32))  # no error once wrapped


def test_unknown_env_id_and_bad_config_values():
    with pytest.raises(gym.error.Error):
        gym.make("SimnOffice-v99")
    with pytest.raises(ConfigError, match="success_distance"):
        gym.make("SimnOffice-v0", config={"success_distance": -1.0})
    with pytest.raises(ConfigError, match="unknown config key"):
        gym.make("SimnOffice-v0", config={"widht": 320})
    with pytest.raises(ConfigError, match="model"):
        gym.make("SimnOffice-v0", config={"depth_noise": {"model": "kinect"}})


def test_bad_episode_rejected(env):
    with pytest.raises(ValueError, match="not in free space"):
        env.reset(
            options={
                "episode": {
                    "episode_id": "x",
                    "layout_seed": None,
                    "start": [0.0, 0.0, 0.0],
                    "goal": [5, 5],
                }
            }
        )
    with pytest.raises(ValueError, match="NaN"):
        env.reset(
            options={
                "episode": {
                    "episode_id": "x",
                    "layout_seed": None,
                    "start": [1.0, math.nan, 0.0],
                    "goal": [5, 5],
                }
            }
        )


def test_corrupt_episode_file(tmp_path):
    from simn_sim.env.episodes import EpisodeSet

    p = tmp_path / "eps.json"
    p.write_text('{"format": "simn-sim-episodes/1", "episodes": [{"episode_id": "a"')
    with pytest.raises(ValueError, match="corrupt episode file"):
        EpisodeSet.load(p)
    p.write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="not a simn-sim episode file"):
        EpisodeSet.load(p)


def test_goal_observation_is_in_start_frame(env):
    obs, info = env.reset(seed=3)
    T = info["T_world_base"]
    goal_w = np.asarray(info["episode_spec"]["goal"])
    g = np.linalg.inv(T) @ np.array([*goal_w, 0.0, 1.0])
    np.testing.assert_allclose(obs["goal"], g[:2], atol=1e-5)
    assert info["geodesic_distance_to_goal"] >= info["distance_to_goal"] - 1e-9


def test_render_modes():
    e = gym.make("SimnOffice-v0", config=FAST, render_mode="rgb_array")
    e.reset(seed=0)
    img = e.render()
    assert img.shape == (480, 640, 3) and img.std() > 5
    e.close()
    e = gym.make("SimnOffice-v0", config=FAST, render_mode="rgbd_tuple")
    obs, _ = e.reset(seed=0)
    rgb, depth = e.render()
    np.testing.assert_array_equal(depth, obs["depth"])
    e.close()


def test_agent_registry_lists_builtin_agents_and_rejects_unknown(env):
    import simn_sim.agents.simn  # noqa: F401  (importing one agent module first must not hide others)
    from simn_sim.agents import agent_names, make_agent

    assert {"oracle", "simn", "rrtstar"} <= set(agent_names())
    with pytest.raises(ValueError, match="unknown agent 'nope'"):
        make_agent("nope", env.unwrapped)


def test_depth_after_turning_and_driving_matches_the_reported_camera_pose():
    """The image returned by ``step`` is rendered at the pose ``info`` reports. (It lagged one
    physics substep: after ``mj_step`` MuJoCo's camera poses are those of the state before the
    last integration, 0.9 deg behind at 0.8 rad/s, until kinematics are recomputed.)"""
    e = _env_with_layout(_wall_layout(), width=320, height=240)
    obs, info = e.reset(
        options={
            "episode": {
                "episode_id": "w",
                "layout_seed": None,
                "start": [15.0, 7.0, 0.0],
                "goal": [3.0, 3.0],
            }
        }
    )
    for action in ([0.0, 1.0], [0.0, 1.0], [0.5, -1.0], [0.8, 0.0]):
        obs, _, _, _, info = e.step(np.array(action, np.float32))
        pts = backproject(obs["depth"], e.camera_info.intrinsics).reshape(-1, 3)
        valid = obs["depth"].reshape(-1) > 0
        pw = transform_points(info["T_world_cam"], pts[valid].astype(np.float64))
        on_wall = pw[:, 2] > 2e-3
        assert on_wall.sum() > 1000
        # the east wall's inner face is x = 19.925: every point above the floor lies on it
        err = np.abs(pw[on_wall, 0] - 19.925)
        assert err.max() < 1e-3, f"action {action}: max plane error {err.max() * 1000:.1f} mm"
        assert np.abs(pw[~on_wall, 2]).max() < 2e-3
    e.close()
