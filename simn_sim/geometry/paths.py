"""Polylines: the one home of segment and path lengths (metres, any units of the input)."""

from __future__ import annotations

import numpy as np

__all__ = ["path_length", "segment_lengths"]


def segment_lengths(points: np.ndarray) -> np.ndarray:
    """(N - 1,) float64 lengths of the segments of an (N, 2) or (N, 3) polyline.

    2-D: ``hypot(dx, dy)``; 3-D: ``hypot(hypot(dx, dy), dz)``. Raises ValueError for another
    shape or a non-finite point; an empty input (no points) gives no segments.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.size == 0:
        return np.zeros(0)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (N, 2) or (N, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite (found NaN or inf)")
    d = np.diff(p, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    return seg if p.shape[1] == 2 else np.hypot(seg, d[:, 2])


def path_length(points: np.ndarray) -> float:
    """Length of an (N, 2) or (N, 3) polyline: the sum of its segment lengths (0 for N < 2)."""
    seg = segment_lengths(points)
    return float(seg.sum()) if len(seg) else 0.0
