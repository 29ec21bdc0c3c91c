"""Heading from the walls: the Manhattan-frame yaw of a depth frame's vertical surfaces.

Office walls share two horizontal directions, 90 deg apart. The horizontal normals of a
frame's vertical surfaces, rotated into a gravity-aligned frame, cluster at those directions;
their angle modulo 90 deg is the frame's wall direction, and its change from one frame to
another, measured through the estimated rotations, is the heading error accumulated between
them (modulo 90 deg). Clutter at other angles (rotated desks, boxes) only thins the peak.

Normals come from the organised point image sampled every ``stride`` pixels (a central
difference over ``stride`` pixels: per-pixel normals of D435i depth are too noisy to locate a
peak, docs/navigation.md "The same default on another CPU"). Not used by the agent yet.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.geometry.camera import Intrinsics, pixel_rays
from simn_sim.semantics import normals_from_organized

__all__ = ["ManhattanYaw", "frame_normals", "manhattan_yaw"]


@dataclasses.dataclass(frozen=True)
class ManhattanYaw:
    """``yaw_deg``: the wall direction modulo 90 deg, in (-45, 45]; ``support``: the share of
    the vertical surfaces' normals within ``support_deg`` of it (modulo 90 deg);
    ``n_vertical``: how many normals were vertical surfaces'."""

    yaw_deg: float
    support: float
    n_vertical: int


def frame_normals(
    depth: np.ndarray, intr: Intrinsics, stride: int = 8, max_depth: float = 3.0
) -> np.ndarray:
    """(M, 3) unit normals (OpenCV camera frame) of a depth image's points nearer than
    ``max_depth``, from the point image sampled every ``stride`` pixels. Zero, NaN and
    infinite depths are invalid pixels (no normal touches them)."""
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"depth must be float metres, got dtype {d.dtype}")
    if int(stride) < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    if not (np.isfinite(max_depth) and max_depth > 0):
        raise ValueError(f"max_depth must be > 0, got {max_depth}")
    if d.shape != (intr.height, intr.width):
        raise ValueError(
            f"depth is {d.shape[1]}x{d.shape[0]} but intrinsics are {intr.width}x{intr.height}"
        )
    rx, ry = pixel_rays(intr, stride)  # only the sampled pixels are back-projected
    z = d[::stride, ::stride].astype(np.float32, copy=False)
    P = np.stack([rx * z, ry * z, z], axis=-1).astype(np.float64)
    z = P[..., 2]
    P[~(np.isfinite(z) & (z > 0))] = np.nan
    N = normals_from_organized(P, max_jump=0.05 * stride)
    ok = np.isfinite(N).all(-1) & (z < max_depth)
    return N[ok]


def manhattan_yaw(
    normals_world: np.ndarray,
    vertical_max_nz: float = 0.2,
    min_normals: int = 200,
    peak_halfwidth_deg: float = 4.0,
    support_deg: float = 2.0,
) -> ManhattanYaw | None:
    """The wall direction of gravity-aligned normals (N, 3) (z up); None with fewer than
    ``min_normals`` vertical-surface normals (``|n_z| < vertical_max_nz``). The angles are
    taken modulo 90 deg (as 4x the angle on the circle), the peak of a 0.25 deg histogram
    (smoothed over 3 bins) is refined by the circular mean within ``peak_halfwidth_deg``."""
    n = np.asarray(normals_world, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals_world must be (N, 3), got shape {n.shape}")
    n = n[np.isfinite(n).all(1)]
    v = n[np.abs(n[:, 2]) < vertical_max_nz]
    if len(v) < max(int(min_normals), 1):
        return None
    a = np.angle(np.exp(4j * np.arctan2(v[:, 1], v[:, 0])))  # 4 x angle, in (-pi, pi]
    h, edges = np.histogram(a, bins=360, range=(-np.pi, np.pi))
    hs = h + np.roll(h, 1) + np.roll(h, -1)
    k = int(np.argmax(hs))
    c = 0.5 * (edges[k] + edges[k + 1])
    d = np.angle(np.exp(1j * (a - c)))
    near = np.abs(d) < np.radians(4 * peak_halfwidth_deg)
    c = c + float(np.angle(np.mean(np.exp(1j * d[near]))))
    yaw = float(np.degrees(np.angle(np.exp(1j * c)))) / 4.0
    if yaw <= -45.0:
        yaw += 90.0
    d = np.angle(np.exp(1j * (a - c)))
    support = float(np.mean(np.abs(d) < np.radians(4 * support_deg)))
    return ManhattanYaw(yaw_deg=yaw, support=support, n_vertical=len(v))
