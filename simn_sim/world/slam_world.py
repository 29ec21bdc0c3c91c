"""The SIMN front-end as the agent's world model (``pose_source: slam``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import inv_T
from simn_sim.semantics import OBSTACLE
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.slam.pipeline import SimnSlam
from simn_sim.tracking.topomap import TopoMap
from simn_sim.world.base import WorldStep
from simn_sim.world.obstacles import ObstacleConfig, ObstacleMap


class SlamWorld:
    """:class:`~simn_sim.slam.pipeline.SimnSlam` tracks every frame against the current local
    frame's map, opens local frames, grows the topological map and closes loops; the obstacle
    view is rebuilt from the local frames' stores when the anchors move and every
    ``rebuild_every`` steps, and grows by each frame's obstacle points in between."""

    def __init__(
        self,
        slam_cfg: SlamConfig,
        obstacle_cfg: ObstacleConfig,
        intr: Intrinsics,
        T_base_cam: np.ndarray,
    ) -> None:
        self.slam = SimnSlam(slam_cfg, intr, T_base_cam=T_base_cam)
        self.T_base_cam = T_base_cam
        self.obstacles = ObstacleMap(obstacle_cfg)
        self._pose: np.ndarray | None = None

    def update(self, t: float, obs: dict[str, np.ndarray], T_odom: np.ndarray) -> WorldStep:
        # only the odometry's change between calls is used: the prior must not contain the
        # front-end's own corrections, or each correction would be applied again every frame
        tc = self.obstacles.transient
        dynamic = tc.appeared_at if tc is not None and tc.cfg.mask_tracking else None
        fr = self.slam.process(t, obs["rgb"], obs["depth"], T_odom @ self.T_base_cam, dynamic)
        T_wc = fr.T_world_cam
        self._pose = T_wc @ inv_T(self.T_base_cam)
        self.obstacles.integrate(
            fr.obstacle_points_world,
            fr.pixels[fr.labels == OBSTACLE],
            T_wc,
            self._pose[:2, 3],
            obs["depth"],
            self.slam.perception.intr,
            self.slam.frames,
        )
        return WorldStep(self._pose, fr.success, fr.revisit_accepted, fr.track_ms, fr.map_ms)

    @property
    def pose(self) -> np.ndarray:
        return self._pose

    def close(self) -> None:
        """Join and stop the front-end's training thread (``train_async``): an open one keeps
        the episode's learned maps alive (a batch worker grew ~0.45 GB per episode)."""
        self.slam.close()

    @property
    def frames(self) -> LocalFrames:
        return self.slam.frames

    @property
    def topology(self) -> TopoMap:
        return self.slam.topo

    @property
    def current_frame_id(self) -> int:
        return self.slam.current_frame_id

    def counters(self) -> dict[str, int]:
        s = self.slam.stats()
        out = {
            "track_failures": s["track_failures"],
            "revisits": s["revisits_accepted"],
            "revisit_checks_dropped": s["revisit_checks_dropped"],
            "local_frames": s["local_frames"],
            "map_frames_skipped": s["map_frames_skipped"],
            "carved_points": s["carved_points"],
            "dynamic_points": s["dynamic_points"],
        }
        if "heading" in s:  # the wall-heading correction (SlamConfig.heading), when on
            out["heading_corrections"] = s["heading"]["corrections"]
            out["heading_gated"] = s["heading"]["gated"]
        return out

    def revisit_events(self) -> dict[str, Any]:
        """Each local frame's opening time (s, by frame id), the accepted revisits as
        ``(query frame, accepted frame, T_i_j)`` (the query's anchor in the accepted frame)
        and the check's ``exclude_recent``: what :func:`simn_sim.eval.revisits.revisit_truth`
        judges."""
        frames = self.slam.frames
        t_open = [frames.states[f].frame.t_start for f in sorted(frames.states)]
        acc = [
            (int(e["frame"]), int(e["accepted"]), np.asarray(e["T_i_j"], float))
            for e in self.slam.loop_log
            if e.get("accepted") is not None
        ]
        return {
            "t_open": t_open,
            "accepted": acc,
            "exclude_recent": self.slam.cfg.loop.exclude_recent,
        }

    def debug(self) -> dict[str, Any]:
        d = self.slam.debug()
        d["tracking_map"] = self.slam.tracking_map
        return d
