"""Voxel grids over point sets: the one home of voxel down-sampling and of the voxel point store.

- :func:`first_per_voxel`: indices of one point (the first) per occupied voxel;
- :func:`voxel_mean`: one point per occupied voxel, the mean position and attributes;
- :class:`VoxelStore`: a persistent set of points, one per voxel, that grows frame by frame.

Keys of :func:`first_per_voxel` and :func:`voxel_mean` are dense over the input's bounding box
(exact while its extent in voxels cubed stays below 2^63) and computed in the input's dtype
(pass float64 points for float64 voxel boundaries); :class:`VoxelStore` packs keys in
21 bits per axis (a +-2^20 voxel range: +-52 km at 5 cm).
"""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.bounds import column_bounds

__all__ = ["VoxelStore", "first_per_voxel", "voxel_mean"]


def _dense_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    if voxel <= 0:
        raise ValueError(f"voxel size must be > 0, got {voxel}")
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    g = np.floor(points / voxel).astype(np.int64)  # in the input's dtype
    if len(g) == 0:
        return np.zeros(0, np.int64)
    lo, hi = column_bounds(g)
    g -= lo
    span = hi - lo + 1
    return (g[:, 0] * span[1] + g[:, 1]) * span[2] + g[:, 2]


def first_per_voxel(points: np.ndarray, voxel: float, order: str = "input") -> np.ndarray:
    """Indices of the first point in each occupied voxel of (N, 3) ``points``.

    order: ``"input"`` returns them ascending (the points keep their input order); ``"key"``
    in the voxels' key order.
    """
    keys = _dense_keys(points, voxel)
    _, idx = np.unique(keys, return_index=True)
    if order == "input":
        return np.sort(idx)
    if order != "key":
        raise ValueError(f"order must be 'input' or 'key', got {order!r}")
    return idx


def voxel_mean(
    points: np.ndarray,
    voxel: float,
    colors: np.ndarray | None = None,
    labels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One point per occupied voxel: the mean position and colour, the first point's label.

    points: (N, 3). Returns (M, 3) float32 points (M <= N) and the matching attributes, voxels
    in order of their first point, so the result is deterministic.
    """
    points = np.asarray(points)
    keys = _dense_keys(points, voxel)
    if points.shape[0] == 0:
        return points.astype(np.float32), colors, labels
    _, first, inverse, counts = np.unique(
        keys, return_index=True, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")  # voxel ids in order of first occurrence
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    inv = rank[inverse]
    m = order.size
    cnt = counts[order].astype(np.float64)[:, None]

    def mean(a: np.ndarray) -> np.ndarray:
        out = np.stack([np.bincount(inv, a[:, j], minlength=m) for j in range(a.shape[1])], 1)
        return (out / cnt).astype(np.float32)

    pts = mean(points.astype(np.float64))
    cols = None if colors is None else mean(np.asarray(colors, np.float64))
    labs = None if labels is None else np.asarray(labels)[first[order]]
    return pts, cols, labs


class VoxelStore:
    """Points on a voxel grid, one per voxel, with optional (N, k) extra attributes (normals).

    keep: ``"latest"`` replaces a voxel's point by a newer one (obstacles: the world may
    change); ``"first"`` keeps the first; ``"mean"`` averages all observations of the voxel
    (points and extras: a noise-averaged surface). ``count`` holds the observations per voxel
    (``"mean"``) or ones.
    """

    KEEP = ("latest", "first", "mean")

    def __init__(self, voxel: float, keep: str = "latest", extra_dim: int = 0) -> None:
        if voxel <= 0:
            raise ValueError(f"voxel size must be > 0, got {voxel}")
        if keep not in self.KEEP:
            raise ValueError(f"keep must be one of {self.KEEP}, got {keep!r}")
        self.voxel = float(voxel)
        self.keep = keep
        self.keys = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3), np.float32)
        self.extra = np.zeros((0, extra_dim), np.float32)
        self.count = np.zeros(0, np.float32)
        self.version = 0  # increments on every change (for caches and recordings)

    def _key(self, p: np.ndarray) -> np.ndarray:
        g = np.floor(p / self.voxel).astype(np.int64) + (1 << 20)
        return (g[:, 0] << 42) | (g[:, 1] << 21) | g[:, 2]

    def add(self, p: np.ndarray, extra: np.ndarray | None = None) -> None:
        """Add (N, 3) points (and their (N, k) extras) by the store's ``keep`` rule."""
        if len(p) == 0:
            return
        p = np.asarray(p, np.float32)
        e = np.zeros((len(p), self.extra.shape[1]), np.float32) if extra is None else extra
        e = np.asarray(e, np.float32)
        if e.shape != (len(p), self.extra.shape[1]):
            raise ValueError(f"extra must be ({len(p)}, {self.extra.shape[1]}), got {e.shape}")
        kn = self._key(p)
        self.version += 1
        if self.keep == "mean":
            keys = np.concatenate([self.keys, kn])
            w = np.concatenate([self.count, np.ones(len(p), np.float32)])
            P = np.concatenate([self.points * self.count[:, None], p])
            E = np.concatenate([self.extra * self.count[:, None], e])
            self.keys, inv = np.unique(keys, return_inverse=True)
            inv = inv.reshape(-1)
            m = len(self.keys)
            self.count = np.bincount(inv, w, minlength=m).astype(np.float32)

            def mean(a: np.ndarray) -> np.ndarray:
                cols = [np.bincount(inv, a[:, j], minlength=m) for j in range(a.shape[1])]
                return (np.stack(cols, 1) / self.count[:, None]).astype(np.float32)

            self.points = mean(P)
            self.extra = mean(E) if E.shape[1] else np.zeros((m, 0), np.float32)
            return
        new = (kn, p, e)
        old = (self.keys, self.points, self.extra)
        a, b = (new, old) if self.keep == "latest" else (old, new)  # np.unique keeps the first
        keys = np.concatenate([a[0], b[0]])
        self.keys, idx = np.unique(keys, return_index=True)
        self.points = np.concatenate([a[1], b[1]])[idx]
        self.extra = np.concatenate([a[2], b[2]])[idx]
        self.count = np.ones(len(self.keys), np.float32)

    def remove(self, mask: np.ndarray) -> None:
        """Drop the points where the (N,) boolean ``mask`` is true."""
        keep = ~np.asarray(mask, bool)
        self.keys, self.points, self.extra = self.keys[keep], self.points[keep], self.extra[keep]
        self.count = self.count[keep]
        self.version += 1

    def __len__(self) -> int:
        return len(self.keys)
