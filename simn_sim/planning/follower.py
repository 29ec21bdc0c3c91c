"""Pure-pursuit path follower for a unicycle base: path (planning frame) -> ``[v, w]``.

Each :meth:`PathFollower.step` takes the robot pose ``(x, y, yaw)`` in the path's frame and
returns a command within the action bounds plus a status:

- ``"follow"``: pure pursuit towards the lookahead point, ``w = v * 2 sin(a) / d`` (``a`` the
  bearing of the lookahead point, ``d`` its distance); speed reduced near the goal, near
  obstacles (checker clearance) and with the bearing (``cos a``);
- ``"turn"``: the bearing exceeds ``turn_in_place_deg``: ``v = 0``, turn towards it;
- ``"reached"``: within ``goal_tolerance`` of the path's end; zero command;
- ``"blocked"``: the path ahead (``blocked_check_distance`` from the robot's projection) is not
  free under the checker (the map grew); zero command, the caller replans;
- ``"stale"``: the robot is more than ``stale_distance`` from the path; zero command, replan.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, NamedTuple

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.paths import segment_lengths
from simn_sim.planning.collision import CollisionChecker

Status = Literal["follow", "turn", "reached", "blocked", "stale"]


@dataclasses.dataclass(frozen=True)
class FollowerConfig(Config):
    """Pure pursuit + action bounds (metres, seconds, degrees)."""

    lookahead: float = 0.6
    v_min: float = -0.2
    v_max: float = 0.8
    w_min: float = -1.5
    w_max: float = 1.5
    turn_in_place_deg: float = 60.0
    """Turn in place (v = 0) while the lookahead bearing exceeds this."""
    turn_gain: float = 2.0
    """w = turn_gain * bearing while turning in place (clipped to the bounds)."""
    goal_tolerance: float = 0.1
    slow_down_distance: float = 1.0
    """Speed ramps down linearly within this distance of the goal ..."""
    min_approach_speed: float = 0.1
    """... but not below this (unless v_max is lower)."""
    slow_clearance: float = 0.4
    """Speed ramps down when the free margin (clearance - inflation) is below this ..."""
    min_clearance_scale: float = 0.3
    """... to at least this fraction of v_max."""
    blocked_check_distance: float = 1.5
    stale_distance: float = 0.5

    def validate(self) -> None:
        n = type(self).__name__
        for f in (
            "lookahead",
            "goal_tolerance",
            "slow_down_distance",
            "blocked_check_distance",
            "stale_distance",
            "turn_gain",
        ):
            v = getattr(self, f)
            require(math.isfinite(v) and v > 0, n, f, "> 0")
        require(math.isfinite(self.v_min) and math.isfinite(self.v_max), n, "v_max", "finite")
        require(self.v_min <= 0 < self.v_max, n, "v_max", "need v_min <= 0 < v_max")
        require(math.isfinite(self.w_min) and math.isfinite(self.w_max), n, "w_max", "finite")
        require(self.w_min < 0 < self.w_max, n, "w_max", "need w_min < 0 < w_max")
        require(0 < self.turn_in_place_deg <= 180, n, "turn_in_place_deg", "in (0, 180]")
        require(self.min_approach_speed >= 0, n, "min_approach_speed", ">= 0")
        require(self.slow_clearance >= 0, n, "slow_clearance", ">= 0")
        require(0 < self.min_clearance_scale <= 1, n, "min_clearance_scale", "in (0, 1]")


class FollowerCommand(NamedTuple):
    """One follower output."""

    v: float
    """Forward speed, m/s, in [v_min, v_max]."""
    w: float
    """Yaw rate, rad/s (CCW positive), in [w_min, w_max]."""
    status: Status
    lookahead_xy: np.ndarray
    """(2,) current lookahead point."""
    cross_track: float
    """Distance from the robot to the path, m."""
    remaining: float
    """Path length left from the robot's projection, m."""


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class PathFollower:
    """Stateful pure-pursuit follower (keeps the path and the progress along it)."""

    def __init__(
        self, cfg: FollowerConfig | None = None, checker: CollisionChecker | None = None
    ) -> None:
        self.cfg = cfg if cfg is not None else FollowerConfig()
        self.checker = checker
        self.path = np.zeros((0, 2))
        self._cum = np.zeros(0)
        self._seg = 0

    def set_path(self, path: np.ndarray) -> None:
        """New (M, 2) path (M >= 1) in the planning frame; progress restarts at its start."""
        p = np.asarray(path, dtype=np.float64).reshape(-1, 2)
        if len(p) == 0 or not np.all(np.isfinite(p)):
            raise ValueError("path must be a non-empty finite (M, 2) array")
        if len(p) == 1:
            p = np.repeat(p, 2, axis=0)
        self.path = p
        seg = segment_lengths(p)
        self._cum = np.concatenate([[0.0], np.cumsum(seg)])
        self._seg = 0

    def _point_at(self, s: float) -> np.ndarray:
        s = min(max(s, 0.0), float(self._cum[-1]))
        i = int(np.clip(np.searchsorted(self._cum, s, side="right") - 1, 0, len(self.path) - 2))
        L = self._cum[i + 1] - self._cum[i]
        t = 0.0 if L <= 0 else (s - self._cum[i]) / L
        return self.path[i] + t * (self.path[i + 1] - self.path[i])

    def _project(self, p: np.ndarray) -> tuple[float, float]:
        """Arc length of the closest point on segments >= the current one, and the distance."""
        a = self.path[self._seg : -1]
        b = self.path[self._seg + 1 :]
        d = b - a
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(dd, 1e-18), 0.0, 1.0)
        q = a + t[:, None] * d
        dist = np.hypot(*(q - p).T)
        k = int(np.argmin(dist))
        self._seg += k
        s = self._cum[self._seg] + t[k] * math.sqrt(dd[k])
        return float(s), float(dist[k])

    def _stop(self, status: Status, look: np.ndarray, ct: float, rem: float) -> FollowerCommand:
        return FollowerCommand(0.0, 0.0, status, look, ct, rem)

    def step(self, pose: np.ndarray) -> FollowerCommand:
        """pose: (3,) x, y (m), yaw (rad) in the path's frame -> :class:`FollowerCommand`."""
        if len(self.path) == 0:
            raise ValueError("no path: call set_path() first")
        pose = np.asarray(pose, dtype=np.float64).reshape(-1)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be a finite (x, y, yaw), got {pose}")
        cfg = self.cfg
        p, yaw = pose[:2], float(pose[2])
        s, ct = self._project(p)
        total = float(self._cum[-1])
        rem = total - s
        goal = self.path[-1]
        d_goal = float(np.hypot(*(goal - p)))
        look = self._point_at(s + cfg.lookahead)
        if d_goal <= cfg.goal_tolerance:
            return self._stop("reached", goal.copy(), ct, rem)
        if ct > cfg.stale_distance:
            return self._stop("stale", look, ct, rem)
        if self.checker is not None and not self._ahead_free(s):
            return self._stop("blocked", look, ct, rem)
        if rem < 1e-9 or np.hypot(*(look - p)) < 1e-6:
            look = goal  # near the end: aim at the goal itself
        dx, dy = look - p
        ld = max(math.hypot(dx, dy), 1e-6)
        bearing = _wrap(math.atan2(dy, dx) - yaw)
        if abs(bearing) > math.radians(cfg.turn_in_place_deg):
            w = float(np.clip(cfg.turn_gain * bearing, cfg.w_min, cfg.w_max))
            return FollowerCommand(0.0, w, "turn", look, ct, rem)
        v = cfg.v_max
        if d_goal < cfg.slow_down_distance:
            v = max(
                cfg.v_max * d_goal / cfg.slow_down_distance, min(cfg.min_approach_speed, cfg.v_max)
            )
        if self.checker is not None and cfg.slow_clearance > 0:
            margin = float(self.checker.clearance(p[None])[0]) - self.checker.cfg.inflation
            scale = float(np.clip(margin / cfg.slow_clearance, cfg.min_clearance_scale, 1.0))
            v *= scale
        v *= max(math.cos(bearing), 0.0)
        kappa = 2.0 * math.sin(bearing) / ld
        w = v * kappa
        if w > cfg.w_max or w < cfg.w_min:  # keep the curvature, lower the speed
            w = float(np.clip(w, cfg.w_min, cfg.w_max))
            v = abs(w / kappa)
        v = float(np.clip(v, cfg.v_min, cfg.v_max))
        w = float(np.clip(w, cfg.w_min, cfg.w_max))
        return FollowerCommand(v, w, "follow", look, ct, rem)

    def _ahead_free(self, s: float) -> bool:
        """The path from arc length s to s + blocked_check_distance is free under the checker."""
        assert self.checker is not None
        s1 = min(s + self.cfg.blocked_check_distance, float(self._cum[-1]))
        inner = self.path[(self._cum > s) & (self._cum < s1)]
        pts = np.concatenate([self._point_at(s)[None], inner, self._point_at(s1)[None]])
        if len(pts) < 2 or np.allclose(pts[0], pts[-1]):
            return bool(self.checker.is_free(pts[:1])[0])
        return bool(self.checker.segments_free(pts[:-1], pts[1:]).all())
