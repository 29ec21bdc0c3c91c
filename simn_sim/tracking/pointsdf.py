"""A point-to-plane implicit surface from a point cloud: the simplest ``sdf_and_grad`` for real data.

``sdf(x) = n_k . (x - p_k)`` with ``p_k`` the nearest surface point and ``n_k`` its normal
(oriented towards the sensor), gradient ``n_k``; valid within ``max_dist`` of the cloud. It is a
first-order SDF, exact on planes, and lets the registration be checked on real depth (TUM) without
the learned map.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.semantics import estimate_normals, normals_from_organized


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices of one point per occupied voxel (the first), for (N, 3) points."""
    if voxel <= 0:
        raise ValueError(f"voxel must be > 0, got {voxel}")
    g = np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64)
    if len(g) == 0:
        return np.zeros(0, np.int64)
    g -= g.min(axis=0)
    span = g.max(axis=0) + 1
    keys = (g[:, 0] * span[1] + g[:, 1]) * span[2] + g[:, 2]  # exact while span^3 < 2^63
    _, idx = np.unique(keys, return_index=True)
    return np.sort(idx)


class PointCloudSDF:
    """Point-to-plane SDF of (N, 3) points with (N, 3) unit normals, in the points' frame."""

    def __init__(self, points: np.ndarray, normals: np.ndarray, max_dist: float = 0.1) -> None:
        P = np.asarray(points, dtype=np.float64)
        N = np.asarray(normals, dtype=np.float64)
        ok = np.isfinite(P).all(axis=1) & np.isfinite(N).all(axis=1)
        if ok.sum() < 3:
            raise ValueError("PointCloudSDF needs at least 3 points with normals")
        self.P, self.N = P[ok], N[ok] / np.linalg.norm(N[ok], axis=1, keepdims=True)
        self.max_dist = float(max_dist)
        self.tree = cKDTree(self.P)

    @classmethod
    def from_depth(
        cls,
        depth: np.ndarray,
        intr: Intrinsics,
        voxel: float = 0.02,
        max_dist: float = 0.1,
        normals: Literal["pca", "image"] = "pca",
        k: int = 12,
    ) -> PointCloudSDF:
        """From a metric depth image; coordinates = the camera frame (OpenCV).

        normals: ``"pca"`` (local PCA over ``k`` neighbours after voxel down-sampling; robust to
        the quantised depth of structured-light sensors) or ``"image"`` (central differences on
        the organised image; noisy on real depth). Normals point towards the camera.
        """
        Pc = backproject(np.asarray(depth, dtype=np.float32), intr)
        valid = (Pc[..., 2] > 0) & np.isfinite(Pc).all(axis=2)
        if normals == "image":
            Nc = normals_from_organized(Pc)
            ok = valid & np.isfinite(Nc).all(axis=2)
            P, N = Pc[ok].astype(np.float64), Nc[ok]
            keep = voxel_downsample(P, voxel)
            return cls(P[keep], N[keep], max_dist)
        P = Pc[valid].astype(np.float64)
        P = P[voxel_downsample(P, voxel)]
        N = estimate_normals(P, k)
        N *= np.where(np.sum(N * P, axis=1, keepdims=True) > 0, -1.0, 1.0)
        return cls(P, N, max_dist)

    def sdf_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, 3) points -> sdf (M,), grad (M, 3), valid (M,)."""
        x = np.asarray(points, dtype=np.float64)
        dist, k = self.tree.query(x, k=1, distance_upper_bound=self.max_dist)
        valid = np.isfinite(dist)
        k = np.where(valid, k, 0)
        n = self.N[k]
        s = np.sum(n * (x - self.P[k]), axis=1)
        return np.where(valid, s, np.nan), n, valid
