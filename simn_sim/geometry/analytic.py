"""Analytic scenes with exact geometry: signed distance, gradient, ray casting, rendered depth.

A scene is a union of primitives in world coordinates (metres): an optional *room* (the free
space inside an axis-aligned box: walls, floor and ceiling), solid axis-aligned boxes, spheres
and half-spaces (planes). In free space the SDF is the exact Euclidean distance to the nearest
surface (positive), its gradient the analytic gradient of the closest primitive. Ray casting
intersects every primitive exactly. Used as ground truth by the mapping, tracking and semantics
tests and benchmarks (scene factories in :mod:`simn_sim.mapping.synthetic` and
:mod:`simn_sim.tracking.synthetic`).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from simn_sim.geometry.camera import Intrinsics

__all__ = ["AnalyticScene", "Box", "Sphere", "box_sdf", "ray_cast"]


class Box(NamedTuple):
    """An axis-aligned box: centre (3,) and half extents (3,)."""

    center: tuple[float, float, float] | np.ndarray
    half: tuple[float, float, float] | np.ndarray


class Sphere(NamedTuple):
    center: tuple[float, float, float] | np.ndarray
    radius: float


def _box_sdf_grad(p: np.ndarray, c: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def box_sdf(points: np.ndarray, box: Box) -> np.ndarray:
    """(N,) exact SDF of a solid box (positive outside)."""
    c, h = (np.asarray(a, np.float64) for a in box)
    return _box_sdf_grad(np.asarray(points, np.float64), c, h)[0]


@dataclasses.dataclass(frozen=True)
class AnalyticScene:
    """Union of primitives (see the module docstring).

    room: a :class:`Box` (or ``(centre, half)``) or None. boxes: solid boxes. spheres:
    :class:`Sphere` s (or ``(centre, radius)``). planes: ``(unit normal n, offset d)``: solid
    half-space ``n . p < d``, free ``n . p > d``.
    """

    room: Box | tuple | None = None
    boxes: tuple = ()
    spheres: tuple = ()
    planes: tuple = ()

    def sdf_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) world points -> SDF (N,) float64, gradient (N, 3) float64, valid (N,) bool."""
        p = np.asarray(points, dtype=np.float64)
        sdfs, grads = [], []
        if self.room is not None:
            c, h = (np.asarray(a, float) for a in self.room)
            s, g = _box_sdf_grad(p, c, h)
            sdfs.append(-s)
            grads.append(-g)
        for c, h in self.boxes:
            s, g = _box_sdf_grad(p, np.asarray(c, float), np.asarray(h, float))
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
        """(N, 3) world points -> (N,) float64 exact signed distance (positive in free space)."""
        return self.sdf_and_grad(points)[0]

    def raycast(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter ``t`` of the first hit of ``o + t d`` (see :func:`ray_cast`)."""
        return ray_cast(self, origins, dirs)

    def render_depth(self, intr: Intrinsics, T_world_cam: np.ndarray) -> np.ndarray:
        """(H, W) float32 depth (z in the OpenCV camera frame) by exact ray casting."""
        v, u = np.mgrid[0 : intr.height, 0 : intr.width]
        d_cam = np.stack(
            [(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, dtype=np.float64)],
            -1,
        ).reshape(-1, 3)
        d_world = d_cam @ T_world_cam[:3, :3].T  # z component 1 in the camera: t is depth
        t = ray_cast(self, T_world_cam[:3, 3], d_world)
        return t.reshape(intr.height, intr.width).astype(np.float32)


def _slab(e: np.ndarray, d: np.ndarray, c: np.ndarray, h: np.ndarray):
    """Entry and exit ray parameters of an axis-aligned box (slab method), each (N,)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (c - h - e) * inv
        t2 = (c + h - e) * inv
    t1 = np.where(np.isnan(t1), -np.inf, t1)
    t2 = np.where(np.isnan(t2), np.inf, t2)
    return np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)


def ray_cast(scene: AnalyticScene, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Ray parameter of the first hit along ``o + t d`` (in units of ``|d|``; with unit
    directions the distance); inf for no hit. origins: (3,) or (N, 3) in free space; dirs: (N, 3).
    """
    d = np.asarray(dirs, np.float64)
    e = np.broadcast_to(np.asarray(origins, np.float64), d.shape)
    t = np.full(len(d), np.inf)
    if scene.room is not None:
        c, h = (np.asarray(a, float) for a in scene.room)
        _, tf = _slab(e, d, c, h)
        t = np.minimum(t, np.where(tf > 0, tf, np.inf))
    for c, h in scene.boxes:
        tn, tf = _slab(e, d, np.asarray(c, float), np.asarray(h, float))
        t = np.minimum(t, np.where((tn <= tf) & (tn > 0), tn, np.inf))
    a = np.einsum("ij,ij->i", d, d)
    for c, r in scene.spheres:
        oc = e - np.asarray(c, float)
        b = np.einsum("ij,ij->i", d, oc)
        disc = b * b - a * (np.einsum("ij,ij->i", oc, oc) - r * r)
        root = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        t = np.minimum(t, np.where((disc >= 0) & (root > 0), root, np.inf))
    for nrm, off in scene.planes:
        nrm = np.asarray(nrm, float) / np.linalg.norm(nrm)
        dn = d @ nrm
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = (off - e @ nrm) / dn
        t = np.minimum(t, np.where((dn < 0) & (tp > 0), tp, np.inf))
    return t
