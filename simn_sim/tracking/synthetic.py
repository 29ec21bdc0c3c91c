"""Analytic scenes for testing registration and loop closure without a learned map.

The scenes are :class:`~simn_sim.geometry.analytic.AnalyticScene` s (exact SDF, gradient and
ray casting); ``render_points`` casts camera rays to produce the surface points a depth camera
would see.
"""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.analytic import AnalyticScene, ray_cast
from simn_sim.geometry.se3 import transform_points

__all__ = [
    "AnalyticFrameMap",
    "AnalyticScene",
    "look_at",
    "loop_scene",
    "office_scene",
    "plane_scene",
    "ray_cast",
    "render_points",
    "world_points",
]


def office_scene() -> AnalyticScene:
    """A 6 x 5 x 3 m room (floor at z = 0) with three boxes and a sphere."""
    return AnalyticScene(
        room=(np.array([0.0, 0.0, 1.5]), np.array([3.0, 2.5, 1.5])),
        boxes=(
            (np.array([1.8, 1.2, 0.4]), np.array([0.5, 0.4, 0.4])),  # desk-sized block
            (np.array([-1.5, 1.6, 0.9]), np.array([0.3, 0.5, 0.9])),  # shelf
            (np.array([1.6, -1.4, 0.25]), np.array([0.35, 0.35, 0.25])),  # low box
        ),
        spheres=((np.array([-1.2, -1.0, 0.5]), 0.5),),
    )


def plane_scene() -> AnalyticScene:
    """A single infinite floor plane z = 0 (degenerate for registration)."""
    return AnalyticScene(planes=((np.array([0.0, 0.0, 1.0]), 0.0),))


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera (z forward, y down) at ``eye`` looking at ``target``.

    ``up``: world up (None: +z); when it is parallel to the view direction, +x stands in.
    """
    up = (0.0, 0.0, 1.0) if up is None else up
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([1.0, 0.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def render_points(
    scene: AnalyticScene,
    T_world_cam: np.ndarray,
    n_rays: int,
    rng: np.random.Generator,
    hfov_deg: float = 69.0,
    vfov_deg: float = 42.5,
    max_range: float = 8.0,
) -> np.ndarray:
    """Surface points seen by a camera: (M, 3) float32 in the OpenCV camera frame, M <= n_rays.

    Rays through uniformly random pixels of a pinhole with the given fields of view (D435i
    defaults) are intersected exactly with the scene; rays beyond ``max_range`` are dropped.
    """
    tx, ty = np.tan(np.radians(hfov_deg) / 2), np.tan(np.radians(vfov_deg) / 2)
    d = np.stack(
        [rng.uniform(-tx, tx, n_rays), rng.uniform(-ty, ty, n_rays), np.ones(n_rays)], axis=1
    )
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    R, e = T_world_cam[:3, :3], T_world_cam[:3, 3]
    t = ray_cast(scene, np.asarray(e, float), d @ R.T)
    hit = t <= max_range
    return (d[hit] * t[hit, None]).astype(np.float32)


def world_points(points_cam: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """Convenience: camera-frame points to world (float32)."""
    return transform_points(T_world_cam, points_cam.astype(np.float64)).astype(np.float32)


def loop_scene() -> AnalyticScene:
    """An 8 x 8 x 3 m hall (floor z = 0) with asymmetric furniture, for loops around its centre."""
    return AnalyticScene(
        room=(np.array([0.0, 0.0, 1.5]), np.array([4.0, 4.0, 1.5])),
        boxes=(
            (np.array([0.0, 0.0, 0.6]), np.array([0.8, 0.5, 0.6])),  # central block
            (np.array([3.3, -3.0, 0.4]), np.array([0.5, 0.6, 0.4])),
            (np.array([3.4, 1.5, 0.9]), np.array([0.4, 1.0, 0.9])),  # shelf
            (np.array([-3.0, 3.2, 0.35]), np.array([0.8, 0.4, 0.35])),  # desk
            (np.array([-3.4, -1.0, 1.0]), np.array([0.4, 0.4, 1.0])),  # column-ish
            (np.array([1.0, 3.4, 0.25]), np.array([0.3, 0.3, 0.25])),
        ),
        spheres=(
            (np.array([-1.5, -3.2, 0.45]), 0.45),
            (np.array([2.2, 0.8, 1.2]), 0.3),
        ),
    )


class AnalyticFrameMap:
    """A per-frame map backed by an analytic scene, in the frame's (true) anchor coordinates.

    Implements the :class:`~simn_sim.tracking.localframes.FrameMap` protocol for tests: the SDF is
    exact but, like a learned map, only *valid* within ``support_radius`` of the frame's own
    feature points (what the frame observed); feature points are given surface points (anchor
    frame) with features ``sin(W p_world)`` (a fixed function of the world position, so
    revisits see the same features).
    """

    def __init__(
        self,
        scene: AnalyticScene,
        T_world_anchor_true: np.ndarray,
        points_anchor: np.ndarray,
        feature_dim: int = 8,
        labels: np.ndarray | None = None,
        support_radius: float = 0.2,
    ) -> None:
        from scipy.spatial import cKDTree

        self.scene = scene
        self.T = np.asarray(T_world_anchor_true, dtype=np.float64)
        self.P = np.asarray(points_anchor, dtype=np.float32).reshape(-1, 3)
        W = np.random.default_rng(12345).normal(size=(feature_dim, 3)) * 2.0
        Pw = transform_points(self.T, self.P.astype(np.float64))
        self.F = np.sin(Pw @ W.T).astype(np.float32)
        self.L = np.zeros(len(self.P), np.int64) if labels is None else np.asarray(labels)
        self.support_radius = float(support_radius)
        self._tree = cKDTree(self.P.astype(np.float64))

    def feature_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.P, self.F, self.L

    def sdf_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p = np.asarray(points, dtype=np.float64)
        s, g, v = self.scene.sdf_and_grad(transform_points(self.T, p))
        dist, _ = self._tree.query(p, k=1, distance_upper_bound=self.support_radius)
        return s, g @ self.T[:3, :3], v & np.isfinite(dist)
