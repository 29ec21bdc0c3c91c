"""Frame descriptors for place recognition in the topological map
(:mod:`simn_sim.tracking.topomap`; the descriptor's three parts are described there):
:class:`DescriptorConfig`, :class:`FrameDescriptor`, :func:`describe` and :func:`similarity`."""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.config import Config, require

__all__ = ["DescriptorConfig", "FrameDescriptor", "describe", "similarity"]


@dataclasses.dataclass(frozen=True)
class DescriptorConfig(Config):
    occupancy_cell: float = 1.0  # m, world x/y grid of the occupancy signature
    height_range: tuple[float, float] = (-0.5, 3.0)  # world z covered by the height histogram
    height_bins: int = 16
    radius_max: float = 5.0  # horizontal distance covered by the radial histogram
    radius_bins: int = 16
    occupancy_weight: float = 1.0
    shape_weight: float = 0.5
    feature_weight: float = 0.5
    # a frame with more key points is described by an even stride subsample of at most this
    # many (its region always uses all of them); 0: all. Descriptors are recomputed for every
    # frame whose anchor the pose graph moves, and a 1 m occupancy grid needs few points.
    max_points: int = 0

    def validate(self) -> None:
        n = type(self).__name__
        require(self.occupancy_cell > 0, n, "occupancy_cell", "must be > 0")
        require(self.max_points >= 0, n, "max_points", "must be >= 0 (0: all points)")
        require(self.height_range[1] > self.height_range[0], n, "height_range", "must increase")
        require(self.height_bins >= 2 and self.radius_bins >= 2, n, "height_bins", "need >= 2 bins")
        require(self.radius_max > 0, n, "radius_max", "must be > 0")
        for f in ("occupancy_weight", "shape_weight", "feature_weight"):
            require(getattr(self, f) >= 0, n, f, "must be >= 0")
        require(
            self.occupancy_weight + self.shape_weight > 0,
            n,
            "occupancy_weight",
            "occupancy_weight + shape_weight must be > 0",
        )


@dataclasses.dataclass(frozen=True)
class FrameDescriptor:
    """occupancy: (cells (M,) int64 packed grid keys, weights (M,) unit norm);
    shape: (height_bins + radius_bins,) unit vector; feature: (2 d,) unit vector or None."""

    cells: np.ndarray
    weights: np.ndarray
    shape: np.ndarray
    feature: np.ndarray | None = None


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


_OFF = 1 << 20


def _occupancy(xy: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    g = xy / cell - 0.5  # cell centres at (i + 0.5) * cell
    i0 = np.floor(g).astype(np.int64)
    f = g - i0
    keys, vals = [], []
    for dx in (0, 1):
        for dy in (0, 1):
            w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
            keys.append((i0[:, 0] + dx + _OFF) * (2 * _OFF) + (i0[:, 1] + dy + _OFF))
            vals.append(w)
    k, inv = np.unique(np.concatenate(keys), return_inverse=True)
    v = np.bincount(inv, weights=np.concatenate(vals), minlength=len(k))
    return k, _unit(v)


def describe(
    points_world: np.ndarray,
    features: np.ndarray | None = None,
    cfg: DescriptorConfig | None = None,
) -> FrameDescriptor:
    """Descriptor of (N, 3) world-frame key points and optional (N, d) features."""
    cfg = cfg or DescriptorConfig()
    P = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    if len(P) == 0:
        raise ValueError("cannot describe an empty point set")
    if not np.isfinite(P).all():
        raise ValueError("points_world contains NaN or inf")
    cells, weights = _occupancy(P[:, :2], cfg.occupancy_cell)
    zh, _ = np.histogram(P[:, 2], bins=cfg.height_bins, range=cfg.height_range)
    r = np.linalg.norm(P[:, :2] - P[:, :2].mean(axis=0), axis=1)
    rh, _ = np.histogram(
        np.minimum(r, cfg.radius_max - 1e-9), bins=cfg.radius_bins, range=(0, cfg.radius_max)
    )
    shape = np.concatenate([np.sqrt(zh / max(zh.sum(), 1)), np.sqrt(rh / max(rh.sum(), 1))])
    feat = None
    if features is not None and np.asarray(features).size:
        F = np.asarray(features, dtype=np.float64).reshape(len(P), -1)
        v = np.concatenate([F.mean(axis=0), F.std(axis=0)])
        feat = _unit(v - v.mean()) if v.std() > 0 else None
    return FrameDescriptor(cells, weights, _unit(shape), feat)


def similarity(
    a: FrameDescriptor, b: FrameDescriptor, cfg: DescriptorConfig | None = None
) -> float:
    """Weighted mean of the cosine similarities of the parts present in both descriptors."""
    cfg = cfg or DescriptorConfig()
    _, ia, ib = np.intersect1d(a.cells, b.cells, assume_unique=True, return_indices=True)
    occ = float(a.weights[ia] @ b.weights[ib])
    s = cfg.occupancy_weight * occ + cfg.shape_weight * float(a.shape @ b.shape)
    w = cfg.occupancy_weight + cfg.shape_weight
    if (
        cfg.feature_weight > 0
        and a.feature is not None
        and b.feature is not None
        and a.feature.shape == b.feature.shape
    ):
        s += cfg.feature_weight * float(a.feature @ b.feature)
        w += cfg.feature_weight
    return s / w
