"""The odometry-pose ablation (``pose_source: odometry``): the method without its front-end.

The pose is the wheel odometry as it comes; perception, the floor / obstacle labels, the
point stores, carving and the obstacle view are the front-end's own (same configs), in one
local frame anchored at the start that never closes (no tracking, no topology growth, no
revisits). It measures what the SLAM front-end adds over odometry, with everything else equal.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.perception.frame import Perception
from simn_sim.semantics import OBSTACLE
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.slam.integrate import classify
from simn_sim.tracking.topomap import TopoMap
from simn_sim.world.base import WorldStep
from simn_sim.world.obstacles import ObstacleConfig, ObstacleMap


class OdometryWorld:
    """See the module docstring."""

    def __init__(
        self,
        slam_cfg: SlamConfig,
        obstacle_cfg: ObstacleConfig,
        intr: Intrinsics,
        T_base_cam: np.ndarray,
    ) -> None:
        self.cfg = slam_cfg
        self.perception = Perception(intr, slam_cfg.perception.replace(map_normal_smooth_px=-1))
        self.frames = LocalFrames(slam_cfg)
        self.T_base_cam = T_base_cam
        self.obstacles = ObstacleMap(obstacle_cfg)
        self._pose: np.ndarray | None = None

    def update(self, t: float, obs: dict[str, np.ndarray], T_odom: np.ndarray) -> WorldStep:
        t0 = time.perf_counter()
        T_wc = T_odom @ self.T_base_cam
        frames = self.frames
        if frames.current_id < 0:
            frames.open(T_wc, t)
        frame = self.perception(obs["rgb"], obs["depth"])
        frame = frame.with_labels(classify(frame, T_wc, self.T_base_cam, self.cfg.classifier))
        T_anchor_cam = inv_T(frames.topo.anchor(frames.current_id)) @ T_wc
        frames.store(frames.current, frame, T_anchor_cam)
        if self.cfg.stores.carve:
            frames.carve(frame, T_wc)
        obst = frame.labels == OBSTACLE
        Pw = transform_points(T_wc, frame.points[obst].astype(np.float64)).astype(np.float32)
        self._pose = T_odom.copy()
        self.obstacles.integrate(
            Pw,
            frame.pixels[obst],
            T_wc,
            T_odom[:2, 3],
            obs["depth"],
            self.perception.intr,
            frames,
        )
        return WorldStep(self._pose, True, False, None, (time.perf_counter() - t0) * 1e3)

    @property
    def pose(self) -> np.ndarray:
        return self._pose

    def close(self) -> None:
        """Nothing to release (no training thread)."""

    @property
    def topology(self) -> TopoMap:
        return self.frames.topo

    @property
    def current_frame_id(self) -> int:
        return self.frames.current_id

    def counters(self) -> dict[str, int]:
        return {"local_frames": len(self.frames), "carved_points": self.frames.n_carved}

    def revisit_events(self) -> None:
        """No revisit checks: the odometry pose is never corrected."""
        return None

    def debug(self) -> dict[str, Any]:
        return {
            "local_frames": self.frames.debug(),
            "T_world_base_est": self._pose,
            "tracking_map": None,  # the odometry pose is not tracked against a map
        }
