"""What the implicit map returns (:class:`TrainResult`, :class:`FrameResult`,
:class:`SdfQuery`), the checks of its inputs (points, colours, labels) and the denormal guard
of its training."""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np
import torch

__all__ = [
    "FrameResult",
    "SdfQuery",
    "TrainResult",
    "as_float_points",
    "check_colors",
    "check_labels",
    "flush_denormals",
]


@dataclasses.dataclass(frozen=True)
class TrainResult:
    """Outcome of one call of the adaptive training loop."""

    iterations: int
    converged: bool  # stopped on the windowed loss change (not the cap)
    final_loss: float  # mean total loss over the last window
    n_samples: int  # valid samples used (new + replayed)
    n_replayed: int
    seconds: float


@dataclasses.dataclass(frozen=True)
class FrameResult:
    """Outcome of integrating one frame."""

    frame_index: int
    n_points: int  # after dropping non-finite points and down-sampling
    n_dropped: int  # non-finite input points
    n_new_neural_points: int
    n_samples: int
    train: TrainResult | None  # None when this frame did not trigger training


@dataclasses.dataclass
class SdfQuery:
    """sdf (N,), grad (N, 3) or None, valid (N,) bool; numpy or torch like the input."""

    sdf: np.ndarray | torch.Tensor
    grad: np.ndarray | torch.Tensor | None
    valid: np.ndarray | torch.Tensor


@contextlib.contextmanager
def flush_denormals():
    """Flush denormal floats to zero while training.

    Adam's second moments of tiny gradients underflow to denormals, which make CPU arithmetic
    ~10x slower. The flag is process-wide and breaks other code (scipy's cKDTree segfaults on
    planar data with it), so it is set only inside the training loop and cleared afterwards.
    """
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def as_float_points(points: np.ndarray | torch.Tensor, name: str = "points") -> torch.Tensor:
    if isinstance(points, np.ndarray):
        if not np.issubdtype(points.dtype, np.floating):
            raise TypeError(f"{name} must be float32 or float64, got dtype {points.dtype}")
        t = torch.from_numpy(np.ascontiguousarray(points))
    elif isinstance(points, torch.Tensor):
        if not points.is_floating_point():
            raise TypeError(f"{name} must be a floating-point tensor, got {points.dtype}")
        t = points
    else:
        raise TypeError(
            f"{name} must be a numpy array or torch tensor, got {type(points).__name__}"
        )
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {tuple(t.shape)}")
    return t


def check_colors(colors, n: int) -> np.ndarray:
    """(n, 3) float32 colours in [0, 1] from float or uint8 input (grey 0.5 when None)."""
    if colors is None:
        return np.full((n, 3), 0.5, np.float32)
    c = colors.detach().cpu().numpy() if isinstance(colors, torch.Tensor) else colors
    if not isinstance(c, np.ndarray) or c.shape != (n, 3):
        raise ValueError(f"colors must be ({n}, 3), got {getattr(c, 'shape', type(c).__name__)}")
    if c.dtype == np.uint8:
        return c.astype(np.float32) / 255.0
    if not np.issubdtype(c.dtype, np.floating):
        raise TypeError(f"colors must be float in [0, 1] or uint8, got dtype {c.dtype}")
    return np.clip(np.nan_to_num(c.astype(np.float32), nan=0.5), 0.0, 1.0)


def check_labels(labels, n: int) -> np.ndarray | None:
    """(n,) int16 semantic labels from integer input (None stays None)."""
    if labels is None:
        return None
    lab = labels.detach().cpu().numpy() if isinstance(labels, torch.Tensor) else labels
    if not isinstance(lab, np.ndarray) or lab.shape != (n,):
        raise ValueError(f"labels must be ({n},), got {getattr(lab, 'shape', type(lab).__name__)}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise TypeError(f"labels must be integers, got dtype {lab.dtype}")
    return lab.astype(np.int16)
