"""Stateful per-frame tracking: constant-velocity prior + registration, with fallback.

:class:`FrameTracker` keeps the last two camera poses ``T_frame_cam`` (in the coordinates of the
current local frame) and their stamps, predicts the next pose at constant velocity, registers the
new points against the current map and records the result -- or the prediction when the
registration fails (``success=False``), as DESIGN §3 asks. When a new local frame opens, call
:meth:`FrameTracker.rebase` with ``T_new_old`` so the history moves to the new coordinates.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from simn_sim.tracking.lie import check_pose, constant_velocity_prior
from simn_sim.tracking.registration import (
    RegistrationConfig,
    RegistrationResult,
    SdfAndGrad,
    register,
)


class FrameTracker:
    """Tracks ``T_frame_cam`` frame by frame; see the module docstring."""

    def __init__(
        self,
        cfg: RegistrationConfig | None = None,
        points_as: Literal["numpy", "torch"] = "numpy",
    ) -> None:
        self.cfg = cfg or RegistrationConfig()
        self.points_as = points_as
        self._poses: list[np.ndarray] = []
        self._stamps: list[float] = []
        self.n_failures = 0  # consecutive failed registrations
        self.last: RegistrationResult | None = None

    def reset(self, T_frame_cam: np.ndarray, timestamp: float) -> None:
        """Start tracking at a known pose (e.g. the identity at the first frame)."""
        self._poses = [check_pose(T_frame_cam, "T_frame_cam")]
        self._stamps = [float(timestamp)]
        self.n_failures = 0
        self.last = None

    @property
    def pose(self) -> np.ndarray:
        """The latest ``T_frame_cam``."""
        if not self._poses:
            raise RuntimeError("FrameTracker: call reset() first")
        return self._poses[-1].copy()

    def predict(self, timestamp: float) -> np.ndarray:
        """Constant-velocity prediction of ``T_frame_cam`` at ``timestamp``."""
        if not self._poses:
            raise RuntimeError("FrameTracker: call reset() first")
        if len(self._poses) == 1:
            return self._poses[-1].copy()
        t0, t1 = self._stamps[-2], self._stamps[-1]
        ratio = (float(timestamp) - t1) / (t1 - t0) if t1 > t0 else 1.0
        return constant_velocity_prior(self._poses[-2], self._poses[-1], max(ratio, 0.0))

    def track(
        self, points_cam: Any, sdf_and_grad: SdfAndGrad, timestamp: float
    ) -> RegistrationResult:
        """Register the frame's (N, 3) camera points against the current map; record the pose."""
        if not self._poses:
            raise RuntimeError("FrameTracker: call reset() first")
        if float(timestamp) <= self._stamps[-1]:
            raise ValueError(f"timestamp {timestamp} is not after {self._stamps[-1]}")
        prior = self.predict(timestamp)
        res = register(points_cam, sdf_and_grad, prior, self.cfg, points_as=self.points_as)
        self.n_failures = 0 if res.success else self.n_failures + 1
        self._poses = [self._poses[-1], res.pose]
        self._stamps = [self._stamps[-1], float(timestamp)]
        self.last = res
        return res

    def rebase(self, T_new_old: np.ndarray) -> None:
        """Re-express the history in a new frame: ``T_new_cam = T_new_old @ T_old_cam``."""
        T = check_pose(T_new_old, "T_new_old")
        self._poses = [T @ P for P in self._poses]
