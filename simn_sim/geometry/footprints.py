"""Footprint validation and corner geometry shared by :mod:`simn_sim.geometry.freespace` and
:mod:`simn_sim.geometry.geodesic` (world x-y metres, angles in radians; see the model in
:mod:`simn_sim.geometry.freespace`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely

_CORE_SHRINK = 1e-5  # m; visibility tests use obstacles inflated by r - this
_THICKEN = 1e-6  # m; zero-area obstacles (points, lines) are thickened by this
_ARC_STEP = math.radians(1.0)  # arc free-ness is sampled at most this far apart
_ANG_TOL = 1e-9  # rad; tolerance on the valid angular range of a corner circle
_KEY = 8.0  # > 2 pi: sort key of a node is corner * _KEY + relative angle
_TWO_PI = 2.0 * math.pi
_BATCH = 8  # visibility checks per vectorised batch in point queries


# --------------------------------------------------------------------------- validation


def _as_point(xy: np.ndarray | Sequence[float], name: str) -> np.ndarray:
    """Validate one point: returns a (2,) float64 array (world x-y, metres)."""
    p = np.asarray(xy, dtype=np.float64)
    if p.shape != (2,):
        raise ValueError(f"{name}: expected a point of shape (2,), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: point must be finite, got {p.tolist()}")
    return p


def _as_points(xy: np.ndarray | Sequence, name: str) -> np.ndarray:
    """Validate points of shape (..., 2): returns a float64 array of the same shape."""
    p = np.asarray(xy, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 2:
        raise ValueError(f"{name}: expected points of shape (..., 2), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name}: points must be finite (found NaN or inf)")
    return p


def _as_polygonal(obstacle: np.ndarray | shapely.Geometry, index: int) -> list[shapely.Polygon]:
    """Convert one obstacle footprint to a list of valid shapely polygons."""
    if isinstance(obstacle, shapely.Geometry):
        geom = obstacle
        if geom.is_empty:
            raise ValueError(f"obstacles[{index}]: empty geometry")
        if not shapely.is_valid(geom):
            reason = shapely.is_valid_reason(geom)
            raise ValueError(f"obstacles[{index}]: invalid geometry ({reason})")
        if not isinstance(geom, (shapely.Polygon, shapely.MultiPolygon)) or geom.area <= 0.0:
            geom = shapely.buffer(geom, _THICKEN, cap_style="square", join_style="mitre")
    else:
        arr = np.asarray(obstacle, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 3:
            raise ValueError(
                f"obstacles[{index}]: expected a (K, 2) polygon vertex array with K >= 3, "
                f"got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"obstacles[{index}]: vertices must be finite (found NaN or inf)")
        geom = shapely.Polygon(arr)
        if not shapely.is_valid(geom):
            reason = shapely.is_valid_reason(geom)
            raise ValueError(f"obstacles[{index}]: invalid polygon ({reason})")
        if geom.area <= 0.0:
            raise ValueError(f"obstacles[{index}]: polygon has zero area")
    parts = [g for g in shapely.get_parts(geom) if isinstance(g, shapely.Polygon) and g.area > 0]
    return [shapely.geometry.polygon.orient(g, sign=1.0) for g in parts]


# --------------------------------------------------------------------------- corners


def _ring_corners(coords: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convex corners of one ring whose obstacle material lies on its left.

    Args:
        coords: (K, 2) ring coordinates (closed or open).

    Returns:
        centres (C, 2); theta0 (C,) angle of the outward normal of the incoming edge;
        width (C,) turn angle in (0, pi): the circle of the corner is part of the inflated
        boundary for angles theta0 .. theta0 + width (counter-clockwise).
    """
    pts = np.asarray(coords, dtype=np.float64)
    if len(pts) > 1 and np.allclose(pts[0], pts[-1]):
        pts = pts[:-1]
    keep = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1) > 1e-12
    pts = pts[keep]
    if len(pts) < 3:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    e_in = pts - np.roll(pts, 1, axis=0)
    e_out = np.roll(pts, -1, axis=0) - pts
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    dot = np.einsum("ij,ij->i", e_in, e_out)
    turn = np.arctan2(cross, dot)
    convex = turn > 1e-9
    theta0 = np.arctan2(-e_in[:, 0], e_in[:, 1])  # outward (right-hand) normal of e_in
    return pts[convex], theta0[convex], turn[convex]


def _rel_angle(
    phi: np.ndarray, theta0: np.ndarray, width: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Angle of ``phi`` relative to a corner's valid range; returns (rel in [0, width], valid)."""
    rel = np.mod(phi - theta0, _TWO_PI)
    rel = np.where(rel > _TWO_PI - _ANG_TOL, 0.0, rel)
    valid = rel <= width + _ANG_TOL
    return np.minimum(rel, width), valid
