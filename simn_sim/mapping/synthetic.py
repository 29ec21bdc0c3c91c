"""Analytic test scenes for mapping: a box room with boxes and spheres (exact SDF and ray-cast
depth from :mod:`simn_sim.geometry.analytic`) and camera orbits."""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.analytic import AnalyticScene, Box, Sphere, box_sdf
from simn_sim.tracking.synthetic import look_at

__all__ = ["AnalyticScene", "Box", "Sphere", "box_room_scene", "box_sdf", "look_at", "orbit_poses"]


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
