"""Navigation episode metrics with Habitat-lab's definitions (``habitat/tasks/nav/nav.py``).

All lengths are metres in the world x-y plane; times are seconds.

* success: ``distance_to_goal < success_distance`` (Habitat's strict inequality; Habitat
  additionally requires the STOP action, which here is the caller's termination logic).
* SPL (Anderson et al. 2018): ``S * l / max(p, l)`` with l the geodesic start-goal distance
  and p the length of the path actually travelled.
* Soft SPL (Habitat ``SoftSPL``): ``max(0, 1 - d_T / d_0) * l / max(p, l)`` where d_T is the
  *geodesic* distance from the final position to the goal and d_0 = l is the geodesic distance
  from the start.

Degenerate cases Habitat leaves undefined (it divides by zero) are fixed here: when
``l == p == 0`` the efficiency ``l / max(p, l)`` is 1, and when ``d_0 == 0`` the soft success is 1
if ``d_T == 0`` and 0 otherwise. An infinite d_T (final position cannot reach the goal) gives a
soft success of 0.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simn_sim.geometry.paths import path_length

__all__ = ["EpisodeMetrics", "path_length", "soft_spl", "spl", "success"]


def _length(value: float, name: str, allow_inf: bool = False) -> float:
    """Validate a length (metres): a real number >= 0, finite unless ``allow_inf``."""
    if isinstance(value, bool):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number, got {value!r}") from exc
    if math.isnan(v) or v < 0.0 or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name} must be a {'' if allow_inf else 'finite '}length >= 0, got {v}")
    return v


def _success_value(s: bool | float, name: str = "success") -> float:
    if isinstance(s, (bool, np.bool_)):
        return float(s)
    try:
        v = float(s)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a bool or a number in [0, 1], got {s!r}") from exc
    if not 0.0 <= v <= 1.0:
        raise ValueError(f"{name} must be a bool or a number in [0, 1], got {s!r}")
    return v


def _efficiency(shortest: float, travelled: float) -> float:
    """``l / max(p, l)``; 1 when both are 0."""
    denom = max(shortest, travelled)
    return 1.0 if denom == 0.0 else shortest / denom


def success(distance_to_goal: float, success_distance: float) -> bool:
    """Habitat success: ``distance_to_goal < success_distance`` (metres).

    ``distance_to_goal`` may be ``inf`` (e.g. an unreachable final position): not a success.
    """
    d = _length(distance_to_goal, "distance_to_goal", allow_inf=True)
    sd = _length(success_distance, "success_distance")
    return d < sd


def spl(success: bool | float, shortest_path_length: float, path_length: float) -> float:
    """Success weighted by Path Length: ``S * l / max(p, l)``.

    Args:
        success: episode success (bool or a number in [0, 1]).
        shortest_path_length: l, geodesic distance start -> goal (metres, finite, >= 0).
        path_length: p, length travelled (metres, finite, >= 0).
    """
    s = _success_value(success)
    ln = _length(shortest_path_length, "shortest_path_length")
    p = _length(path_length, "path_length")
    return s * _efficiency(ln, p)


def soft_spl(dist_to_goal_final: float, geodesic_start: float, path_length: float) -> float:
    """Habitat Soft SPL: ``max(0, 1 - d_T / d_0) * d_0 / max(p, d_0)``.

    Args:
        dist_to_goal_final: d_T, geodesic distance from the final position to the goal (metres;
            ``inf`` allowed and gives 0).
        geodesic_start: d_0, geodesic distance from the start to the goal (finite, >= 0).
        path_length: p, length travelled (finite, >= 0).
    """
    d_t = _length(dist_to_goal_final, "dist_to_goal_final", allow_inf=True)
    d_0 = _length(geodesic_start, "geodesic_start")
    p = _length(path_length, "path_length")
    if d_0 == 0.0:
        soft = 1.0 if d_t == 0.0 else 0.0
    else:
        soft = min(1.0, max(0.0, 1.0 - d_t / d_0))
    return soft * _efficiency(d_0, p)


def _point(xy: Any, name: str) -> np.ndarray:
    p = np.asarray(xy, dtype=np.float64)
    if p.shape != (2,):
        raise ValueError(f"{name} must be a world x-y point of shape (2,), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be finite, got {p.tolist()}")
    return p


class EpisodeMetrics:
    """Accumulates per-step quantities of one episode and produces its metrics row.

    Args:
        dt: control period in seconds (sim time added per :meth:`step` unless overridden).

    Usage::

        m = EpisodeMetrics(dt=0.1)
        m.reset(start_xy, geodesic_start)
        for each control step: m.step(xy, collided, clearance)
        row = m.finish("success", final_distance, final_geodesic, success_distance)
    """

    def __init__(self, dt: float) -> None:
        self.dt = _length(dt, "dt")
        self._active = False
        self._start = np.zeros(2)
        self._prev = np.zeros(2)
        self._geodesic_start = 0.0
        self._path = 0.0
        self._collisions = 0
        self._collided_steps = 0
        self._was_colliding = False
        self._min_clearance = math.inf
        self._steps = 0
        self._sim_time = 0.0

    def reset(self, start_xy: np.ndarray, geodesic_start: float) -> None:
        """Start an episode at ``start_xy`` (2,) world x-y with geodesic start-goal distance
        ``geodesic_start`` (metres, finite, >= 0)."""
        self._start = _point(start_xy, "start_xy")
        self._prev = self._start.copy()
        self._geodesic_start = _length(geodesic_start, "geodesic_start")
        self._path = 0.0
        self._collisions = 0
        self._collided_steps = 0
        self._was_colliding = False
        self._min_clearance = math.inf
        self._steps = 0
        self._sim_time = 0.0
        self._active = True

    def step(
        self, xy: np.ndarray, collided: bool, clearance: float, dt: float | None = None
    ) -> None:
        """Record one control step.

        Args:
            xy: (2,) robot position after the step, world x-y metres.
            collided: whether the robot was in contact with an obstacle during this step.
                A collision *event* is counted on each rising edge (not colliding -> colliding).
            clearance: distance from the robot's surface to the nearest obstacle (metres; may
                be negative for penetration, NaN is rejected).
            dt: seconds of sim time of this step (default: the constructor's ``dt``).
        """
        if not self._active:
            raise RuntimeError("EpisodeMetrics.step called before reset (or after finish)")
        p = _point(xy, "xy")
        c = float(clearance)
        if math.isnan(c):
            raise ValueError("clearance must not be NaN")
        step_dt = self.dt if dt is None else _length(dt, "dt")
        self._path += float(np.hypot(*(p - self._prev)))
        self._prev = p
        hit = bool(collided)
        if hit:
            self._collided_steps += 1
            if not self._was_colliding:
                self._collisions += 1
        self._was_colliding = hit
        self._min_clearance = min(self._min_clearance, c)
        self._steps += 1
        self._sim_time += step_dt

    @property
    def collisions(self) -> int:
        """Collision events so far (rising edges)."""
        return self._collisions

    @property
    def path_length_m(self) -> float:
        """Length travelled so far (metres)."""
        return self._path

    @property
    def collided_steps(self) -> int:
        """Steps with contact so far."""
        return self._collided_steps

    @property
    def steps(self) -> int:
        """Steps recorded so far."""
        return self._steps

    @property
    def sim_time_s(self) -> float:
        """Sim time recorded so far (seconds)."""
        return self._sim_time

    @property
    def min_clearance_m(self) -> float:
        """Smallest clearance recorded so far (metres; inf before the first step)."""
        return self._min_clearance

    def finish(
        self,
        termination_reason: str,
        final_distance: float,
        final_geodesic: float,
        success_distance: float,
    ) -> dict[str, Any]:
        """Close the episode and return its metrics.

        Args:
            termination_reason: recorded verbatim (e.g. "success", "timeout", "collision").
            final_distance: distance to the goal used for success (metres; the env's convention,
                Habitat uses the geodesic one; ``inf`` allowed).
            final_geodesic: geodesic distance from the final position to the goal (metres;
                ``inf`` allowed) used for soft SPL.
            success_distance: success radius (metres).

        Returns:
            dict with success (bool), spl, soft_spl, path_length_m, geodesic_distance_m,
            collisions (rising edges), collided_steps, min_clearance_m (None if no finite
            clearance was recorded), steps, sim_time_s, termination.
        """
        if not self._active:
            raise RuntimeError("EpisodeMetrics.finish called before reset (or twice)")
        if not isinstance(termination_reason, str) or not termination_reason:
            raise ValueError(
                f"termination_reason must be a non-empty string, got {termination_reason!r}"
            )
        ok = success(final_distance, success_distance)
        row = {
            "success": ok,
            "spl": spl(ok, self._geodesic_start, self._path),
            "soft_spl": soft_spl(final_geodesic, self._geodesic_start, self._path),
            "path_length_m": self._path,
            "geodesic_distance_m": self._geodesic_start,
            "collisions": self._collisions,
            "collided_steps": self._collided_steps,
            "min_clearance_m": self._min_clearance if math.isfinite(self._min_clearance) else None,
            "steps": self._steps,
            "sim_time_s": self._sim_time,
            "termination": termination_reason,
        }
        self._active = False
        return row
