"""Pure-pursuit follower: bounds, driving a unicycle along an L path, slow-downs, blocked/stale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.planning import CollisionChecker
from simn_sim.planning.follower import FollowerConfig, PathFollower

L_PATH = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0]])


def drive(f: PathFollower, pose, dt: float = 0.05, steps: int = 800):
    """Integrate the unicycle x' = v cos(yaw), y' = v sin(yaw), yaw' = w (exact arcs)."""
    pose = np.array(pose, float)
    log = []
    for _ in range(steps):
        cmd = f.step(pose)
        log.append((pose.copy(), cmd))
        if cmd.status in ("reached", "blocked", "stale"):
            break
        v, w = cmd.v, cmd.w
        x, y, th = pose
        if abs(w) < 1e-9:
            x, y = x + v * dt * math.cos(th), y + v * dt * math.sin(th)
        else:
            x += v / w * (math.sin(th + w * dt) - math.sin(th))
            y -= v / w * (math.cos(th + w * dt) - math.cos(th))
        pose = np.array([x, y, th + w * dt])
    return pose, log


def wall_checker(points_xy: np.ndarray) -> CollisionChecker:
    c = CollisionChecker()
    c.update(np.column_stack([points_xy, np.full(len(points_xy), 0.5)]))
    return c


def test_drives_l_path_to_goal_within_bounds() -> None:
    cfg = FollowerConfig()
    f = PathFollower(cfg)
    f.set_path(L_PATH)
    pose, log = drive(f, [0.0, 0.0, 0.0])
    assert log[-1][1].status == "reached"
    assert np.hypot(*(pose[:2] - L_PATH[-1])) <= cfg.goal_tolerance
    vs = np.array([c.v for _, c in log])
    ws = np.array([c.w for _, c in log])
    assert np.all((vs >= cfg.v_min) & (vs <= cfg.v_max))
    assert np.all((ws >= cfg.w_min) & (ws <= cfg.w_max))
    assert vs.max() > 0.9 * cfg.v_max  # it does drive at speed on the straight
    assert max(c.cross_track for _, c in log) < 0.35  # corner cut bounded by the lookahead
    # slows down when approaching the goal
    near_goal = [c.v for p, c in log if np.hypot(*(p[:2] - L_PATH[-1])) < 0.3]
    assert near_goal and max(near_goal) < 0.5 * cfg.v_max
    assert len(log) * 0.05 < 15.0  # 6 m at up to 0.8 m/s


def test_turns_in_place_when_facing_away() -> None:
    f = PathFollower()
    f.set_path(L_PATH)
    cmd = f.step([0.0, 0.0, math.pi])  # facing backwards
    assert cmd.status == "turn" and cmd.v == 0.0 and abs(cmd.w) > 0.5
    pose, log = drive(f, [0.0, 0.0, math.pi])
    assert log[-1][1].status == "reached"


def test_commands_within_bounds_for_random_poses() -> None:
    cfg = FollowerConfig(v_min=-0.1, v_max=0.5, w_min=-0.7, w_max=1.2, lookahead=0.4)
    rng = np.random.default_rng(0)
    for _ in range(300):
        f = PathFollower(cfg, wall_checker(np.array([[1.5, 0.6], [1.6, 0.6]])))
        f.set_path(L_PATH)
        pose = np.array([*rng.uniform([-0.3, -0.4], [3.4, 3.3]), rng.uniform(-4, 4)])
        cmd = f.step(pose)
        assert cfg.v_min <= cmd.v <= cfg.v_max and cfg.w_min <= cmd.w <= cfg.w_max


def test_slows_near_obstacles() -> None:
    path = np.array([[0.0, 0.0], [6.0, 0.0]])
    free = PathFollower(checker=wall_checker(np.array([[0.0, 5.0]])))
    tight = PathFollower(
        checker=wall_checker(np.column_stack([np.linspace(0, 6, 200), np.full(200, 0.4)]))
    )
    for f in (free, tight):
        f.set_path(path)
    a, b = free.step([2.0, 0.0, 0.0]), tight.step([2.0, 0.0, 0.0])
    assert a.status == b.status == "follow"
    assert b.v < 0.5 * a.v


def test_flags_blocked_and_stale() -> None:
    c = wall_checker(np.array([[10.0, 10.0]]))
    f = PathFollower(checker=c)
    f.set_path(L_PATH)
    pose, log = drive(f, [0.0, 0.0, 0.0], steps=30)
    assert log[-1][1].status == "follow"
    # the map grows: an obstacle appears on the path 1 m ahead
    ahead = f.step(pose).lookahead_xy + np.array([0.6, 0.0])
    c.update(np.array([[ahead[0], 0.0, 0.5]]))
    cmd = f.step(pose)
    assert cmd.status == "blocked" and cmd.v == 0.0 and cmd.w == 0.0
    # far off the path -> stale
    g = PathFollower()
    g.set_path(L_PATH)
    assert g.step([1.5, 1.2, 0.0]).status == "stale"


def test_bad_inputs_raise() -> None:
    with pytest.raises(ConfigError):
        FollowerConfig(v_min=0.1)
    with pytest.raises(ConfigError):
        FollowerConfig(lookahead=0.0)
    f = PathFollower()
    with pytest.raises(ValueError, match="set_path"):
        f.step([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="finite"):
        f.set_path(np.array([[0.0, np.nan]]))
    f.set_path(L_PATH)
    with pytest.raises(ValueError, match="pose"):
        f.step([0.0, np.inf, 0.0])
