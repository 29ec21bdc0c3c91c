"""Per-column bounds and per-row finiteness of (N, D) point arrays.

``a.min(axis=0)`` on a tall, narrow C-ordered array reduces across rows with a stride of D
elements, which this numpy does 10-40x slower than D contiguous-enough column reductions
(0.11 against 2.0-2.4 ms for 60000 x 3 int64 points on the 2-core VM). :func:`column_bounds`
gives the same values and dtype as ``(a.min(axis=0), a.max(axis=0))`` (NaN propagates the
same way), column by column; :func:`finite_rows` gives ``np.isfinite(a).all(axis=-1)``
the same way.
"""

from __future__ import annotations

import numpy as np

__all__ = ["column_bounds", "finite_rows"]


def column_bounds(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi): the per-column minimum and maximum of a non-empty (N, D) array."""
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[0] == 0:
        raise ValueError(f"column_bounds needs a non-empty (N, D) array, got shape {a.shape}")
    d = a.shape[1]
    lo, hi = np.empty(d, a.dtype), np.empty(d, a.dtype)
    for j in range(d):
        col = a[:, j]
        lo[j], hi[j] = col.min(), col.max()
    return lo, hi


def finite_rows(a: np.ndarray) -> np.ndarray:
    """``np.isfinite(a).all(axis=-1)``: True where every entry along the last axis is finite."""
    a = np.asarray(a)
    if a.ndim == 0 or a.shape[-1] == 0:
        return np.isfinite(a).all(axis=-1)
    out = np.isfinite(a[..., 0])
    for j in range(1, a.shape[-1]):
        out &= np.isfinite(a[..., j])
    return out
