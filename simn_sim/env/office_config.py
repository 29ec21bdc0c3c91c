"""Configuration of the ``SimnOffice-v0`` env (:class:`EnvConfig`, also from YAML) and its
camera description (:class:`CameraInfo`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

import numpy as np

from simn_sim.config import Config, ConfigError, require
from simn_sim.env.noise import ActuationNoiseConfig, DepthNoiseConfig
from simn_sim.geometry.camera import Intrinsics

NOISE_KEYS = ("depth_noise", "odom_noise_trans", "odom_noise_rot", "actuation_noise")

# What each ``sensing`` condition sets the noise keys to when they are not given (docs/env.md).
SENSING_PRESETS: dict[str, dict[str, Any]] = {
    "realistic": {
        "depth_noise": {"model": "d435i"},
        "odom_noise_trans": 0.02,
        "odom_noise_rot": 0.02,
        "actuation_noise": {"model": "gaussian"},
    },
    "ideal": {
        "depth_noise": {"model": "none"},
        "odom_noise_trans": 0.0,
        "odom_noise_rot": 0.0,
        "actuation_noise": {"model": "none"},
    },
}


@dataclasses.dataclass(frozen=True)
class EnvConfig(Config):
    """Configuration of :class:`SimnOfficeEnv` (every field validated).

    ``sensing`` picks the noise condition: ``"realistic"`` (the default) or ``"ideal"`` (exact
    depth, exact odometry, the command executed exactly). The noise keys (:data:`NOISE_KEYS`)
    left unset (``None``) take the preset's value; a key given explicitly wins over the preset
    (a partial mapping for ``depth_noise`` / ``actuation_noise`` is merged over the preset's).
    ``to_dict`` holds the resolved values. Realistic sensing:

    - ``depth_noise``: ``{model: d435i}`` (:class:`~simn_sim.env.noise.DepthNoiseConfig`; the
      D435/D435i datasheet's 50 mm baseline and Intel's whitepaper figures, 0.08 px subpixel
      RMS, 1/32 px disparity steps; dropout rates chosen, not measured);
    - ``odom_noise_trans`` 0.02, ``odom_noise_rot`` 0.02: wheel-odometry drift, chosen, not
      measured (zero-mean per-step errors: no systematic wheel-diameter or wheelbase error of
      the kind UMBmark, Borenstein & Feng 1996, measures); the drift they give is measured in
      ``tests/test_sensing.py`` and quoted in docs/env.md. Odometry integrates the motion the
      base executed (encoders see the actuation error), with this drift on top;
    - ``actuation_noise``: ``{model: gaussian}``
      (:class:`~simn_sim.env.noise.ActuationNoiseConfig`: the LoCoBot/PyRobot model, Murali et
      al. 2019, at Habitat Challenge 2020's noise multiplier 0.5).
    """

    layout_seed: int | None = None  # None: the fixed reference office in envs/
    width: int = 640
    height: int = 480
    fovy_deg: float = 42.5
    depth_min: float = 0.28
    depth_max: float = 10.0
    sensing: Literal["realistic", "ideal"] = "realistic"
    # None: from the ``sensing`` preset (SENSING_PRESETS); resolved in __post_init__
    depth_noise: DepthNoiseConfig | None = None
    odom_noise_trans: float | None = None  # relative std of each step's translation (m/m)
    odom_noise_rot: float | None = None  # heading std per radian turned + per metre (rad)
    actuation_noise: ActuationNoiseConfig | None = None
    control_hz: float = 10.0
    v_min: float = -0.3
    v_max: float = 1.0
    w_max: float = 1.5
    success_distance: float = 0.36
    # 100 s at 10 Hz: office_nav_v2 goals lie up to 20 m away, which takes ~250 steps at the
    # top speed; 1000 steps give about 4x the shortest drive (Habitat PointNav: 500 steps of
    # 0.25 m for at most 30 m)
    max_episode_steps: int = 1000
    max_collisions: int | None = None  # end the episode after this many collisions
    min_geodesic: float = 3.0  # sampled episodes: goal geodesic distance range (m)
    max_geodesic: float = 14.0
    start_clearance: float = 0.15  # sampled starts/goals keep this margin beyond the robot radius
    n_people: int = 0  # moving people (the dynamic office)
    # people stop while the robot is in their way (and pick another target after 3 s of
    # waiting); False: they walk through the robot's position (env/people.py)
    people_yield: bool = True
    segmentation: bool = False  # also render the segmentation (info['segmentation'])

    def __post_init__(self) -> None:
        if not isinstance(self.sensing, str) or self.sensing not in SENSING_PRESETS:
            raise ConfigError(
                f"EnvConfig.sensing: {self.sensing!r} is not one of {tuple(SENSING_PRESETS)}"
            )
        given = {k: getattr(self, k) for k in NOISE_KEYS if getattr(self, k) is not None}
        object.__setattr__(self, "_given", given)  # not a field: kept by ``replace``
        preset = SENSING_PRESETS[self.sensing]
        for k in NOISE_KEYS:
            v = given.get(k, preset[k])
            if isinstance(v, dict):
                v = {**preset[k], **v}
            object.__setattr__(self, k, v)
        super().__post_init__()

    def replace(self, **changes: Any) -> EnvConfig:
        """A copy with ``changes``; the noise keys not given explicitly stay unset, so a new
        ``sensing`` value re-resolves them."""
        d = {k: v for k, v in self.to_dict().items() if k not in NOISE_KEYS}
        for k, v in self._given.items():
            d[k] = v.to_dict() if isinstance(v, Config) else v
        return type(self).from_dict({**d, **changes})

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
