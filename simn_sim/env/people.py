"""People walking between free-space waypoints in the office env (kinematic mocap capsules)."""

from __future__ import annotations

import numpy as np

from simn_sim.env.scene import (
    ROBOT_RADIUS,
)
from simn_sim.geometry.freespace import FreeSpace2D


class _People:
    """People walking between waypoints at walking speed (kinematic mocap capsules)."""

    def __init__(self, fs: FreeSpace2D, n: int, rng: np.random.Generator, speed=(0.8, 1.3)):
        self.fs, self.rng = fs, rng
        self.pos = (
            fs.sample_free(rng, n, min_clearance=ROBOT_RADIUS + 0.1) if n else np.zeros((0, 2))
        )
        self.paths: list[np.ndarray] = [np.zeros((0, 2))] * n
        self.speed = rng.uniform(*speed, size=n)
        for i in range(n):
            self._new_target(i)

    def _new_target(self, i: int) -> None:
        for _ in range(20):
            tgt = self.fs.sample_free(self.rng, 1, min_clearance=ROBOT_RADIUS + 0.1)[0]
            path = self.fs.shortest_path(self.pos[i], tgt)
            if path is not None and len(path) >= 2:
                self.paths[i] = path[1:]
                return
        self.paths[i] = self.pos[i][None]

    def advance(self, dt: float) -> None:
        for i in range(len(self.pos)):
            step = self.speed[i] * dt
            while step > 1e-9:
                if len(self.paths[i]) == 0:
                    self._new_target(i)
                    break
                d = self.paths[i][0] - self.pos[i]
                dist = float(np.hypot(*d))
                if dist <= step:
                    self.pos[i] = self.paths[i][0]
                    self.paths[i] = self.paths[i][1:]
                    step -= dist
                else:
                    self.pos[i] = self.pos[i] + d / dist * step
                    step = 0.0
