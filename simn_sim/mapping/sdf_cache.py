"""F_theta baked into a sparse grid near the surface, for the LM iterations of tracking.

Registration evaluates the learned SDF of a few thousand points 5-10 times per frame, and
each evaluation of the network needs a k-NN search, the neighbours' tables and the MLP with
its gradient (docs/tracking.md, "Tracking on the learned map"). :class:`SdfCache` instead
keeps the SDF value and gradient of the map at the vertices of a grid of edge ``cell``
(sparse: only the vertices that queries touched), evaluated by the network once, and answers
a query from the 8 vertices of its cell:

``sdf(x) = sum_v w_v(x) (s_v + g_v . (x - v))``,

the trilinear blend of the vertices' first-order Taylor expansions (exact on a plane, so on
the geometric prior's planes, for any cell; continuous everywhere), with the exact gradient
of that interpolant. A query is valid where all 8 vertices are (the network's validity at a
vertex: a neural point within the search radius and, with ``max_distance``, within that
distance along the surface; see :class:`~simn_sim.mapping.tracking_sdf.TrackingSdf`).

Freshness: a vertex is re-baked when :meth:`prepare` (called once per registration, with the
points at the predicted pose) finds it baked at an older version of the map (trained since,
or neural points / plane observations added since); during the LM iterations
(:meth:`sdf_and_grad`) only missing vertices are baked, so the function LM minimises does not
change under it. Measured (docs/tracking.md, "Tracking on the learned map"): keeping vertices
of older versions across frames (re-baking only those near new neural points, and the rest
within a budget per frame) made LM stop at its first step on the noisy desk, so the cache is
exact at its vertices for the map of the frame being tracked, and its reuse is within a frame.

Everything is a function of the inputs and the call order: same inputs, same values.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from simn_sim.mapping.tracking_sdf import TrackingSdf

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap

__all__ = ["SdfCache"]

_BITS = 21
_OFF = 1 << (_BITS - 1)
# the 8 corners of a cell, (8, 3) in {0, 1}
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.int64)


def _pack(ijk: np.ndarray) -> np.ndarray:
    c = ijk + _OFF
    return (c[..., 0] << (2 * _BITS)) | (c[..., 1] << _BITS) | c[..., 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    m = (1 << _BITS) - 1
    return np.stack([(keys >> (2 * _BITS)) & m, (keys >> _BITS) & m, keys & m], -1) - _OFF


class SdfCache:
    """Sparse grid cache of an :class:`ImplicitMap`'s SDF and gradient (module docstring).

    cell: grid edge (m). max_distance: validity along the surface at a vertex (as
    :class:`TrackingSdf`), None: the map's own (search radius). Counters: ``baked`` (vertex evaluations of the network), ``queries`` (points
    answered), ``calls``.
    """

    def __init__(
        self,
        imap: ImplicitMap,
        cell: float = 0.02,
        max_distance: float | None = None,
    ) -> None:
        if not cell > 0:
            raise ValueError(f"cell must be > 0, got {cell}")
        self.map = imap
        self.cell = float(cell)
        self._exact = TrackingSdf(imap, 0.0, max_distance)
        self.keys = np.empty(0, np.int64)  # sorted
        self.vals = np.empty((0, 4), np.float64)  # sdf, gradient
        self.ok = np.empty(0, bool)
        self.version = np.empty(0, np.int64)  # the map's version when baked
        self.baked = 0
        self.queries = 0
        self.calls = 0

    def __len__(self) -> int:
        return int(self.keys.size)

    # ---- baking --------------------------------------------------------------------------------
    def _lookup(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions of ``keys`` in the table and whether they are there."""
        if self.keys.size == 0:
            return np.zeros(keys.shape, np.int64), np.zeros(keys.shape, bool)
        pos = np.searchsorted(self.keys, keys).clip(max=self.keys.size - 1)
        return pos, self.keys[pos] == keys

    def _bake(self, keys: np.ndarray) -> None:
        """Evaluate the network at the vertices ``keys`` (unique) and store them."""
        if keys.size == 0:
            return
        v = (_unpack(keys) * self.cell).astype(np.float32)
        s, g = self._exact.sdf_and_grad(torch.from_numpy(v))
        s = s.detach().cpu().numpy().astype(np.float64)
        g = g.detach().cpu().numpy().astype(np.float64)
        ok = np.isfinite(s) & np.isfinite(g).all(1)
        vals = np.concatenate([np.where(ok, s, 0.0)[:, None], np.where(ok[:, None], g, 0.0)], 1)
        ver = self._version()
        self.baked += int(keys.size)
        pos, hit = self._lookup(keys)
        if hit.any():  # re-baked in place
            p = pos[hit]
            self.vals[p], self.ok[p] = vals[hit], ok[hit]
            self.version[p] = ver
        new = ~hit
        if new.any():
            k = keys[new]
            at = np.searchsorted(self.keys, k)
            self.keys = np.insert(self.keys, at, k)
            self.vals = np.insert(self.vals, at, vals[new], axis=0)
            self.ok = np.insert(self.ok, at, ok[new])
            self.version = np.insert(self.version, at, ver)

    def _corner_keys(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = x / self.cell
        c0 = np.floor(u)
        return _pack(c0.astype(np.int64)[:, None, :] + _CORNERS[None]), u - c0

    def _version(self) -> int:
        """A number that changes whenever the map does (trained, points or planes added)."""
        m = self.map
        return hash((m.n_trainings, len(m.points), m.frame_count))

    def prepare(self, points: np.ndarray | torch.Tensor) -> None:
        """Bake the vertices the (N, 3) map-frame points at the predicted pose touch that are
        missing or were baked at an older version of the map."""
        x = _as_numpy(points)
        if len(x) == 0:
            return
        keys = np.unique(self._corner_keys(x)[0])
        pos, hit = self._lookup(keys)
        old = np.zeros(keys.shape, bool)
        old[hit] = self.version[pos[hit]] != self._version()
        self._bake(keys[~hit | old])

    # ---- queries -------------------------------------------------------------------------------
    def sdf_and_grad(self, points: np.ndarray | torch.Tensor):
        """(N,) SDF, (N, 3) gradient and (N,) validity at map-frame points (numpy); vertices
        not baked yet are baked first."""
        x = _as_numpy(points)
        n = len(x)
        self.calls += 1
        self.queries += n
        if n == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool)
        keys, t = self._corner_keys(x)
        pos, hit = self._lookup(keys)
        if not hit.all():
            self._bake(np.unique(keys[~hit]))
            pos, hit = self._lookup(keys)
        vals, ok = self.vals[pos], self.ok[pos]  # (N, 8, 4), (N, 8)
        h = self.cell
        o = _CORNERS[None].astype(np.float64)  # (1, 8, 3)
        tt = t[:, None, :]
        f = np.where(o > 0, tt, 1.0 - tt)  # per-axis factors (N, 8, 3)
        w = f.prod(-1)  # trilinear weights (N, 8)
        d = (tt - o) * h  # x - v
        taylor = vals[..., 0] + (vals[..., 1:] * d).sum(-1)  # (N, 8)
        sdf = (w * taylor).sum(1)
        # gradient of the interpolant: sum_v w_v g_v + sum_v grad(w_v) taylor_v
        sgn = np.where(o > 0, 1.0, -1.0) / h
        dw = np.stack(
            [
                sgn[..., 0] * f[..., 1] * f[..., 2],
                sgn[..., 1] * f[..., 0] * f[..., 2],
                sgn[..., 2] * f[..., 0] * f[..., 1],
            ],
            -1,
        )  # (N, 8, 3)
        grad = (w[..., None] * vals[..., 1:]).sum(1) + (dw * taylor[..., None]).sum(1)
        valid = ok.all(1)
        sdf = np.where(valid, sdf, np.nan)
        grad = np.where(valid[:, None], grad, np.nan)
        return sdf, grad, valid


def _as_numpy(points: np.ndarray | torch.Tensor) -> np.ndarray:
    if isinstance(points, torch.Tensor):
        points = points.detach().cpu().numpy()
    return np.asarray(points, np.float64).reshape(-1, 3)
