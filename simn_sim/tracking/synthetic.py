"""Analytic signed-distance scenes for testing registration and loop closure without a learned map.

A scene is a union of primitives: an optional *room* (the free space inside an axis-aligned box,
SDF positive inside), solid axis-aligned boxes, spheres and half-spaces (planes). For points in
free space the SDF is the exact Euclidean distance to the nearest surface; the gradient is the
analytic gradient of the closest primitive. ``render_points`` casts camera rays by sphere tracing
to produce the surface points a depth camera would see.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.geometry.se3 import transform_points


def _box_sdf(p: np.ndarray, c: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact SDF of a solid box (centre c, half extents h) and its gradient. p: (N, 3)."""
    d = p - c
    s = np.where(d >= 0, 1.0, -1.0)
    q = np.abs(d) - h
    qp = np.maximum(q, 0.0)
    out_norm = np.linalg.norm(qp, axis=1)
    k = np.argmax(q, axis=1)
    qmax = q[np.arange(len(q)), k]
    sdf = out_norm + np.minimum(qmax, 0.0)
    grad_out = s * qp / np.maximum(out_norm, 1e-12)[:, None]
    grad_in = np.zeros_like(p)
    grad_in[np.arange(len(p)), k] = s[np.arange(len(p)), k]
    outside = (qmax > 0)[:, None]
    return sdf, np.where(outside, grad_out, grad_in)


@dataclasses.dataclass(frozen=True)
class AnalyticScene:
    """Union of primitives in world coordinates (metres).

    room: (centre (3,), half extents (3,)) or None -- free space inside, walls/floor/ceiling.
    boxes: list of (centre, half extents) solid boxes. spheres: list of (centre, radius).
    planes: list of (unit normal n, offset d): solid half-space ``n . p < d``, free ``n . p > d``.
    """

    room: tuple[np.ndarray, np.ndarray] | None = None
    boxes: tuple = ()
    spheres: tuple = ()
    planes: tuple = ()

    def sdf_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) world points -> SDF (N,) float64, gradient (N, 3) float64, valid (N,) bool."""
        p = np.asarray(points, dtype=np.float64)
        sdfs, grads = [], []
        if self.room is not None:
            c, h = (np.asarray(a, float) for a in self.room)
            s, g = _box_sdf(p, c, h)
            sdfs.append(-s)
            grads.append(-g)
        for c, h in self.boxes:
            s, g = _box_sdf(p, np.asarray(c, float), np.asarray(h, float))
            sdfs.append(s)
            grads.append(g)
        for c, r in self.spheres:
            d = p - np.asarray(c, float)
            n = np.linalg.norm(d, axis=1)
            sdfs.append(n - r)
            grads.append(d / np.maximum(n, 1e-12)[:, None])
        for nrm, off in self.planes:
            nrm = np.asarray(nrm, float) / np.linalg.norm(nrm)
            sdfs.append(p @ nrm - off)
            grads.append(np.broadcast_to(nrm, p.shape))
        if not sdfs:
            raise ValueError("AnalyticScene has no primitives")
        S = np.stack(sdfs, axis=1)
        k = np.argmin(S, axis=1)
        idx = np.arange(len(p))
        G = np.stack(grads, axis=1)
        return S[idx, k], G[idx, k], np.ones(len(p), dtype=bool)

    def sdf(self, points: np.ndarray) -> np.ndarray:
        return self.sdf_and_grad(points)[0]


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


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera (z forward, y down) at ``eye`` looking at ``target``."""
    up = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, float)
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
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
    tol: float = 1e-6,
    max_steps: int = 400,
) -> np.ndarray:
    """Surface points seen by a camera: (M, 3) float32 in the OpenCV camera frame, M <= n_rays.

    Rays through uniformly random pixels of a pinhole with the given fields of view are sphere
    traced against the exact SDF; rays that leave ``max_range`` or do not converge are dropped.
    """
    tx, ty = np.tan(np.radians(hfov_deg) / 2), np.tan(np.radians(vfov_deg) / 2)
    d = np.stack(
        [rng.uniform(-tx, tx, n_rays), rng.uniform(-ty, ty, n_rays), np.ones(n_rays)], axis=1
    )
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    R, e = T_world_cam[:3, :3], T_world_cam[:3, 3]
    dw = d @ R.T
    t = np.zeros(n_rays)
    active = np.ones(n_rays, dtype=bool)
    hit = np.zeros(n_rays, dtype=bool)
    for _ in range(max_steps):
        ia = np.flatnonzero(active)
        if ia.size == 0:
            break
        s = scene.sdf(e + t[ia, None] * dw[ia])
        done = s < tol
        hit[ia[done]] = True
        t[ia[~done]] += s[~done]
        gone = t[ia] > max_range
        active[ia[done | gone]] = False
    pts = d[hit] * t[hit, None]
    return pts.astype(np.float32)


def world_points(points_cam: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """Convenience: camera-frame points to world (float32)."""
    return transform_points(T_world_cam, points_cam.astype(np.float64)).astype(np.float32)
