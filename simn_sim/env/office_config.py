"""Configuration of the ``SimnOffice-v0`` env (:class:`EnvConfig`, also from YAML) and its
camera description (:class:`CameraInfo`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from simn_sim.config import Config, ConfigError, require
from simn_sim.env.noise import DepthNoiseConfig
from simn_sim.geometry.camera import Intrinsics


@dataclasses.dataclass(frozen=True)
class EnvConfig(Config):
    """Configuration of :class:`SimnOfficeEnv` (every field validated)."""

    layout_seed: int | None = None  # None: the fixed reference office in envs/
    width: int = 640
    height: int = 480
    fovy_deg: float = 42.5
    depth_min: float = 0.28
    depth_max: float = 10.0
    depth_noise: DepthNoiseConfig = DepthNoiseConfig()
    odom_noise_trans: float = 0.0  # std of translation error per metre driven (m/m)
    odom_noise_rot: float = 0.0  # std of heading error per radian turned + per metre (rad)
    control_hz: float = 10.0
    v_min: float = -0.3
    v_max: float = 1.0
    w_max: float = 1.5
    success_distance: float = 0.36
    max_episode_steps: int = 500
    max_collisions: int | None = None  # end the episode after this many collisions
    min_geodesic: float = 3.0  # sampled episodes: goal geodesic distance range (m)
    max_geodesic: float = 14.0
    start_clearance: float = 0.15  # sampled starts/goals keep this margin beyond the robot radius
    n_people: int = 0  # moving people (the dynamic office)
    segmentation: bool = False  # also render the segmentation (info['segmentation'])

    def validate(self) -> None:
        n = "EnvConfig"
        require(
            self.layout_seed is None or self.layout_seed >= 0,
            n,
            "layout_seed",
            "must be >= 0 or null",
        )
        require(
            16 <= self.width <= 1920 and 16 <= self.height <= 1080,
            n,
            "width/height",
            "image size must be within 16x16..1920x1080",
        )
        require(0 < self.fovy_deg < 180, n, "fovy_deg", "must be in (0, 180)")
        require(
            0 < self.depth_min < self.depth_max, n, "depth_min", "need 0 < depth_min < depth_max"
        )
        require(
            self.odom_noise_trans >= 0 and self.odom_noise_rot >= 0,
            n,
            "odom_noise_*",
            "must be >= 0",
        )
        require(0 < self.control_hz <= 100, n, "control_hz", "must be in (0, 100]")
        require(self.v_min <= 0 < self.v_max, n, "v_min/v_max", "need v_min <= 0 < v_max")
        require(
            self.v_max <= 2.0 and self.v_min >= -2.0,
            n,
            "v_max",
            "|v| bound must be <= 2 m/s (actuator limit)",
        )
        require(0 < self.w_max <= 4.0, n, "w_max", "must be in (0, 4] rad/s")
        require(self.success_distance > 0, n, "success_distance", "must be > 0")
        require(self.max_episode_steps >= 1, n, "max_episode_steps", "must be >= 1")
        require(
            self.max_collisions is None or self.max_collisions >= 1,
            n,
            "max_collisions",
            "must be >= 1 or null",
        )
        require(
            0 < self.min_geodesic < self.max_geodesic,
            n,
            "min_geodesic",
            "need 0 < min_geodesic < max_geodesic",
        )
        require(self.start_clearance >= 0, n, "start_clearance", "must be >= 0")
        require(0 <= self.n_people <= 20, n, "n_people", "must be in [0, 20]")


@dataclasses.dataclass(frozen=True)
class CameraInfo:
    """Everything about the camera, in one place."""

    intrinsics: Intrinsics
    T_base_cam: np.ndarray  # 4x4, OpenCV optical frame -> base frame
    depth_min: float
    depth_max: float


def env_config_from_file(path: str | Path) -> EnvConfig:
    import yaml

    p = Path(path)
    try:
        d = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{p}: invalid YAML: {e}") from e
    return EnvConfig.from_dict(d)
