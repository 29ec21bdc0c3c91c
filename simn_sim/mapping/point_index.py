"""The k-NN spatial indices of the neural points (:class:`~simn_sim.mapping.neural_points.NeuralPointMap`)
and the voxel key packing they share.

Bucket grids (:class:`BucketIndex`): the points are bucketed into cells of edge
``search_radius``; the k nearest points of a query within the radius are among the 27 cells
around the query's cell, which are gathered into a padded candidate matrix and reduced with
``topk``. No linear scan. Two levels: the search first looks in the 27 cells of a fine grid
(edge ``2 voxel_size``, when that is below ``search_radius / 1.5``); a query whose k-th
neighbour found there lies within the fine edge has its exact answer (every point that near
is in those cells), and only the others (fewer than k points that near: off the surface) are
searched on the coarse grid.

On the CPU the same k nearest within the radius come from KD-trees (:class:`TreeIndex`, 3-5x
faster than the grid on this CPU, docs/tracking.md "Tracking on the learned map"): a static
``scipy.spatial.cKDTree`` over most points plus a small one over the points added since it was
built (rebuilt when they exceed a quarter of it), merged per query.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

__all__ = ["BucketIndex", "TreeIndex", "pack_keys", "unpack_keys"]

_BITS = 21
_OFF = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1


def pack_keys(ijk: torch.Tensor) -> torch.Tensor:
    """(..., 3) int64 voxel coordinates (|c| < 2**20) -> (...) int64 keys."""
    c = ijk + _OFF
    return (c[..., 0] << (2 * _BITS)) | (c[..., 1] << _BITS) | c[..., 2]


def unpack_keys(keys: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`pack_keys`."""
    return (
        torch.stack([(keys >> (2 * _BITS)) & _MASK, (keys >> _BITS) & _MASK, keys & _MASK], -1)
        - _OFF
    )


def _offsets27(device: torch.device) -> torch.Tensor:
    r = torch.arange(-1, 2, device=device)
    return torch.stack(torch.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)


class TreeIndex:
    """Log-structured KD-tree index of the (append-only) points: a static ``cKDTree`` over the
    first ``n_static`` points and a small one over the rest, rebuilt when the rest exceeds a
    quarter of the static part. Queries take the k nearest within the radius from both."""

    def __init__(self) -> None:
        self.n_static = 0
        self.static: cKDTree | None = None
        self.tail: cKDTree | None = None
        self.n = 0
        self.rebuilds = 0

    def update(self, positions: torch.Tensor) -> None:
        n = positions.shape[0]
        with _no_denormal_flush():  # cKDTree misbehaves with flushed denormals (results.py)
            if n < self.n or n - self.n_static > max(4096, self.n_static // 4):
                p = positions.detach().cpu().numpy().astype(np.float64)
                self.static = cKDTree(p) if n else None
                self.n_static = n
                self.rebuilds += 1
            tail = positions[self.n_static :].detach().cpu().numpy().astype(np.float64)
            self.tail = cKDTree(tail) if len(tail) else None
        self.n = n

    def nbytes(self) -> int:
        return 48 * self.n  # the trees' data (float64) and index arrays, about

    def knn(
        self, x: torch.Tensor, positions: torch.Tensor, k: int, r: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        xn = x.detach().cpu().numpy().astype(np.float64)
        parts = []
        with _no_denormal_flush():
            for tree, off in ((self.static, 0), (self.tail, self.n_static)):
                if tree is None:
                    continue
                kk = min(k, tree.n)
                _, i = tree.query(xn, kk, distance_upper_bound=r)
                i = np.asarray(i, np.int64).reshape(len(xn), kk)
                parts.append(np.where(i < tree.n, i + off, -1))
        idx = torch.from_numpy(np.concatenate(parts, 1) if len(parts) > 1 else parts[0])
        # squared distances as the grid computes them (float32), inf where none
        d2 = ((positions[idx.clamp(min=0)] - x[:, None, :]) ** 2).sum(-1)
        d2 = torch.where((idx >= 0) & (d2 <= r * r), d2, torch.full_like(d2, float("inf")))
        if idx.shape[1] != k or len(parts) > 1:
            kk = min(k, idx.shape[1])
            d2, arg = torch.topk(d2, kk, dim=1, largest=False, sorted=True)
            idx = idx.gather(1, arg)
        idx = torch.where(torch.isfinite(d2), idx, torch.full_like(idx, -1))
        if idx.shape[1] < k:
            pad = k - idx.shape[1]
            idx = torch.cat([idx, torch.full((len(idx), pad), -1, dtype=torch.long)], 1)
            d2 = torch.cat([d2, torch.full((len(d2), pad), float("inf"))], 1)
        return idx, d2


def _denormals_flushed() -> bool:
    """Whether this thread flushes denormal floats (torch.set_flush_denormal)."""
    return bool(torch.tensor([1e-39], dtype=torch.float32).mul(1.0)[0] == 0)


class _no_denormal_flush:
    """Keep denormals while inside (restoring a flush set by the caller, e.g. training)."""

    def __enter__(self):
        self.was = _denormals_flushed()
        if self.was:
            torch.set_flush_denormal(False)

    def __exit__(self, *exc):
        if self.was:
            torch.set_flush_denormal(True)


class BucketIndex:
    """Points bucketed in cubic cells of edge ``cell`` (sorted packed keys): the candidates of
    a query are the points of the 27 cells around its cell, so every point within ``cell`` of
    it is among them."""

    def __init__(self, positions: torch.Tensor, cell: float) -> None:
        self.cell = float(cell)
        dev = positions.device
        self.off27 = _offsets27(dev)
        bkeys = pack_keys(torch.floor(positions / self.cell).long())
        sorted_b, perm = torch.sort(bkeys, stable=True)
        self.perm = perm
        self.pos = positions[perm].contiguous()
        self.keys, counts = torch.unique_consecutive(sorted_b, return_counts=True)
        self.count = counts
        self.start = torch.cumsum(counts, 0) - counts

    def nbytes(self) -> int:
        ts = (self.perm, self.pos, self.keys, self.count, self.start)
        return int(sum(t.numel() * t.element_size() for t in ts))

    def knn(
        self,
        x: torch.Tensor,
        k: int,
        r: float,
        idx_out: torch.Tensor,
        d2_out: torch.Tensor,
        step: int,
    ) -> None:
        """Write the k nearest candidates within ``r`` of each query (nearest first; -1 / inf
        where fewer) into ``idx_out`` / ``d2_out`` (Q, k)."""
        budget = 64 * step  # candidate slots per chunk (bounds memory)
        q = x.shape[0]
        for s in range(0, q, step):
            xs = x[s : s + step]
            start, cnt = self._buckets(xs)
            total = cnt.sum(1)
            live = torch.nonzero(total > 0).squeeze(1)
            if live.numel() == 0:
                continue
            # group queries with similar candidate counts so the padded matrix stays tight
            order = live[torch.argsort(total[live])]
            tot = total[order]
            i0 = 0
            while i0 < order.numel():
                c_max = int(tot[min(i0 + step, order.numel()) - 1])
                i1 = min(order.numel(), i0 + max(1, budget // max(c_max, 1)), i0 + step)
                c = int(tot[i1 - 1])
                sel = order[i0:i1]
                i, d = self._candidates(xs[sel], start[sel], cnt[sel], c, k, r)
                idx_out[s + sel], d2_out[s + sel] = i, d
                i0 = i1

    def _buckets(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Start (in bucket order) and size of the 27 buckets around each query, (Q, 27)."""
        cell = torch.floor(x / self.cell).long()
        keys = pack_keys(cell[:, None, :] + self.off27[None]).contiguous()  # (Q, 27)
        pos = torch.searchsorted(self.keys, keys).clamp(max=self.keys.numel() - 1)
        found = self.keys[pos] == keys
        cnt = torch.where(found, self.count[pos], torch.zeros_like(pos))
        return self.start[pos], cnt

    def _candidates(
        self, x: torch.Tensor, start: torch.Tensor, cnt: torch.Tensor, c: int, k: int, r: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Top-k over the (Q, c) padded candidates of the 27 buckets of each query."""
        q = x.shape[0]
        dev = x.device
        cum = torch.cumsum(cnt, 1)
        total = cum[:, -1:]
        j = torch.arange(c, device=dev).expand(q, c).contiguous()
        b = torch.searchsorted(cum, j, right=True).clamp(max=26)  # bucket of each slot
        slot = (start - cum + cnt).gather(1, b) + j
        ok = j < total
        slot = torch.where(ok, slot, torch.zeros_like(slot))
        d2 = ((self.pos[slot] - x[:, None, :]) ** 2).sum(-1)  # positions in bucket order
        d2 = torch.where(ok & (d2 <= r * r), d2, torch.full_like(d2, float("inf")))
        kk = min(k, c)
        d2k, arg = torch.topk(d2, kk, dim=1, largest=False)
        idk = self.perm[slot.gather(1, arg)]
        idk = torch.where(torch.isfinite(d2k), idk, torch.full_like(idk, -1))
        if kk < k:
            pad = k - kk
            idk = torch.cat([idk, torch.full((q, pad), -1, dtype=torch.long, device=dev)], 1)
            d2k = torch.cat([d2k, torch.full((q, pad), float("inf"), device=dev)], 1)
        return idk, d2k
