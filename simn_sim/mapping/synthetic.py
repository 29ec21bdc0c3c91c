"""Analytic test scenes: a box room with boxes and spheres, exact SDF and ray-cast depth.

Used by the mapping tests and benchmark (and usable by anyone needing exact geometry). The room
is a hollow box: free space inside (positive SDF), solid outside. Boxes and spheres are solid.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.geometry.camera import Intrinsics
from simn_sim.tracking.synthetic import look_at

__all__ = ["AnalyticScene", "Box", "Sphere", "box_room_scene", "box_sdf", "look_at", "orbit_poses"]


@dataclasses.dataclass(frozen=True)
class Box:
    center: tuple[float, float, float]
    half: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class Sphere:
    center: tuple[float, float, float]
    radius: float


def box_sdf(points: np.ndarray, box: Box) -> np.ndarray:
    q = np.abs(points - np.asarray(box.center)) - np.asarray(box.half)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


@dataclasses.dataclass(frozen=True)
class AnalyticScene:
    room: Box
    boxes: tuple[Box, ...] = ()
    spheres: tuple[Sphere, ...] = ()

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N,) float64 exact signed distance (positive in free space)."""
        p = np.asarray(points, np.float64)
        d = -box_sdf(p, self.room)
        for b in self.boxes:
            d = np.minimum(d, box_sdf(p, b))
        for s in self.spheres:
            d = np.minimum(d, np.linalg.norm(p - np.asarray(s.center), axis=1) - s.radius)
        return d

    def raycast(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter ``t`` of the first hit of ``o + t d`` (origins inside the room)."""
        o = np.broadcast_to(np.asarray(origins, np.float64), dirs.shape)
        d = np.asarray(dirs, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            lo = np.asarray(self.room.center) - np.asarray(self.room.half)
            hi = np.asarray(self.room.center) + np.asarray(self.room.half)
            t = np.max(np.stack([(lo - o) * inv, (hi - o) * inv]), axis=0).min(axis=1)
            for b in self.boxes:
                blo = np.asarray(b.center) - np.asarray(b.half)
                bhi = np.asarray(b.center) + np.asarray(b.half)
                t1, t2 = (blo - o) * inv, (bhi - o) * inv
                tn = np.minimum(t1, t2).max(axis=1)
                tf = np.maximum(t1, t2).min(axis=1)
                hit = (tn <= tf) & (tn > 0)
                t = np.where(hit & (tn < t), tn, t)
            for s in self.spheres:
                oc = o - np.asarray(s.center)
                a = (d * d).sum(1)
                bq = (oc * d).sum(1)
                c = (oc * oc).sum(1) - s.radius**2
                disc = bq * bq - a * c
                th = (-bq - np.sqrt(np.maximum(disc, 0.0))) / a
                hit = (disc >= 0) & (th > 0)
                t = np.where(hit & (th < t), th, t)
        return t

    def render_depth(self, intr: Intrinsics, T_world_cam: np.ndarray) -> np.ndarray:
        """(H, W) float32 depth (z in the OpenCV camera frame) by exact ray casting."""
        v, u = np.mgrid[0 : intr.height, 0 : intr.width]
        d_cam = np.stack(
            [(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, dtype=np.float64)],
            -1,
        ).reshape(-1, 3)
        d_world = d_cam @ T_world_cam[:3, :3].T  # z component 1 in the camera: t is depth
        t = self.raycast(T_world_cam[:3, 3], d_world)
        return t.reshape(intr.height, intr.width).astype(np.float32)


def box_room_scene() -> AnalyticScene:
    """A 4 x 3 x 2.5 m room with three boxes and a sphere (floor at z = 0)."""
    return AnalyticScene(
        room=Box((0.0, 0.0, 1.25), (2.0, 1.5, 1.25)),
        boxes=(
            Box((1.2, 0.8, 0.35), (0.35, 0.3, 0.35)),
            Box((-1.1, -0.7, 0.25), (0.4, 0.35, 0.25)),
            Box((1.3, -0.9, 0.6), (0.25, 0.25, 0.6)),
        ),
        spheres=(Sphere((-0.9, 0.7, 0.45), 0.3),),
    )


def orbit_poses(
    n: int, radius: float = 0.6, height: float = 1.3, center=(0.0, 0.0)
) -> list[np.ndarray]:
    """``n`` cameras on a circle around ``center`` looking outwards and slightly down."""
    out = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a), height])
        target = np.array([center[0] + 3 * np.cos(a), center[1] + 3 * np.sin(a), 0.5])
        out.append(look_at(eye, target))
    return out
