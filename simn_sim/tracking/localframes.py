"""Spatial-implicit local frames: when to open one, and what a frame holds.

A local frame owns a per-frame map in its own anchor coordinates (anything implementing
:class:`FrameMap`: the learned :class:`~simn_sim.mapping.mapper.ImplicitMap`, or an analytic SDF
in tests) and the observations from ``t_start`` to ``t_end``. Because the map lives in anchor
coordinates, moving the anchor (pose-graph optimisation) moves the whole map rigidly.

:class:`FrameTrigger` decides when a frame closes: when the travel distance accumulated since the
frame opened, or the viewpoint change (rotation angle between the current camera orientation and
the one at the frame's start), passes its threshold -- whichever comes first (paper: "variances
in translation and viewpoint").
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.se3 import inv_T, rotation_angle, transform_points
from simn_sim.tracking.lie import check_pose


@runtime_checkable
class FrameMap(Protocol):
    """What the tracker needs from a per-frame map (coordinates: the frame's anchor).

    ``feature_points()`` -> ``(P (N, 3) float32, F (N, d) float32, labels (N,) int)`` or an
    object with ``positions``, ``features``, ``labels`` attributes.
    ``sdf_and_grad(points (N, 3))`` -> ``(sdf (N,), grad (N, 3)[, valid (N,)])``.
    """

    def feature_points(self) -> Any: ...

    def sdf_and_grad(self, points: Any) -> tuple: ...


def unpack_feature_points(fp: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalise a ``feature_points()`` result to numpy ``(P (N,3) f32, F (N,d) f32, L (N,) i64)``."""
    if isinstance(fp, tuple | list):
        P, F, L = fp[0], fp[1], fp[2]
    else:
        P, F, L = fp.positions, fp.features, fp.labels

    def np_(x):
        return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)

    P = np_(P).astype(np.float32).reshape(-1, 3)
    F = np_(F).astype(np.float32)
    if F.ndim != 2:
        F = F.reshape(-1, 1) if F.size else np.zeros((len(P), 0), np.float32)
    L = np_(L).astype(np.int64).reshape(-1)
    if len(F) != len(P) or len(L) != len(P):
        raise ValueError(f"feature_points: {len(P)} positions, {len(F)} features, {len(L)} labels")
    return P, F, L


@dataclasses.dataclass(frozen=True)
class FrameTriggerConfig(Config):
    """Thresholds for closing a local frame (paper fr1/desk: ~120 observations per frame)."""

    max_travel_m: float = 1.0  # accumulated camera travel since the frame opened
    max_rotation_deg: float = 30.0  # viewpoint change since the frame opened
    max_observations: int = 0  # optional cap on observations per frame (0: none)

    def validate(self) -> None:
        n = type(self).__name__
        require(self.max_travel_m > 0, n, "max_travel_m", "must be > 0")
        require(0 < self.max_rotation_deg <= 180, n, "max_rotation_deg", "must be in (0, 180]")
        require(self.max_observations >= 0, n, "max_observations", "must be >= 0")


class FrameTrigger:
    """Decides when to open a new local frame from the stream of camera poses ``T_world_cam``.

    ``update(T)`` returns True when the frame that was open before this pose should be closed;
    the trigger then restarts at ``T`` (the new frame opens there) and ``reason`` says which
    threshold fired. The first call only starts the first frame and returns False.
    """

    def __init__(self, cfg: FrameTriggerConfig | None = None) -> None:
        self.cfg = cfg or FrameTriggerConfig()
        self._start: np.ndarray | None = None
        self._last: np.ndarray | None = None
        self.travel_m = 0.0
        self.rotation_deg = 0.0
        self.n_observations = 0
        self.reason = ""

    def reset(self, T_world_cam: np.ndarray) -> None:
        """Start a frame at ``T_world_cam``."""
        T = check_pose(T_world_cam, "T_world_cam")
        self._start, self._last = T, T
        self.travel_m, self.rotation_deg, self.n_observations = 0.0, 0.0, 1

    def update(self, T_world_cam: np.ndarray) -> bool:
        T = check_pose(T_world_cam, "T_world_cam")
        if self._start is None:
            self.reset(T)
            return False
        travel = self.travel_m + float(np.linalg.norm(T[:3, 3] - self._last[:3, 3]))
        rot = float(np.degrees(rotation_angle(self._start[:3, :3].T @ T[:3, :3])))
        n = self.n_observations + 1
        cfg = self.cfg
        reason = ""
        if travel > cfg.max_travel_m:
            reason = "travel"
        elif rot > cfg.max_rotation_deg:
            reason = "rotation"
        elif cfg.max_observations and n > cfg.max_observations:
            reason = "observations"
        if reason:
            self.reason = reason
            self.reset(T)
            return True
        self.travel_m, self.rotation_deg, self.n_observations, self._last = travel, rot, n, T
        return False


@dataclasses.dataclass
class LocalFrame:
    """A local frame: its map (anchor coordinates), anchor pose and observation span."""

    frame_id: int
    T_world_anchor: np.ndarray
    map: FrameMap
    t_start: float = 0.0
    t_end: float = 0.0
    n_observations: int = 0

    def points_world(self) -> np.ndarray:
        """(N, 3) float32 feature-point positions in world coordinates (via the anchor)."""
        P, _, _ = unpack_feature_points(self.map.feature_points())
        return transform_points(self.T_world_anchor, P.astype(np.float64)).astype(np.float32)

    def T_anchor_cam(self, T_world_cam: np.ndarray) -> np.ndarray:
        return inv_T(self.T_world_anchor) @ T_world_cam
