"""People walking between free-space waypoints in the office env (kinematic mocap capsules)."""

from __future__ import annotations

import numpy as np

from simn_sim.env.scene import PERSON_RADIUS, ROBOT_RADIUS
from simn_sim.geometry.freespace import FreeSpace2D

# a yielding person stops while the robot's hull is within this gap (m) of its own, ahead of it
YIELD_GAP = 0.4
YIELD_HALF_ANGLE = np.radians(70.0)  # "ahead": within this angle of the walking direction


class _People:
    """People walking between waypoints at walking speed (kinematic mocap capsules).

    With ``yield_to_robot`` a person stops while the robot is in its way (the robot's hull
    within ``YIELD_GAP`` of the person's, within 70 deg of its walking direction), as people do
    for a slow robot; after ``patience`` seconds of waiting it walks to a new target instead.
    Without it people walk through the robot's position."""

    def __init__(
        self,
        fs: FreeSpace2D,
        n: int,
        rng: np.random.Generator,
        speed=(0.8, 1.3),
        yield_to_robot: bool = True,
        patience: float = 3.0,
    ):
        self.fs, self.rng = fs, rng
        self.yield_to_robot, self.patience = yield_to_robot, patience
        self.waited = np.zeros(n)  # seconds each person has been waiting for the robot
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

    def _robot_in_way(self, i: int, robot_xy: np.ndarray) -> bool:
        if len(self.paths[i]) == 0:
            return False
        to_robot = robot_xy - self.pos[i]
        gap = float(np.hypot(*to_robot)) - ROBOT_RADIUS - PERSON_RADIUS
        if gap > YIELD_GAP:
            return False
        heading = self.paths[i][0] - self.pos[i]
        n = float(np.hypot(*heading)) * float(np.hypot(*to_robot))
        return n < 1e-9 or float(heading @ to_robot) / n >= np.cos(YIELD_HALF_ANGLE)

    def advance(self, dt: float, robot_xy: np.ndarray | None = None) -> None:
        """Walk ``dt`` seconds; ``robot_xy``: the robot's position, for yielding."""
        for i in range(len(self.pos)):
            if self.yield_to_robot and robot_xy is not None and self._robot_in_way(i, robot_xy):
                self.waited[i] += dt
                if self.waited[i] < self.patience:
                    continue  # wait for the robot to pass
                self._new_target(i)  # give up: walk somewhere else
                if self._robot_in_way(i, robot_xy):
                    continue
            self.waited[i] = 0.0
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
