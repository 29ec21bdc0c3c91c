"""The implicit map's SDF for registration, with the k-NN search reused across LM iterations."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from simn_sim.mapping.results import as_float_points

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap

__all__ = ["TrackingSdf"]


class TrackingSdf:
    """The map's SDF and gradient for registration, with the k-NN search reused.

    LM evaluates the same points at poses a few millimetres apart; the k-NN search is ~70 %
    of a query's cost (docs/mapping.md). Here the neighbour indices of the last search are
    reused while the query has the same number of points, the map did not change (its
    neural points' ``version``: points added, planes or features updated), and no point moved
    more than ``reuse_distance`` (m) since that search; otherwise it searches again. With the
    neighbours, their tables (positions, features, colours, planes: ``ImplicitMap._gather``)
    are kept too, so a reused evaluation is the decoder alone; the SDF and gradient are always
    recomputed at the new points, and equal those of ``ImplicitMap.query`` with the same
    neighbours. With fixed neighbours the SDF is smooth in the pose (no jumps where the
    neighbour set changes). ``searches`` counts the searches done, ``evaluations`` the calls.

    ``max_distance``: a point further than this *along the surface* (the distance to a
    neighbour's mean surface point minus its component along that neighbour's normal; the
    full distance where the map has no normals) from every neighbour is invalid (NaN), instead
    of ``search_radius``: beyond the observed surface the blended planes are extrapolated, and
    such residuals pull a frame towards the map's edge (docs/slam.md).
    """

    def __init__(
        self,
        imap: ImplicitMap,
        reuse_distance: float = 0.02,
        max_distance: float | None = None,
    ) -> None:
        self.map = imap
        self.reuse_distance = float(reuse_distance)
        self.max_distance = None if max_distance is None else float(max_distance)
        self._key: tuple | None = None
        self._x: torch.Tensor | None = None
        self._idx: torch.Tensor | None = None
        self._tables: tuple[torch.Tensor, ...] | None = None
        self.searches = 0
        self.evaluations = 0

    def sdf_and_grad(self, points: np.ndarray | torch.Tensor):
        """(N,) SDF and (N, 3) gradient at map-frame points (NaN where invalid)."""
        m = self.map
        x = as_float_points(points).to(m.device, torch.float32)
        # indices and tables stay valid while the map's points do not change
        key = (len(m.points), m.points.version, x.shape[0])
        stale = (
            self._key != key
            or self._x is None
            or bool(((x - self._x) ** 2).sum(1).max() > self.reuse_distance**2)
        )
        self.evaluations += 1
        if stale:
            self._idx, _ = m.points.knn(x)
            self._tables = m._gather(self._idx)
            self._x, self._key = x.clone(), key
            self.searches += 1
        idx, tables = self._idx, self._tables
        if self.max_distance is not None:
            # coverage: the distance along the surface to the nearest neighbour's plane point
            # (the offset along its normal is depth noise, not a lack of map)
            q_nb, n_nb = tables[4], tables[5]  # the neighbours' plane points and normals
            dv = x[:, None, :] - q_nb
            dt = dv - (dv * n_nb).sum(-1, keepdim=True) * n_nb
            d2 = torch.where(idx >= 0, (dt**2).sum(-1), torch.full_like(dt[..., 0], float("inf")))
            far = d2.min(1).values > self.max_distance**2
            idx = torch.where(far[:, None], torch.full_like(idx, -1), idx)
        q = m.query(points, with_grad=True, neighbors=idx, tables=tables)
        return q.sdf, q.grad
