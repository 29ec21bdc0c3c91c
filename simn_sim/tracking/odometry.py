"""Frame-to-frame depth odometry: the registration on a point-to-plane surface of the previous
frame, chained. A baseline (no learned map) for TUM sequences and for checking the tracker on
real data; the SIMN agent registers to the local frame's learned map instead."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np

from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.se3 import inv_T

if TYPE_CHECKING:
    from simn_sim.io.tum import TumFrame
from simn_sim.tracking.lie import check_pose
from simn_sim.tracking.pointsdf import PointCloudSDF, voxel_downsample
from simn_sim.tracking.registration import RegistrationConfig, RegistrationResult, register


def frame_points(
    depth: np.ndarray, intr: Intrinsics, n_points: int, voxel: float, rng: np.random.Generator
) -> np.ndarray:
    """(M, 3) float32 camera-frame points: valid depth, voxel down-sampled, at most n_points."""
    P = backproject(np.asarray(depth, dtype=np.float32), intr)[depth > 0]
    P = P[voxel_downsample(P, voxel)]
    if len(P) > n_points:
        P = P[rng.choice(len(P), n_points, replace=False)]
    return P.astype(np.float32)


def depth_odometry(
    frames: Iterable[TumFrame],
    intr: Intrinsics,
    T_world_cam0: np.ndarray | None = None,
    cfg: RegistrationConfig | None = None,
    n_points: int = 4000,
    voxel: float = 0.02,
    surface_voxel: float = 0.02,
    rng: np.random.Generator | None = None,
) -> tuple[list[tuple[float, np.ndarray]], list[RegistrationResult]]:
    """Chain frame-to-frame registrations with a constant-velocity prior.

    Returns ``[(timestamp, T_world_cam)]`` (the first pose is ``T_world_cam0``, default the
    identity) and the per-frame registration results. A failed registration keeps the prior
    (constant velocity), as the tracker does.
    """
    rng = rng or np.random.default_rng(0)
    T0 = np.eye(4) if T_world_cam0 is None else check_pose(T_world_cam0, "T_world_cam0")
    traj: list[tuple[float, np.ndarray]] = []
    results: list[RegistrationResult] = []
    prev_surf, rel = None, np.eye(4)
    for f in frames:
        if prev_surf is None:
            traj.append((f.timestamp, T0.copy()))
        else:
            P = frame_points(f.depth, intr, n_points, voxel, rng)
            res = register(P, prev_surf.sdf_and_grad, rel, cfg)  # prior: last relative motion
            results.append(res)
            rel = res.pose
            traj.append((f.timestamp, traj[-1][1] @ rel))
        prev_surf = PointCloudSDF.from_depth(f.depth, intr, voxel=surface_voxel)
    return traj, results


def relative_motion(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """``T_a^-1 T_b``."""
    return inv_T(T_a) @ T_b
