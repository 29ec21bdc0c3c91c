"""An obstacle map's cells judged against the scene's true footprints.

The planner's collision model is an occupancy grid of obstacle points (x-y cells of
``resolution`` metres, points inside a height band). :func:`occupancy_scores` rasterises a point
set the same way and compares its cells with the true footprints (the layout's polygons of
everything that blocks the band, :meth:`~simn_sim.env.layout.Layout.footprints`):

* a cell is **true** when its centre lies within ``tol`` (m) of a footprint (points lie on
  surfaces, so on a polygon's boundary; ``tol`` absorbs depth noise, pose error inside a local
  frame and the cell's own half-width);
* **phantom** cells are the others: obstacles the map holds where there are none (depth noise,
  ghosts of people who walked on), which close free space to the planner.

Recall needs a reference of what was seen; :func:`cells_of` gives the cell sets so a caller can
take the union of several maps' true cells as that reference.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely

__all__ = ["cells_of", "occupancy_scores"]


def cells_of(points: np.ndarray, resolution: float, z_band: tuple[float, float]) -> np.ndarray:
    """(M, 2) int64 unique x-y cell indices (floor(x / resolution)) of the (N, 3) points whose
    z lies in ``z_band`` (closed); non-finite points are an error."""
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"cells_of: points must be (N, 3), got shape {P.shape}")
    if not np.isfinite(P).all():
        raise ValueError("cells_of: points contain NaN or inf")
    if not resolution > 0:
        raise ValueError(f"cells_of: resolution must be > 0, got {resolution}")
    lo, hi = z_band
    if not lo < hi:
        raise ValueError(f"cells_of: z_band must be (low, high) with low < high, got {z_band}")
    P = P[(P[:, 2] >= lo) & (P[:, 2] <= hi)]
    if len(P) == 0:
        return np.zeros((0, 2), np.int64)
    return np.unique(np.floor(P[:, :2] / resolution).astype(np.int64), axis=0)


def occupancy_scores(
    cells: np.ndarray,
    footprints: Sequence[np.ndarray],
    resolution: float,
    tol: float,
) -> dict[str, object]:
    """Judge (M, 2) cell indices (:func:`cells_of`) against footprint polygons ((K, 2) arrays).

    Returns ``cells`` (M), ``true`` (cells whose centre is within ``tol`` of a footprint),
    ``phantom`` (M - true), ``precision`` (true / M; None for an empty map) and ``true_set``
    (a frozenset of the true cells' index pairs, for recall against a reference).
    """
    if not tol >= 0:
        raise ValueError(f"occupancy_scores: tol must be >= 0, got {tol}")
    C = np.asarray(cells)
    if C.ndim != 2 or C.shape[1] != 2:
        raise ValueError(f"occupancy_scores: cells must be (M, 2), got shape {C.shape}")
    if len(C) == 0:
        return {"cells": 0, "true": 0, "phantom": 0, "precision": None, "true_set": frozenset()}
    polys = [shapely.Polygon(np.asarray(f, float)) for f in footprints]
    if not polys:
        near = np.zeros(len(C), bool)
    else:
        region = shapely.union_all(polys).buffer(tol)
        shapely.prepare(region)
        centres = (C.astype(np.float64) + 0.5) * resolution
        near = shapely.contains_xy(region, centres[:, 0], centres[:, 1])
    n_true = int(near.sum())
    return {
        "cells": int(len(C)),
        "true": n_true,
        "phantom": int(len(C) - n_true),
        "precision": n_true / len(C),
        "true_set": frozenset(map(tuple, C[near].tolist())),
    }
