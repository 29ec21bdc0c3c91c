"""Depth noise model of an Intel RealSense D435i (active IR stereo).

Model ``"d435i"`` (all parameters in :class:`DepthNoiseConfig`):

1. True depth z becomes a disparity ``d = f_px * b / z`` with baseline ``b`` (0.05 m) and the
   depth camera's focal length in pixels ``f_px`` (the colour stream's fx, scaled by the stereo
   resolution ratio).
2. Subpixel matching noise: ``d += N(0, sigma_d)`` with ``sigma_d`` px (0.08 px default). This
   gives the stereo RMS depth error ``sigma_z = z^2 * sigma_d / (f_px * b)``, growing with z^2.
3. Disparity quantisation to ``1/subpixel_steps`` px (1/32 default), then ``z' = f_px b / d``.
4. Dropouts: pixels at depth edges (relative depth jump to a 4-neighbour above
   ``edge_rel_jump``) read 0 with probability ``edge_dropout``; any pixel reads 0 with
   probability ``random_dropout``.

The noise is drawn from the ``np.random.Generator`` passed in, so a seeded env reproduces it.
Model ``"none"`` returns the depth unchanged.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np

from simn_sim.config import Config, require


@dataclasses.dataclass(frozen=True)
class DepthNoiseConfig(Config):
    model: Literal["none", "d435i"] = "none"
    baseline_m: float = 0.05
    sigma_disparity_px: float = 0.08
    subpixel_steps: int = 32
    stereo_focal_px: float = 0.0  # 0: use the colour stream's fx
    edge_rel_jump: float = 0.04
    edge_dropout: float = 0.5
    random_dropout: float = 0.002

    def validate(self) -> None:
        n = "DepthNoiseConfig"
        require(self.baseline_m > 0, n, "baseline_m", "must be > 0")
        require(self.sigma_disparity_px >= 0, n, "sigma_disparity_px", "must be >= 0")
        require(self.subpixel_steps >= 1, n, "subpixel_steps", "must be >= 1")
        require(self.stereo_focal_px >= 0, n, "stereo_focal_px", "must be >= 0")
        require(self.edge_rel_jump > 0, n, "edge_rel_jump", "must be > 0")
        for f in ("edge_dropout", "random_dropout"):
            require(0.0 <= getattr(self, f) <= 1.0, n, f, "must be a probability in [0, 1]")


def depth_sigma(z: np.ndarray, fx: float, cfg: DepthNoiseConfig) -> np.ndarray:
    """Stereo RMS depth error (m) at depth ``z`` (before quantisation)."""
    f = cfg.stereo_focal_px or fx
    return z**2 * cfg.sigma_disparity_px / (f * cfg.baseline_m)


def apply_depth_noise(
    depth: np.ndarray, fx: float, cfg: DepthNoiseConfig, rng: np.random.Generator
) -> np.ndarray:
    """Return a noisy copy of metric ``depth`` (H, W) float32; 0 marks invalid pixels."""
    if cfg.model == "none":
        return depth
    f = cfg.stereo_focal_px or fx
    valid = depth > 0
    z = np.where(valid, depth, 1.0).astype(np.float64)
    disp = f * cfg.baseline_m / z
    disp = disp + rng.normal(0.0, cfg.sigma_disparity_px, size=disp.shape)
    q = 1.0 / cfg.subpixel_steps
    disp = np.maximum(np.round(disp / q) * q, q)
    out = (f * cfg.baseline_m / disp).astype(np.float32)
    # edges: relative jump to any 4-neighbour
    jump = np.zeros(depth.shape, bool)
    zz = np.where(valid, depth, 0.0)
    for axis in (0, 1):
        d = np.abs(np.diff(zz, axis=axis)) / np.maximum(
            np.minimum(np.delete(zz, -1, axis), np.delete(zz, 0, axis)), 1e-6
        )
        e = d > cfg.edge_rel_jump
        if axis == 0:
            jump[:-1] |= e
            jump[1:] |= e
        else:
            jump[:, :-1] |= e
            jump[:, 1:] |= e
    u = rng.random(depth.shape)
    drop = (jump & (u < cfg.edge_dropout)) | (rng.random(depth.shape) < cfg.random_dropout)
    out[drop | ~valid] = 0.0
    return out
