"""Realistic sensing (the default of SimnOffice-v0) against ideal sensing: D435i depth, odometry
drift, actuation noise; the preset switch, explicit overrides and seeded determinism."""

from __future__ import annotations

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import simn_sim  # noqa: F401  (registers the env ids)
import simn_sim.env.office as office
from simn_sim.config import ConfigError
from simn_sim.env.layout import Box, Layout, Room
from simn_sim.env.noise import (
    ActuationNoise,
    ActuationNoiseConfig,
    depth_sigma,
    odometry_step,
)
from simn_sim.env.office import SimnOfficeEnv
from simn_sim.env.office_config import SENSING_PRESETS, EnvConfig, env_config_from_file
from simn_sim.experiments.batch_config import resolve_env_config
from simn_sim.geometry.camera import backproject
from simn_sim.geometry.se3 import inv_T, transform_points

WALL_X = 19.925  # inner face of the east wall of the test room


def _room() -> Layout:
    """A 20 x 14 m empty room whose walls are known planes (east wall face at x = 19.925)."""
    t, c = 0.075, (0.8, 0.8, 0.8, 1)
    boxes = [
        Box("s", "wall", -1, (10.0, 0.0, 1.3), (10.0 + t, t, 1.3), 0.0, c),
        Box("n", "wall", -1, (10.0, 14.0, 1.3), (10.0 + t, t, 1.3), 0.0, c),
        Box("w", "wall", -1, (0.0, 7.0, 1.3), (t, 7.0 + t, 1.3), 0.0, c),
        Box("e", "wall", -1, (20.0, 7.0, 1.3), (t, 7.0 + t, 1.3), 0.0, c),
    ]
    return Layout(99, (20.0, 14.0), [Room("r", 0, 0, 20, 14)], [], boxes)


def _room_env(**cfg) -> SimnOfficeEnv:
    orig = office.load_layout
    office.load_layout = lambda seed: _room()
    try:
        return SimnOfficeEnv(config=cfg)
    finally:
        office.load_layout = orig


def _episode(x: float, y: float = 7.0, yaw: float = 0.0) -> dict:
    return {"episode_id": "room", "layout_seed": None, "start": [x, y, yaw], "goal": [3.0, 3.0]}


def _pose2d(T: np.ndarray) -> np.ndarray:
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


# ---- the switch ------------------------------------------------------------------------------


def test_realistic_is_the_default_and_ideal_is_one_switch_away():
    cfg = EnvConfig()
    assert cfg.sensing == "realistic"
    assert cfg.depth_noise.model == "d435i"
    assert (cfg.odom_noise_trans, cfg.odom_noise_rot) == (0.02, 0.02)
    assert cfg.actuation_noise.model == "gaussian"
    d = cfg.to_dict()  # the resolved values, as written beside every result
    assert d["depth_noise"]["model"] == "d435i" and d["actuation_noise"]["sigma_v"] == 0.167
    for env_id in ("SimnOffice-v0", "SimnOfficeFast-v0", "SimnOfficeDynamic-v0"):
        assert resolve_env_config(env_id, {})["sensing"] == "realistic", env_id
    ideal = resolve_env_config("SimnOfficeIdeal-v0", {})
    assert ideal["sensing"] == "ideal" and ideal["depth_noise"]["model"] == "none"
    assert ideal["odom_noise_trans"] == ideal["odom_noise_rot"] == 0.0
    assert ideal["actuation_noise"]["model"] == "none"
    assert resolve_env_config("SimnOffice-v0", {"sensing": "ideal"}) == ideal
    assert EnvConfig.from_dict(d) == cfg  # the resolved dict round-trips


def test_explicit_noise_keys_override_the_preset():
    c = EnvConfig(sensing="ideal", odom_noise_trans=0.05, depth_noise={"model": "d435i"})
    assert c.odom_noise_trans == 0.05 and c.odom_noise_rot == 0.0
    assert c.depth_noise.model == "d435i" and c.actuation_noise.model == "none"
    # a partial mapping is merged over the preset's
    c = EnvConfig(depth_noise={"sigma_disparity_px": 0.1}, actuation_noise={"tau_s": 0.0})
    assert c.depth_noise.model == "d435i" and c.depth_noise.sigma_disparity_px == 0.1
    assert c.actuation_noise.model == "gaussian" and c.actuation_noise.tau_s == 0.0
    # replace re-resolves the keys that were not given, keeps the ones that were
    r = EnvConfig(odom_noise_rot=0.1).replace(sensing="ideal")
    assert r.odom_noise_rot == 0.1 and r.odom_noise_trans == 0.0 and r.depth_noise.model == "none"
    # the explicit keys of an existing config file keep their meaning
    env = gym.make("SimnOfficeIdeal-v0", config={"width": 16, "height": 16, "odom_noise_rot": 0.3})
    assert env.unwrapped.cfg.odom_noise_rot == 0.3 and env.unwrapped.cfg.sensing == "ideal"
    env.close()


def test_yaml_with_the_old_noise_keys_still_loads(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("width: 320\nheight: 240\ndepth_noise: {model: none}\nodom_noise_trans: 0.0\n")
    c = env_config_from_file(p)
    assert c.depth_noise.model == "none" and c.odom_noise_trans == 0.0
    assert c.odom_noise_rot == SENSING_PRESETS["realistic"]["odom_noise_rot"]


def test_bad_sensing_value_is_a_config_error_naming_it():
    with pytest.raises(
        ConfigError, match=r"sensing: 'noisy' is not one of \('realistic', 'ideal'\)"
    ):
        gym.make("SimnOffice-v0", config={"sensing": "noisy"})
    with pytest.raises(ConfigError, match="sigma_v"):
        EnvConfig(actuation_noise={"sigma_v": -0.1})
    with pytest.raises(ConfigError, match="model"):
        EnvConfig(actuation_noise={"model": "habitat"})


# ---- depth -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def room_envs():
    real = _room_env(width=320, height=240)
    ideal = _room_env(width=320, height=240, sensing="ideal")
    yield real, ideal
    real.close()
    ideal.close()


def _wall_pixels(env: SimnOfficeEnv, depth: np.ndarray, T_world_cam: np.ndarray):
    """Mask of the pixels (and of their 4-neighbours) that see the east wall, and the world x of
    every pixel: ``depth`` is an exact render."""
    pts = backproject(depth, env.camera_info.intrinsics).reshape(-1, 3).astype(np.float64)
    pw = transform_points(T_world_cam, pts).reshape(*depth.shape, 3)
    wall = (depth > 0) & (pw[..., 2] > 0.05)
    inner = wall.copy()
    inner[1:] &= wall[:-1]
    inner[:-1] &= wall[1:]
    inner[:, 1:] &= wall[:, :-1]
    inner[:, :-1] &= wall[:, 1:]
    return wall, inner, pw[..., 0]


def test_depth_has_dropouts_and_an_error_growing_with_z_squared(room_envs):
    """Realistic against ideal depth of the same pose, facing a wall 2, 4 and 6 m away."""
    real, ideal = room_envs
    fx = real.intrinsics.fx
    rms, predicted, dropped = [], [], []
    for dist in (2.0, 4.0, 6.0):
        ep = _episode(WALL_X - dist)
        o_real, _ = real.reset(seed=5, options={"episode": ep})
        o_ideal, info = ideal.reset(seed=5, options={"episode": ep})
        z_true, z = o_ideal["depth"], o_real["depth"]
        wall, inner, x_world = _wall_pixels(ideal, z_true, info["T_world_cam"])
        assert inner.sum() > 5000
        # the ideal render is exact: every wall pixel back-projects onto the wall's plane
        assert np.abs(x_world[wall] - WALL_X).max() < 1e-3
        ok = inner & (z > 0)
        dropped.append(1.0 - ok.sum() / inner.sum())
        err = (z - z_true)[ok]
        sigma = depth_sigma(z_true[ok], fx, real.cfg.depth_noise)
        # unbiased, and the error normalised by the model's z^2 * 0.08 px / (f b) has std 1
        assert abs(err.mean()) < 0.1 * np.sqrt(np.mean(sigma**2))
        assert np.std(err / sigma) == pytest.approx(1.0, abs=0.1)
        rms.append(np.sqrt(np.mean(err**2)))
        predicted.append(np.sqrt(np.mean(sigma**2)))
    # at 320x240 (f = 309 px): 1.7 cm at 1.8 m, 7.1 cm at 3.7 m, 16 cm at 5.5 m along the axis
    np.testing.assert_allclose(rms, predicted, rtol=0.1)
    assert rms[2] / rms[0] > 6.0  # grows like z^2 (the wall spans a range of depths at each)
    # random dropouts (0.002 of the pixels) away from depth edges
    assert 0.0005 < np.mean(dropped) < 0.005


def test_depth_drops_about_half_the_pixels_at_depth_edges():
    """A box in front of the wall: the pixels at its depth edges read 0 with probability 0.5."""
    lay = _room()
    lay.boxes.append(Box("b", "box", 0, (17.5, 7.6, 0.5), (0.3, 0.3, 0.5), 0.0, (0.5, 0.4, 0.3, 1)))
    orig = office.load_layout
    office.load_layout = lambda seed: lay
    try:
        real = SimnOfficeEnv(config={"width": 160, "height": 120})
        ideal = SimnOfficeEnv(config={"width": 160, "height": 120, "sensing": "ideal"})
    finally:
        office.load_layout = orig
    ep = _episode(14.5)
    zr = real.reset(seed=2, options={"episode": ep})[0]["depth"]
    zi = ideal.reset(seed=2, options={"episode": ep})[0]["depth"]
    jump = np.abs(np.diff(zi, axis=1)) / np.minimum(zi[:, 1:], zi[:, :-1]).clip(1e-6) > 0.04
    edge = np.zeros_like(zi, bool)
    edge[:, 1:] |= jump
    edge[:, :-1] |= jump
    edge &= zi > 0
    assert edge.sum() > 50
    assert 0.35 < (zr[edge] == 0).mean() < 0.65
    real.close()
    ideal.close()


# ---- odometry --------------------------------------------------------------------------------


def test_odometry_drift_statistics_over_10m():
    """The realistic drift (0.02 / 0.02) measured: 10 m straight at 0.5 m/s (0.05 m a step)
    gives a heading std of 0.014 rad and a lateral std of about 8 cm; these are the docs'."""
    rng = np.random.default_rng(0)
    errs = []
    for _ in range(300):
        o, p = np.zeros(3), np.zeros(3)
        for _ in range(200):
            q = p + [0.05, 0.0, 0.0]
            o = odometry_step(o, p, q, 0.02, 0.02, rng)
            p = q
        errs.append(o - p)
    std = np.array(errs).std(0)
    assert std[0] == pytest.approx(0.02 * math.sqrt(10 * 0.05), rel=0.15)  # 1.4 cm along
    assert std[2] == pytest.approx(0.02 * math.sqrt(10 * 0.05), rel=0.15)  # 0.014 rad
    assert std[1] == pytest.approx(0.0816, rel=0.15)  # lateral: L * heading std / sqrt(3)
    # no noise: exact, and nothing drawn
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    o = odometry_step(np.zeros(3), np.zeros(3), np.array([0.3, 0.1, 0.2]), 0.0, 0.0, rng)
    np.testing.assert_allclose(o, [0.3, 0.1, 0.2])
    assert rng.bit_generator.state == state


def test_odometry_diverges_from_the_true_pose_under_realistic_sensing_only():
    real = _room_env(width=16, height=16)
    ideal = _room_env(width=16, height=16, sensing="ideal")
    final = {}
    for name, env in (("realistic", real), ("ideal", ideal)):
        obs, info = env.reset(seed=3, options={"episode": _episode(5.0)})
        T_sw = inv_T(info["T_world_base"])
        errs = []
        for k in range(120):
            obs, _, _, _, info = env.step(np.array([0.6, 0.5 if (k // 20) % 2 else -0.5]))
            true = _pose2d(T_sw @ info["T_world_base"])
            d = obs["odometry"].astype(float) - true
            d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
            errs.append(np.abs(d))
        final[name] = np.array(errs)
        env.close()
    assert final["ideal"].max() < 1e-4  # float32 odometry of the exact pose
    assert final["realistic"][-1, :2].max() > 5e-3
    assert final["realistic"][-20:, :2].mean() > final["realistic"][:20, :2].mean()  # grows


# ---- actuation -------------------------------------------------------------------------------


def test_actuation_noise_has_the_configured_statistics():
    cfg = ActuationNoiseConfig(model="gaussian")
    dt = 0.1
    rng = np.random.default_rng(1)
    an = ActuationNoise(cfg, dt)
    an.reset(rng)
    g = np.array([an.apply(1.0, 1.0, rng) for _ in range(40000)]) - 1.0 - an.bias
    np.testing.assert_allclose(g.mean(0), 0.0, atol=0.01)
    np.testing.assert_allclose(g.std(0), [cfg.sigma_v, cfg.sigma_w], rtol=0.05)
    r = g - g.mean(0)
    lag1 = (r[1:] * r[:-1]).mean(0) / r.var(0)
    np.testing.assert_allclose(lag1, math.exp(-dt / cfg.tau_s), atol=0.03)
    bias = []
    for _ in range(4000):
        an.reset(rng)
        bias.append(an.bias.copy())
    np.testing.assert_allclose(np.std(bias, 0), [cfg.bias_v, cfg.bias_w], rtol=0.06)
    # a zero command stays zero; the executed motion never opposes the command
    assert an.apply(0.0, 0.0, rng) == (0.0, 0.0)
    v, w = an.apply(-0.3, -1.5, rng)
    assert v < 0 and w < 0
    # model none: the command, and nothing drawn
    none = ActuationNoise(ActuationNoiseConfig(), dt)
    state = rng.bit_generator.state
    none.reset(rng)
    assert none.apply(0.4, -0.2, rng) == (0.4, -0.2)
    assert rng.bit_generator.state == state


def test_env_executes_the_noisy_velocity_and_validates_the_command():
    env = _room_env(width=16, height=16)
    obs, info = env.reset(seed=4, options={"episode": _episode(10.0)})
    yaw, executed = [_pose2d(info["T_world_base"])[2]], []
    for _ in range(150):
        obs, _, _, _, info = env.step(np.array([0.0, 1.0], np.float32))
        yaw.append(_pose2d(info["T_world_base"])[2])
        executed.append(info["executed_action"])
    ex = np.array(executed)
    assert ex.shape == (150, 2) and (ex[:, 0] == 0.0).all()
    rel = ex[:, 1] - 1.0  # relative error of w (the command is 1 rad/s)
    cfg = env.cfg.actuation_noise
    assert 0.5 * cfg.sigma_w < rel.std() < 1.5 * cfg.sigma_w
    # the physics turns at the executed rate (1 % residual), not the commanded one
    rate = np.diff(np.unwrap(yaw)) / env.dt
    assert np.std(rate - ex[:, 1]) < 0.2 * np.std(rate - 1.0)
    # the command is validated as before: out of bounds raises, the bound itself is fine
    with pytest.raises(ValueError, match="out of bounds"):
        env.step(np.array([1.2, 0.0], np.float32))
    env.step(np.array([1.0, 1.5], np.float32))
    env.close()


# ---- ideal -----------------------------------------------------------------------------------


def test_ideal_sensing_is_exact(room_envs):
    _, ideal = room_envs
    obs, info = ideal.reset(seed=0, options={"episode": _episode(16.0)})
    T_sw = inv_T(info["T_world_base"])
    for a in ([0.5, 0.0], [0.3, 0.8], [0.0, -1.0]):
        obs, _, _, _, info = ideal.step(np.array(a, np.float32))
        np.testing.assert_array_equal(info["executed_action"], np.array(a, np.float32))
        np.testing.assert_allclose(obs["odometry"], _pose2d(T_sw @ info["T_world_base"]), atol=1e-5)
    obs, info = ideal.reset(seed=0, options={"episode": _episode(WALL_X - 3.0)})
    wall, _, x_world = _wall_pixels(ideal, obs["depth"], info["T_world_cam"])
    assert wall.sum() > 5000 and np.abs(x_world[wall] - WALL_X).max() < 1e-3
    assert (obs["depth"][obs["depth"] == 0].size) == 0  # no dropouts (all in range here)


# ---- determinism -----------------------------------------------------------------------------


def _assert_same(a, b, path="") -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=path)
    elif hasattr(a, "__dataclass_fields__"):
        for k in a.__dataclass_fields__:
            _assert_same(getattr(a, k), getattr(b, k), f"{path}.{k}")
    else:
        assert a == b or (a != a and b != b), path  # NaN == NaN here


def _rollout(seed: int, episode: dict | None = None, n: int = 30):
    env = gym.make("SimnOffice-v0", config={"width": 64, "height": 48, "max_episode_steps": n})
    obs, info = env.reset(seed=seed, options={"episode": episode} if episode else None)
    act_rng = np.random.default_rng(7)
    out = [(obs, info)]
    for _ in range(n):
        a = np.array([act_rng.uniform(0.0, 0.6), act_rng.uniform(-1.0, 1.0)], np.float32)
        obs, r, term, trunc, info = env.step(a)
        out.append((obs, {**info, "reward": r, "term": term, "trunc": trunc}))
        if term or trunc:
            break
    env.close()
    return out


def test_same_seed_gives_bit_identical_episodes_under_realistic_sensing():
    a, b = _rollout(11), _rollout(11)
    assert len(a) == len(b) and "episode" in a[-1][1]  # ran to the end: the episode record
    for (oa, ia), (ob, ib) in zip(a, b, strict=True):
        _assert_same(oa, ob, "obs")
        _assert_same(ia, ib, "info")
    # another seed on the same episode: the same start, different noise
    ep = a[0][1]["episode_spec"]
    c, d = _rollout(12, ep, n=3), _rollout(13, ep, n=3)
    np.testing.assert_array_equal(c[0][1]["T_world_base"], d[0][1]["T_world_base"])
    assert not np.array_equal(c[0][0]["depth"], d[0][0]["depth"])
    assert not np.array_equal(c[1][1]["executed_action"], d[1][1]["executed_action"])
    assert not np.array_equal(c[-1][0]["odometry"], d[-1][0]["odometry"])


def test_realistic_env_passes_check_env_and_pickles_with_its_noise_state():
    env = gym.make("SimnOffice-v0", config={"width": 32, "height": 24}).unwrapped
    check_env(env, skip_render_check=True)
    env.reset(seed=9)
    env.step(np.array([0.3, 0.2], np.float32))
    clone = pickle.loads(pickle.dumps(env))
    for a in ([0.5, -0.1], [0.2, 0.4]):
        x = env.step(np.array(a, np.float32))
        y = clone.step(np.array(a, np.float32))
        _assert_same(x[0], y[0], "obs")
        _assert_same(x[4], y[4], "info")
    env.close()
    clone.close()
