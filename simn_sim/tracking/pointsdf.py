"""A point-to-plane implicit surface from a point cloud: the simplest ``sdf_and_grad`` for real data.

Nearest point (``kernel=0``): ``sdf(x) = n_k . (x - p_k)`` with ``p_k`` the nearest surface point
and ``n_k`` its normal (oriented towards the sensor), gradient ``n_k``; valid within ``max_dist``
of the cloud. It is a first-order SDF, exact on planes, and lets the registration be checked on
real depth (TUM) without the learned map.

Kernel (``kernel=h > 0``): the implicit moving-least-squares surface of Kolluri (2008) as used by
IMLS-SLAM (Deschaud 2018): ``sdf(x) = sum_i w_i n_i . (x - p_i) / sum_i w_i`` over the ``k``
nearest points within ``max_dist``, ``w_i = c_i exp(-|x - p_i|^2 / h^2)`` (``c_i`` optional
per-point confidences, e.g. observation counts); gradient ``sum_i w_i n_i / sum_i w_i`` (not
normalised: where the neighbours' normals disagree, at creases, its norm drops and the
registration's gradient-norm check drops the point). Unlike the nearest-point SDF it is continuous
in ``x``, and it averages the positions of ``k`` noisy surface samples: on a cloud spread
``+-sigma`` about the surface by depth noise the nearest point is the one the noise moved towards
``x``, so the nearest-point SDF is flat within the spread (registration stalls there, see
docs/tracking.md), while the kernel average keeps a slope ``h^2 / (h^2 + sigma^2)`` with its zero
on the surface.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.voxel import first_per_voxel as voxel_downsample
from simn_sim.semantics import estimate_normals, normals_from_organized

__all__ = ["PointCloudSDF", "voxel_downsample"]  # voxel_downsample: first_per_voxel, re-exported


class PointCloudSDF:
    """Point-to-plane SDF of (N, 3) points with (N, 3) normals, in the points' frame.

    kernel: 0 for the nearest point's plane, else the Gaussian kernel width ``h`` (m) of the
    implicit MLS surface over the ``k`` nearest points (module docstring). confidence: optional
    (N,) weights >= 0 of the points in the kernel average (ignored with ``kernel=0``).
    normal_gate: with a kernel, only neighbours whose normal has a cosine >= this with the
    nearest point's normal take part (-1: all), so creases stay sharp.
    """

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        max_dist: float = 0.1,
        kernel: float = 0.0,
        k: int = 8,
        confidence: np.ndarray | None = None,
        normal_gate: float = -1.0,
    ) -> None:
        P = np.asarray(points, dtype=np.float64)
        N = np.asarray(normals, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or N.shape != P.shape:
            raise ValueError(f"points and normals must be (N, 3), got {P.shape} and {N.shape}")
        if not (np.isfinite(kernel) and kernel >= 0):
            raise ValueError(f"kernel must be >= 0, got {kernel}")
        if int(k) < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        nn = np.linalg.norm(N, axis=1)
        ok = np.isfinite(P).all(axis=1) & np.isfinite(N).all(axis=1) & (nn > 0)
        C = None
        if confidence is not None:
            C = np.asarray(confidence, dtype=np.float64).reshape(-1)
            if C.shape != (len(P),):
                raise ValueError(f"confidence must have shape ({len(P)},), got {C.shape}")
            if not np.isfinite(C).all() or (C < 0).any():
                raise ValueError("confidence must be finite and >= 0")
            ok &= C > 0
        if ok.sum() < 3:
            raise ValueError("PointCloudSDF needs at least 3 points with normals")
        self.P, self.N = P[ok], N[ok] / nn[ok, None]
        self.C = None if C is None else C[ok]
        self.max_dist = float(max_dist)
        self.kernel = float(kernel)
        self.k = int(min(k, len(self.P)))
        self.normal_gate = float(normal_gate)
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
        N = estimate_normals(P, k, towards_origin=True)
        return cls(P, N, max_dist)

    def sdf_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, 3) points -> sdf (M,), grad (M, 3), valid (M,)."""
        x = np.asarray(points, dtype=np.float64)
        if self.kernel > 0:
            return self._kernel_sdf(x)
        dist, k = self.tree.query(x, k=1, distance_upper_bound=self.max_dist)
        valid = np.isfinite(dist)
        k = np.where(valid, k, 0)
        n = self.N[k]
        s = np.sum(n * (x - self.P[k]), axis=1)
        return np.where(valid, s, np.nan), n, valid

    def _kernel_sdf(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dist, nb = self.tree.query(x, k=self.k, distance_upper_bound=self.max_dist)
        dist, nb = dist.reshape(len(x), -1), nb.reshape(len(x), -1)
        found = np.isfinite(dist)
        nb = np.where(found, nb, 0)
        n = self.N[nb]  # (M, k, 3)
        if self.normal_gate > -1:
            # only the nearest point's side of a crease: neighbours whose normal differs from
            # the nearest one's (the floor below a wall point) would round the corner off
            found &= np.einsum("mkj,mj->mk", n, n[:, 0]) >= self.normal_gate
        w = np.exp(-((np.where(found, dist, 0.0) / self.kernel) ** 2)) * found
        if self.C is not None:
            w = w * self.C[nb]
        sw = w.sum(axis=1)
        valid = sw > 1e-12
        sw = np.where(valid, sw, 1.0)
        s = (w * np.einsum("mkj,mkj->mk", n, x[:, None, :] - self.P[nb])).sum(axis=1) / sw
        g = np.einsum("mk,mkj->mj", w, n) / sw[:, None]
        return np.where(valid, s, np.nan), g, valid
