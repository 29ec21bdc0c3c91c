"""Recovery behaviours of the navigation agent: bumps, escape, creeping back to free space.

- :class:`BumpDetector`: the wheel odometry shows no motion although the base was commanded
  forwards (an obstacle the camera cannot see, e.g. within its ~0.6 m blind zone below the view);
- :func:`escape`: inside the inflated obstacles, drive towards the freest nearby direction;
- :func:`drive_to`: turn towards a target and creep to it (backwards when it is behind);
- :func:`nearest_free`: the nearest point on rings around ``p`` that a checker calls free.
"""

from __future__ import annotations

import math

import numpy as np

from simn_sim.planning import CollisionChecker, FollowerConfig


class BumpDetector:
    """Counts steps where commanded forward motion did not happen; two in a row is a bump."""

    def __init__(self, control_dt: float) -> None:
        self.control_dt = float(control_dt)
        self.stuck_steps = 0
        self.bumps = 0

    def update(self, v_cmd: float, T_step: np.ndarray) -> bool:
        """``v_cmd``: the last forward command (m/s); ``T_step``: (4, 4) odometry increment
        over the last step. True when a bump is detected (then the count restarts)."""
        moved = float(np.hypot(T_step[0, 3], T_step[1, 3]))
        if v_cmd > 0.1 and moved < 0.2 * v_cmd * self.control_dt:
            self.stuck_steps += 1
        else:
            self.stuck_steps = 0
        if self.stuck_steps >= 2:
            self.bumps += 1
            self.stuck_steps = 0
            return True
        return False


def nearest_free(
    checker: CollisionChecker, p: np.ndarray, radius: float = 1.0
) -> np.ndarray | None:
    """The first free point on rings of 24 points every 0.1 m around ``p`` up to ``radius``."""
    ang = np.linspace(0, 2 * math.pi, 24, endpoint=False)
    for r in np.arange(0.1, radius + 1e-9, 0.1):
        cand = p + r * np.c_[np.cos(ang), np.sin(ang)]
        free = checker.is_free(cand)
        if free.any():
            return cand[np.flatnonzero(free)[0]]
    return None


def drive_to(pose: np.ndarray, target: np.ndarray, f: FollowerConfig) -> np.ndarray:
    """[v, w] turning towards ``target`` and creeping to it (forwards, or backwards when it is
    behind and the follower may reverse). pose: (x, y, yaw)."""
    d = target - pose[:2]
    err = (math.atan2(d[1], d[0]) - pose[2] + math.pi) % (2 * math.pi) - math.pi
    if abs(err) > math.radians(120) and f.v_min < 0:  # behind: reverse
        err_b = (err + 2 * math.pi) % (2 * math.pi) - math.pi - math.copysign(math.pi, err)
        return np.array([max(f.v_min, -0.15), float(np.clip(1.5 * err_b, -1.0, 1.0))], np.float32)
    if abs(err) > math.radians(45):
        return np.array([0.0, math.copysign(0.8, err)], np.float32)
    return np.array([0.15, float(np.clip(1.5 * err, -1.0, 1.0))], np.float32)


def escape(pose: np.ndarray, checker: CollisionChecker, w_max: float) -> np.ndarray:
    """[v, w] towards the freest of 16 directions 0.3 m around the robot. pose: (x, y, yaw)."""
    xy, yaw = pose[:2], pose[2]
    ang = yaw + np.linspace(-math.pi, math.pi, 16, endpoint=False)
    cand = xy + 0.3 * np.c_[np.cos(ang), np.sin(ang)]
    best = ang[int(np.argmax(checker.clearance(cand)))]
    err = (best - yaw + math.pi) % (2 * math.pi) - math.pi
    if abs(err) > math.radians(60):
        return np.array([0.0, math.copysign(w_max * 0.6, err)], np.float32)
    return np.array([0.15, 1.5 * err], np.float32)
