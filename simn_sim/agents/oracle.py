"""``oracle``: knows the true map and the true pose, follows the exact shortest path.

The upper bound for every comparison. It plans once with the env's exact visibility-graph
free space (:class:`~simn_sim.geometry.freespace.FreeSpace2D`, obstacles inflated by the robot
radius plus ``margin``) and follows the path with the pure-pursuit follower, replanning from the
true pose when it drifts off the path.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from simn_sim.agents.base import register_agent
from simn_sim.config import Config, require
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.geometry.se3 import yaw_of
from simn_sim.planning.follower import FollowerConfig, PathFollower


@dataclasses.dataclass(frozen=True)
class OracleConfig(Config):
    margin: float = 0.12  # extra clearance (m) beyond the robot radius when planning
    lookahead: float = 0.4
    v_max: float = 0.8
    goal_tolerance: float = 0.15

    def validate(self) -> None:
        require(0 <= self.margin <= 0.5, "OracleConfig", "margin", "must be in [0, 0.5]")
        require(self.lookahead > 0, "OracleConfig", "lookahead", "must be > 0")
        require(self.v_max > 0, "OracleConfig", "v_max", "must be > 0")
        require(self.goal_tolerance > 0, "OracleConfig", "goal_tolerance", "must be > 0")


class OracleAgent:
    name = "oracle"

    def __init__(self, env: Any, config: dict[str, Any] | OracleConfig | None = None):
        self.cfg = config if isinstance(config, OracleConfig) else OracleConfig.from_dict(config)
        self.env = env
        lo, hi = env.action_space.low, env.action_space.high
        self.follower_cfg = FollowerConfig(
            lookahead=self.cfg.lookahead,
            v_min=float(lo[0]),
            v_max=min(float(hi[0]), self.cfg.v_max),
            w_min=float(lo[1]),
            w_max=float(hi[1]),
            goal_tolerance=self.cfg.goal_tolerance,
        )
        self._fs: dict[float, FreeSpace2D] = {}
        self._fs_key = None
        self._plan_ms: float | None = None
        self._state = "idle"

    def config_dict(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def _free_space(self, margin: float) -> FreeSpace2D:
        """The true free space with obstacles inflated by the robot radius + ``margin``."""
        if self._fs_key != id(self.env.layout):
            self._fs, self._fs_key = {}, id(self.env.layout)
        if margin not in self._fs:
            from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND

            self._fs[margin] = FreeSpace2D(
                self.env.layout.footprints(ROBOT_Z_BAND),
                robot_radius=ROBOT_RADIUS + margin,
                bounds=self.env.layout.bounds,
            )
        return self._fs[margin]

    def _plan(self, xy: np.ndarray) -> None:
        """Exact shortest path with the configured margin; where the start or the goal lies
        inside that margin, with successively smaller margins (down to the bare radius)."""
        t = time.perf_counter()
        path = None
        for margin in (self.cfg.margin, self.cfg.margin / 2, 0.0):
            fs = self._free_space(margin) if margin > 0 else self.env.free_space
            if fs.is_free(np.array([xy, self.goal])).all():
                path = fs.shortest_path(xy, self.goal)
                if path is not None:
                    break
        if path is None:
            path = np.array([xy, self.goal])
        self.follower.set_path(path)
        self.path = path
        self._plan_ms = (time.perf_counter() - t) * 1e3

    def reset(self, obs: dict, info: dict) -> None:
        self.goal = np.asarray(info["episode_spec"]["goal"], float)
        self.follower = PathFollower(self.follower_cfg)
        self._plan(info["T_world_base"][:2, 3])
        self._state = "following"

    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:
        if info is None:
            raise ValueError("the oracle agent needs info (true pose) in act(obs, info)")
        T = info["T_world_base"]
        pose = np.array([T[0, 3], T[1, 3], yaw_of(T)])
        self._plan_ms = None
        cmd = self.follower.step(pose)
        if cmd.status in ("stale", "blocked"):
            self._plan(pose[:2])
            cmd = self.follower.step(pose)
        self._state = cmd.status
        return np.array([cmd.v, cmd.w], np.float32)

    def state(self) -> str:
        return self._state

    def counters(self) -> dict[str, int]:
        return {}  # true map and pose: no fallbacks

    def debug(self) -> dict[str, Any]:
        return {"path": getattr(self, "path", None), "plan_ms": self._plan_ms}


register_agent("oracle", OracleAgent)
