"""Frame descriptors for place recognition in the topological map
(:mod:`simn_sim.tracking.topomap`; the descriptor's three parts are described there):
:class:`DescriptorConfig`, :class:`FrameDescriptor`, :func:`describe` and :func:`similarity`.

:class:`KeyPointIndex` ranks revisit candidates by their learned key points instead
(``SlamConfig.revisit_features``): each of the query's key points is matched to the ``match_k``
nearest key points of a candidate frame within ``match_radius`` (the drift the check expects),
and the score is the mean over the query's points of the best cosine similarity of their
learned feature vectors (each frame's features standardised per dimension; 0 for a point
without a key point in reach). Without features it is the share of query points in reach.
The per-frame mean / standard deviation pooled by :func:`describe` loses what the features say
about a place: on the rendered loops, features at corresponding key points of two frames agree
(cosine 0.3-0.8) while the frames' feature statistics do not separate places (docs/slam.md,
"Revisit candidates").
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.config import Config, require

__all__ = [
    "DescriptorConfig",
    "FrameDescriptor",
    "KeyPointIndex",
    "describe",
    "similarity",
    "standardized_features",
]


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
    # key-point matching (KeyPointIndex): reach of a query key point in the candidate frame
    # (drift the check expects), neighbours compared, query key points used (even stride)
    match_radius: float = 0.15
    match_k: int = 6
    match_points: int = 500

    def validate(self) -> None:
        n = type(self).__name__
        require(self.occupancy_cell > 0, n, "occupancy_cell", "must be > 0")
        require(self.match_radius > 0, n, "match_radius", "must be > 0")
        require(self.match_k >= 1, n, "match_k", "must be >= 1")
        require(self.match_points >= 1, n, "match_points", "must be >= 1")
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


def standardized_features(features: np.ndarray) -> np.ndarray:
    """(N, d) features standardised per dimension (over the N points) and scaled to unit norm
    per point; (N, 0) in, (N, 0) out."""
    F = np.asarray(features, dtype=np.float64)
    if F.ndim != 2 or F.shape[1] == 0 or len(F) == 0:
        return np.zeros((len(F), 0), np.float32)
    Z = (F - F.mean(axis=0)) / (F.std(axis=0) + 1e-9)
    return (Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1e-12)).astype(np.float32)


class KeyPointIndex:
    """A frame's key points (its own coordinates) and standardised learned features, with a
    k-d tree, for :meth:`match` (see the module docstring)."""

    def __init__(self, points: np.ndarray, features: np.ndarray | None = None) -> None:
        from scipy.spatial import cKDTree

        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(P) == 0:
            raise ValueError("a key-point index needs points")
        self.tree = cKDTree(P)
        self.n = len(P)
        self.features = standardized_features(
            np.zeros((len(P), 0)) if features is None else features
        )

    @property
    def has_features(self) -> bool:
        return self.features.shape[1] > 0

    def match(
        self,
        points: np.ndarray,
        features: np.ndarray | None,
        cfg: DescriptorConfig | None = None,
    ) -> tuple[float, float]:
        """Query key points (N, 3) in this frame's coordinates with their standardised features
        (N, d) (:func:`standardized_features`; None: geometry only). Returns (score, reach):
        reach is the share of query points with a key point within ``match_radius``; score is
        the mean best feature cosine (clipped at 0, 0 out of reach), or reach without
        features on either side."""
        cfg = cfg or DescriptorConfig()
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(P) == 0:
            return 0.0, 0.0
        k = min(cfg.match_k, self.n)
        d, j = self.tree.query(P, k, distance_upper_bound=cfg.match_radius)
        d, j = d.reshape(len(P), k), j.reshape(len(P), k)
        ok = np.isfinite(d)
        reach = float(ok[:, 0].mean())
        use = (
            features is not None
            and self.has_features
            and features.shape[1] == self.features.shape[1]
        )
        if not use:
            return reach, reach
        Fn = self.features[np.where(ok, j, 0)]  # (N, k, d)
        cos = np.where(ok, np.einsum("nkd,nd->nk", Fn, features), -1.0)
        best = np.where(ok[:, 0], np.maximum(cos.max(axis=1), 0.0), 0.0)
        return float(best.mean()), reach
