"""Recovery behaviours of the navigation agent: bumps, escape, creeping back to free space.

- :class:`BumpDetector`: the wheel odometry shows no motion although the base was commanded
  forwards (an obstacle the camera cannot see, e.g. within its ~0.6 m blind zone below the view);
- :func:`escape`: inside the inflated obstacles, drive towards the freest nearby direction;
- :func:`drive_to`: turn towards a target and creep to it (backwards when it is behind);
- :func:`nearest_free`: the nearest point on rings around ``p`` that a checker calls free;
- :func:`back_off`: the action while the robot is (nearly) touching the map or inside its safety
  margin;
- :class:`ProgressWatch`: lost progress, measured on the cost-to-go of the agent's own map;
- :class:`NoRouteWatch`: steps in a row without a route, and when to clear the map.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable

import numpy as np

from simn_sim.planning import CollisionChecker, FollowerConfig


class BumpDetector:
    """Contact the camera did not see, from the wheel odometry: a unicycle moves along its
    heading by about the commanded distance, so a step commanded forwards (> 0.1 m/s) that made
    less than ``min_progress`` of it, or that slid sideways by more than ``max_slip`` m, is a
    sign of contact (the hull pushed back, or sliding along a box). Two such steps among the
    last ``window`` forward-commanded steps are a bump (the count then restarts).

    ``min_progress`` 0.3: the env's realistic actuation noise (a per-episode gain error and an
    error correlated over 0.5 s) made free steps as slow as 0.451 of the command, and 0.5 fired
    14 false bumps in 20441 free forward steps, 0.3 none. 0.3 still caught all 15 wall drives
    (median 2 steps after the first contact, as 0.5), but glancing ones later (at most 12
    steps against 4); a turn past a low box making 0.43-0.52 of its progress goes unnoticed
    (``scripts/bench_bumps.py``, docs/navigation.md). ``max_slip`` 0.012 m per 0.1 s step is 3x
    the sideways motion measured while turning at full speed in free space.

    ``rel_progress`` > 0 adds a relative test: a step whose progress ratio (odometry distance
    over commanded distance) falls below ``rel_progress`` times the median ratio of the last
    ``rel_window`` forward-commanded steps is a contact sign too. The actuation noise's error is
    correlated over 0.5 s, so a slow stretch of noise is slow in its median as well, while a
    contact after free driving drops the ratio at once (nav2-ref-009's turn past a low box:
    1.06 -> 0.44).

    ``yaw_tol`` > 0 (rad/s) adds a turning test: a forward-commanded step whose odometry yaw
    rate differs from the commanded ``w`` by more than ``yaw_tol`` + ``yaw_gain_band`` x |w| is
    a contact sign. The actuation noise scales the commanded yaw rate by a gain within
    1 +- 0.5 (its bias and correlated error, each clipped at 3 sigma), so ``yaw_gain_band``
    0.5 covers it; what is left is a torque on the hull. Sliding past a person or a wall beside
    the base (outside the camera's view) turns it towards the contact by friction while the
    forward progress stays nearly whole: dyn-L5-002 drove 17 steps against a standing person
    at 0.77 of its commanded progress, commanding -0.35 to -0.8 rad/s while the base turned
    at +0.7 to +1.6 rad/s. A step caught by this test alone puts the bump at 60 deg on the side
    it turned towards."""

    def __init__(
        self,
        control_dt: float,
        min_progress: float = 0.3,
        max_slip: float = 0.012,
        window: int = 4,
        rel_progress: float = 0.0,
        rel_window: int = 5,
        yaw_tol: float = 0.0,
        yaw_gain_band: float = 0.5,
    ) -> None:
        self.control_dt = float(control_dt)
        self.min_progress = float(min_progress)
        self.max_slip = float(max_slip)
        self.window = int(window)
        self.rel_progress = float(rel_progress)
        self.yaw_tol = float(yaw_tol)
        self.yaw_gain_band = float(yaw_gain_band)
        self._ratios: collections.deque[float] = collections.deque(maxlen=int(rel_window))
        self._recent: list[bool] = []  # suspicious or not, per forward-commanded step
        self._angle = 0.0  # the bearing of the last contact sign's obstacle (rad)
        self.bumps = 0
        self.contact_angle = 0.0  # base-frame bearing (rad) of the last bump's obstacle

    def update(self, v_cmd: float, T_step: np.ndarray, w_cmd: float = 0.0) -> bool:
        """``v_cmd``, ``w_cmd``: the last command (m/s, rad/s); ``T_step``: (4, 4) odometry
        increment over the last step (base frame). True when a bump is detected;
        ``contact_angle`` is then the bearing of the motion that did not happen (or, for a
        step caught only by the turning test, 60 deg on the side the base turned towards)."""
        if v_cmd <= 0.1:
            return False
        want = v_cmd * self.control_dt
        dx, dy = float(T_step[0, 3]), float(T_step[1, 3])
        ratio = dx / want  # want > 0.01 m here
        bad = ratio < self.min_progress or abs(dy) > self.max_slip
        if self.rel_progress > 0 and len(self._ratios) == self._ratios.maxlen:
            bad = bad or ratio < self.rel_progress * float(np.median(self._ratios))
        self._ratios.append(ratio)
        turned = 0.0  # yaw rate beyond the commanded one's noise band (rad/s), signed
        if self.yaw_tol > 0:
            err = math.atan2(T_step[1, 0], T_step[0, 0]) / self.control_dt - float(w_cmd)
            if abs(err) > self.yaw_tol + self.yaw_gain_band * abs(w_cmd):
                turned = err
        self._recent = (self._recent + [bad or turned != 0.0])[-self.window :]
        if bad:
            self._angle = float(math.atan2(-dy, max(want - dx, 0.0)))
        elif turned:
            self._angle = math.copysign(math.radians(60.0), turned)
        if sum(self._recent) >= 2:
            self.bumps += 1
            self._recent = []
            self.contact_angle = self._angle
            return True
        return False


def back_off(
    pose: np.ndarray,
    planning: CollisionChecker,
    touch: float,
    active: Callable[[], CollisionChecker],
    f: FollowerConfig,
) -> tuple[str, np.ndarray] | None:
    """The recovery when the robot is in the map's way, as (state, [v, w]); None when it is
    not. ``"escaping"``: nearer than ``touch`` (m) to a mapped obstacle of the ``planning``
    model; ``"recovering"``: inside the safety margin of the model ``active()`` returns (asked
    only when not touching; the map grew around the robot): back out to the nearest point free
    under the planning margin. pose: (x, y, yaw)."""
    xy = pose[:2]
    if float(planning.clearance(xy[None])[0]) < touch:
        return "escaping", escape(pose, planning, f.w_max)
    if active().is_free(xy[None])[0]:
        return None
    target = nearest_free(planning, xy, radius=0.6)
    if target is None:
        return "recovering", escape(pose, planning, f.w_max)
    return "recovering", drive_to(pose, target, f)


class ProgressWatch:
    """Lost progress: the cost-to-go on the agent's own map has not fallen below its best by
    ``eps`` (m) for more than ``stall_steps`` control steps."""

    def __init__(self, stall_steps: int, eps: float) -> None:
        self.stall_steps = int(stall_steps)
        self.eps = float(eps)
        self.restart(0)

    def restart(self, step: int) -> None:
        """Forget the best so far: progress is measured afresh from ``step``."""
        self.best, self.best_step = math.inf, int(step)

    def update(self, cost_to_go: float, step: int) -> None:
        if cost_to_go < self.best - self.eps:
            self.best, self.best_step = float(cost_to_go), int(step)

    def stalled(self, step: int) -> bool:
        return step - self.best_step > self.stall_steps


class NoRouteWatch:
    """Control steps in a row without a route to the goal. After ``clear_after`` of them
    (0: never) the map is to be cleared, at most once per ``cooldown`` steps."""

    def __init__(self, clear_after: int, cooldown: int) -> None:
        self.clear_after = int(clear_after)
        self.cooldown = int(cooldown)
        self.count = 0
        self.last_clear = -math.inf

    def route(self) -> None:
        """A route was followed this step: the count restarts."""
        self.count = 0

    def no_route(self, step: int) -> bool:
        """Count a step without a route; True when the map is to be cleared now."""
        self.count += 1
        if (
            self.clear_after > 0
            and self.count >= self.clear_after
            and step - self.last_clear >= self.cooldown
        ):
            self.last_clear, self.count = step, 0
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
