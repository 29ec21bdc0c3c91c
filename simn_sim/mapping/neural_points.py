"""Neural points ``m_j = (p_j, f_j, s_j)`` in a voxel-hashed store with a k-NN spatial index.

Storage: one neural point per occupied ``voxel_size`` voxel. Voxel coordinates are packed
into 63-bit integer keys and kept sorted, so membership tests and inserts are vectorised
``searchsorted`` calls (a sorted hash table, no collisions).

Neighbour search (:mod:`simn_sim.mapping.point_index`): KD-trees on the CPU, bucket grids
elsewhere; both give the k nearest points within ``search_radius``. Queries without any
neighbour within the radius get ``idx = -1`` everywhere; callers use
:meth:`NeuralPointMap.knn`'s validity mask rather than garbage values. Training and queries
use this same neighbourhood definition (DESIGN.md section 6).
"""

from __future__ import annotations

import dataclasses
import threading

import torch

from simn_sim.mapping.config import NeuralPointsConfig
from simn_sim.mapping.point_index import BucketIndex, TreeIndex, pack_keys

# planes() updates its cache in steps (read the stale rows, recompute, publish, clear); two
# threads interleaving those steps could publish a cache missing rows, so it runs under a lock
_PLANES_LOCK = threading.Lock()


@dataclasses.dataclass
class FeaturePoints:
    """A snapshot of the map's points (numpy): positions (N, 3) float32 in map coordinates,
    features (N, D) float32, colors (N, 3) float32 in [0, 1], labels (N,) int16."""

    positions: object
    features: object
    colors: object
    labels: object


class NeuralPointMap:
    """Positions, learned features, colours and semantic labels of the neural points, plus the
    spatial index. Points are only ever added (never moved), so indices stay stable."""

    # k-NN on the CPU by KD-trees; False: the bucket grids (as on a GPU), with the fine level
    # when ``fine_grid``. All give the same neighbours (the switches are for benchmarks/tests).
    use_trees = True
    fine_grid = True

    def __init__(
        self,
        cfg: NeuralPointsConfig | None = None,
        device: str | torch.device = "cpu",
        generator: torch.Generator | None = None,
    ) -> None:
        self.cfg = cfg or NeuralPointsConfig()
        self.device = torch.device(device)
        self.generator = generator
        d = self.device
        self.positions = torch.empty((0, 3), dtype=torch.float32, device=d)
        self.features = torch.empty((0, self.cfg.feature_dim), dtype=torch.float32, device=d)
        self.colors = torch.empty((0, 3), dtype=torch.float32, device=d)
        self.labels = torch.empty((0,), dtype=torch.int16, device=d)
        # surface-plane statistics per neural point (the geometric prior of the decoder):
        # sums of the observed surface points and unit normals that fell in its voxel, and
        # how many observations carried a normal
        self.plane_sum = torch.empty((0, 3), dtype=torch.float32, device=d)
        self.normal_sum = torch.empty((0, 3), dtype=torch.float32, device=d)
        self.plane_count = torch.empty((0,), dtype=torch.float32, device=d)
        self._plane_cache: tuple[torch.Tensor, torch.Tensor] | None = None
        self._plane_stale: list[torch.Tensor] = []  # rows changed since the cache was made
        self._trees: TreeIndex | None = None
        # bumped by every change of the points' tables (positions, features, colours, planes):
        # tables gathered at one version stay valid while it holds (TrackingSdf reuses them)
        self.version = 0
        self._rebuild_index()

    # ------------------------------------------------------------------ storage
    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def voxel_keys(self, points: torch.Tensor) -> torch.Tensor:
        return pack_keys(torch.floor(points / self.cfg.voxel_size).long())

    def _rebuild_index(self) -> None:
        keys = self.voxel_keys(self.positions)
        self._vkeys, self._vorder = torch.sort(keys)
        self._coarse = self._fine = None
        if self.device.type == "cpu" and self.use_trees:
            if self._trees is None:
                self._trees = TreeIndex()
            self._trees.update(self.positions)
            return
        self._trees = None
        self._coarse = BucketIndex(self.positions, self.cfg.search_radius)
        fine = self.fine_cell
        self._fine = BucketIndex(self.positions, fine) if fine > 0 else None

    @property
    def fine_cell(self) -> float:
        """Edge (m) of the fine k-NN grid (0: none; see the module docstring)."""
        f = 2.0 * self.cfg.voxel_size
        return f if self.fine_grid and f < self.cfg.search_radius / 1.5 else 0.0

    def lookup_voxels(self, points: torch.Tensor) -> torch.Tensor:
        """(N, 3) points -> (N,) index of the neural point in the same voxel, or -1."""
        keys = self.voxel_keys(points)
        if len(self) == 0:
            return torch.full(keys.shape, -1, dtype=torch.long, device=self.device)
        pos = torch.searchsorted(self._vkeys, keys).clamp(max=len(self) - 1)
        hit = self._vkeys[pos] == keys
        return torch.where(hit, self._vorder[pos], torch.full_like(pos, -1))

    def add_points(
        self,
        points: torch.Tensor,
        colors: torch.Tensor | None = None,
        labels: torch.Tensor | None = None,
        normals: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Insert (N, 3) map-frame points; one neural point per new voxel (the first point
        falling in it). A known point whose label is 0 (unknown) takes a given non-zero label.
        ``normals`` (N, 3) unit surface normals in map coordinates (NaN or zero rows: none)
        update the surface-plane statistics of each point's voxel (:meth:`planes`), new or
        known. Returns the indices of the points created."""
        points = points.to(self.device, torch.float32)
        n = points.shape[0]
        new_ids = self._add_points(points, n, colors, labels)
        if normals is not None and n:
            self.accumulate_planes(points, normals)
        return new_ids

    def accumulate_planes(self, points: torch.Tensor, normals: torch.Tensor) -> None:
        """Add (N, 3) map-frame surface points with unit normals (N, 3) (NaN rows skipped) to
        the plane statistics of the neural points whose voxels they fall in (points in voxels
        without a neural point are ignored)."""
        points = points.to(self.device, torch.float32)
        normals = normals.to(self.device, torch.float32)
        ok = torch.isfinite(normals).all(1) & (normals.norm(dim=1) > 0.5)
        if not ok.any():
            return
        ids = self.lookup_voxels(points[ok])
        hit = ids >= 0
        ids = ids[hit]
        self.plane_sum.index_add_(0, ids, points[ok][hit])
        self.normal_sum.index_add_(0, ids, normals[ok][hit])
        self.plane_count.index_add_(0, ids, torch.ones_like(ids, dtype=torch.float32))
        if self._plane_cache is not None:
            self._plane_stale.append(ids)
        self.version += 1

    def planes(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Per neural point the mean observed surface point (N, 3) and the unit mean normal
        (N, 3) of its voxel; the normal is zero for points without any normal observation (so
        their plane term vanishes), and the mean point falls back to the point's position."""
        with _PLANES_LOCK:  # the training thread and the caller's may both ask (one at a time)
            return self._planes()

    def _planes(self) -> tuple[torch.Tensor, torch.Tensor]:
        n = len(self)
        if self._plane_cache is None:
            self._plane_cache = _plane_rows(
                self.positions, self.plane_sum, self.normal_sum, self.plane_count
            )
        elif self._plane_stale or self._plane_cache[0].shape[0] != n:
            # only the rows whose statistics changed (and new points): each row's values
            # depend on its own statistics alone, so they equal a full recomputation
            # (tests/test_mapping_prior.py); new tensors, as readers may hold the old ones
            q, nrm = self._plane_cache
            m = q.shape[0]
            ids = torch.arange(m, n, device=self.device)
            if self._plane_stale:
                ids = torch.unique(torch.cat([*self._plane_stale, ids]))
            z = torch.zeros((n - m, 3), dtype=torch.float32, device=self.device)
            q, nrm = torch.cat([q, z]), torch.cat([nrm, z])
            q[ids], nrm[ids] = _plane_rows(
                self.positions[ids],
                self.plane_sum[ids],
                self.normal_sum[ids],
                self.plane_count[ids],
            )
            self._plane_cache = (q, nrm)
        self._plane_stale = []
        return self._plane_cache

    def _add_points(
        self,
        points: torch.Tensor,
        n: int,
        colors: torch.Tensor | None,
        labels: torch.Tensor | None,
    ) -> torch.Tensor:
        if colors is None:
            colors = torch.full((n, 3), 0.5, device=self.device)
        colors = colors.to(self.device, torch.float32)
        if labels is not None:
            labels = labels.to(self.device, torch.int16)
            known = self.lookup_voxels(points)
            upd = (known >= 0) & (labels != 0)
            if upd.any():
                ki = known[upd]
                cur = self.labels[ki]
                self.labels[ki] = torch.where(cur == 0, labels[upd], cur)
        keys = self.voxel_keys(points)
        new = self.lookup_voxels(points) < 0
        keys_new = keys[new]
        if keys_new.numel() == 0:
            return torch.empty((0,), dtype=torch.long, device=self.device)
        # first occurrence of each new voxel
        uk, inv = torch.unique(keys_new, return_inverse=True)
        first = torch.full((uk.numel(),), keys_new.numel(), dtype=torch.long, device=self.device)
        first.scatter_reduce_(0, inv, torch.arange(keys_new.numel(), device=self.device), "amin")
        first = torch.sort(first).values
        src = torch.nonzero(new).squeeze(1)[first]
        m = src.numel()
        start = len(self)
        feats = (
            torch.randn((m, self.cfg.feature_dim), generator=self.generator, device=self.device)
            * self.cfg.feature_init_std
        )
        self.positions = torch.cat([self.positions, points[src]])
        self.features = torch.cat([self.features, feats])
        self.colors = torch.cat([self.colors, colors[src]])
        lab = (
            labels[src]
            if labels is not None
            else torch.zeros(m, dtype=torch.int16, device=self.device)
        )
        self.labels = torch.cat([self.labels, lab])
        z3 = torch.zeros((m, 3), dtype=torch.float32, device=self.device)
        self.plane_sum = torch.cat([self.plane_sum, z3])
        self.normal_sum = torch.cat([self.normal_sum, z3])
        self.plane_count = torch.cat([self.plane_count, z3[:, 0]])
        self.version += 1  # planes() adds the new rows to its cache
        self._rebuild_index()
        return torch.arange(start, start + m, device=self.device)

    def set_state(
        self,
        positions: torch.Tensor,
        features: torch.Tensor,
        colors: torch.Tensor,
        labels: torch.Tensor,
        planes: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None,
    ) -> None:
        """Replace all points (used by map loading); ``planes``: the surface-plane sums
        (plane_sum (N, 3), normal_sum (N, 3), plane_count (N,)), zeros when None."""
        n = positions.shape[0]
        if not (
            positions.shape == (n, 3)
            and features.shape == (n, self.cfg.feature_dim)
            and colors.shape == (n, 3)
            and labels.shape == (n,)
        ):
            raise ValueError("inconsistent neural-point arrays")
        self.positions = positions.to(self.device, torch.float32).contiguous()
        self.features = features.to(self.device, torch.float32).contiguous()
        self.colors = colors.to(self.device, torch.float32).contiguous()
        self.labels = labels.to(self.device, torch.int16).contiguous()
        if planes is None:
            z = torch.zeros((n, 3), dtype=torch.float32)
            planes = (z, z.clone(), z[:, 0].clone())
        ps, ns, pc = (t.to(self.device, torch.float32).contiguous() for t in planes)
        if ps.shape != (n, 3) or ns.shape != (n, 3) or pc.shape != (n,):
            raise ValueError("inconsistent surface-plane arrays")
        self.plane_sum, self.normal_sum, self.plane_count = ps, ns, pc
        self._plane_cache, self._plane_stale = None, []
        self.version += 1
        self._rebuild_index()

    def snapshot(self) -> FeaturePoints:
        return FeaturePoints(
            self.positions.cpu().numpy().copy(),
            self.features.cpu().numpy().copy(),
            self.colors.cpu().numpy().copy(),
            self.labels.cpu().numpy().copy(),
        )

    def nbytes(self) -> int:
        ts = [self.positions, self.features, self.colors, self.labels, self._vkeys, self._vorder]
        ts += [self.plane_sum, self.normal_sum, self.plane_count]
        n = int(sum(t.numel() * t.element_size() for t in ts))
        n += sum(b.nbytes() for b in (self._coarse, self._fine) if b is not None)
        return n + (self._trees.nbytes() if self._trees is not None else 0)

    # ------------------------------------------------------------------ search
    @torch.no_grad()
    def knn(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """k nearest neural points of each query within ``search_radius``.

        x: (Q, 3) float32 map-frame queries. Returns idx (Q, k) int64 (-1 where fewer than k
        neighbours exist) and squared distances (Q, k) (inf where idx is -1), nearest first.
        """
        k, r = self.cfg.k_neighbors, self.cfg.search_radius
        q = x.shape[0]
        idx_out = torch.full((q, k), -1, dtype=torch.long, device=self.device)
        d2_out = torch.full((q, k), float("inf"), device=self.device)
        if len(self) == 0 or q == 0:
            return idx_out, d2_out
        x = x.to(self.device, torch.float32)
        if self._trees is not None:
            return self._trees.knn(x, self.positions, k, r)
        step = self.cfg.query_chunk
        if self._fine is None:
            self._coarse.knn(x, k, r, idx_out, d2_out, step)
            return idx_out, d2_out
        self._fine.knn(x, k, r, idx_out, d2_out, step)
        # exact where the k-th neighbour found lies within the fine edge; else the coarse grid
        rest = torch.nonzero(~(d2_out[:, -1] <= self._fine.cell**2)).squeeze(1)
        if rest.numel():
            i2 = torch.full((rest.numel(), k), -1, dtype=torch.long, device=self.device)
            d2 = torch.full((rest.numel(), k), float("inf"), device=self.device)
            self._coarse.knn(x[rest], k, r, i2, d2, step)
            idx_out[rest], d2_out[rest] = i2, d2
        return idx_out, d2_out

    # ------------------------------------------------------------------ interpolation
    def interpolate(
        self, x: torch.Tensor, idx: torch.Tensor, features: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """IDW-interpolated features (Q, D), colours (Q, 3) and neighbour centroid (Q, 3) at
        ``x`` from neighbours ``idx`` (global indices, -1 = none). ``features`` overrides the
        stored feature table."""
        ic = idx.clamp(min=0)
        f = features if features is not None else self.features
        return idw_interpolate(
            x, self.positions[ic], idx >= 0, f[ic], self.colors[ic], self.cfg.idw_power
        )


def _plane_rows(
    positions: torch.Tensor, plane_sum: torch.Tensor, normal_sum: torch.Tensor, count: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`NeuralPointMap.planes` of the given rows: the mean surface point (the position
    where nothing was observed) and the unit mean normal (zero where none)."""
    c = count.clamp(min=1.0)[:, None]
    has = (count > 0)[:, None]
    q = torch.where(has, plane_sum / c, positions)
    nn_ = normal_sum.norm(dim=1, keepdim=True)
    nrm = torch.where(has & (nn_ > 1e-6), normal_sum / nn_.clamp(min=1e-6), 0.0)
    return q.contiguous(), nrm.contiguous()


def idw_interpolate(
    x: torch.Tensor,
    nb_pos: torch.Tensor,
    nb_valid: torch.Tensor,
    nb_feat: torch.Tensor,
    nb_col: torch.Tensor,
    power: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inverse-distance interpolation, differentiable in ``x`` and the features.

    x (Q, 3); neighbour positions (Q, k, 3), validity (Q, k), features (Q, k, D), colours
    (Q, k, 3). ``w_k = 1 / ||p_k - x||^power`` normalised over the valid neighbours (distances
    clamped at 1 mm); rows without any valid neighbour give zeros. Returns the interpolated
    features (Q, D), colours (Q, 3) and the weighted neighbour centroid (Q, 3).
    """
    w = idw_weights(x, nb_pos, nb_valid, power)
    feat = (w[..., None] * nb_feat).sum(1)
    col = (w[..., None] * nb_col).sum(1)
    centroid = (w[..., None] * nb_pos).sum(1)
    return feat, col, centroid


def idw_weights(
    x: torch.Tensor, nb_pos: torch.Tensor, nb_valid: torch.Tensor, power: float
) -> torch.Tensor:
    """Normalised inverse-distance weights (Q, k) of the neighbours (Q, k, 3) of ``x`` (Q, 3):
    ``1 / max(||p_k - x||, 1 mm)^power`` over the valid ones; rows without any valid
    neighbour are zero. Differentiable in ``x``."""
    d = torch.sqrt(((x[:, None, :] - nb_pos) ** 2).sum(-1) + 1e-12).clamp(min=1e-3)
    w = d.pow(-power) * nb_valid
    return w / w.sum(1, keepdim=True).clamp(min=1e-12)


def gaussian_weights(
    x: torch.Tensor, nb_pos: torch.Tensor, nb_valid: torch.Tensor, width: float
) -> torch.Tensor:
    """Normalised Gaussian weights (Q, k), ``exp(-||p_k - x||^2 / (2 width^2))`` over the
    valid neighbours (Q, k, 3) of ``x`` (Q, 3); rows without any valid neighbour are zero.
    Computed relative to the nearest valid neighbour, so far queries do not underflow."""
    d2 = ((x[:, None, :] - nb_pos) ** 2).sum(-1)
    d2 = torch.where(nb_valid, d2, torch.full_like(d2, float("inf")))
    d2min = d2.min(1, keepdim=True).values.detach()
    d2min = torch.where(torch.isfinite(d2min), d2min, torch.zeros_like(d2min))
    w = torch.exp(-(d2 - d2min) / (2.0 * width * width)) * nb_valid
    return w / w.sum(1, keepdim=True).clamp(min=1e-12)
