"""The agent's world model: one owner of perception, pose, local frames and topology."""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.camera import Intrinsics
from simn_sim.slam.config import SlamConfig
from simn_sim.world.base import WorldModel, WorldStep
from simn_sim.world.obstacles import ObstacleConfig, ObstacleMap
from simn_sim.world.odometry_world import OdometryWorld
from simn_sim.world.slam_world import SlamWorld

WORLDS = {"slam": SlamWorld, "odometry": OdometryWorld}


def make_world(
    pose_source: str,
    slam_cfg: SlamConfig,
    obstacle_cfg: ObstacleConfig,
    intr: Intrinsics,
    T_base_cam: np.ndarray,
) -> WorldModel:
    """The world model for ``pose_source`` (``"slam"``: the method; ``"odometry"``: ablation)."""
    if pose_source not in WORLDS:
        raise ValueError(f"unknown pose_source {pose_source!r}; one of {sorted(WORLDS)}")
    return WORLDS[pose_source](slam_cfg, obstacle_cfg, intr, T_base_cam)


__all__ = [
    "ObstacleConfig",
    "ObstacleMap",
    "OdometryWorld",
    "SlamWorld",
    "WORLDS",
    "WorldModel",
    "WorldStep",
    "make_world",
]
