"""Noise models of the env: the depth of an Intel RealSense D435i (active IR stereo) and the
actuation of the mobile base. Wheel-odometry drift lives with the odometry integration in
:mod:`simn_sim.env.office`; the magnitudes of all three, with their sources, are in ``docs/env.md``.

Depth model ``"d435i"`` (all parameters in :class:`DepthNoiseConfig`):

1. True depth z becomes a disparity ``d = f_px * b / z`` with baseline ``b`` (0.05 m) and the
   depth camera's focal length in pixels ``f_px`` (the colour stream's fx, scaled by the stereo
   resolution ratio).
2. Subpixel matching noise: ``d += N(0, sigma_d)`` with ``sigma_d`` px (0.08 px default). This
   gives the stereo RMS depth error ``sigma_z = z^2 * sigma_d / (f_px * b)``, growing with z^2.
3. Disparity quantisation to ``1/subpixel_steps`` px (1/32 default), then ``z' = f_px b / d``.
4. Dropouts: pixels at depth edges (relative depth jump to a 4-neighbour above
   ``edge_rel_jump``) read 0 with probability ``edge_dropout``; any pixel reads 0 with
   probability ``random_dropout``.

Sources: the 50 mm baseline is the D435/D435i datasheet's; the error formula and the typical
subpixel RMS of 0.08 px are from Intel's depth-tuning whitepaper (Grunnet-Jepsen et al., "Tuning
depth cameras for best performance"); the 1/32 px disparity step from Intel's subpixel-linearity
whitepaper. The dropout rates are chosen, not measured.

Actuation model ``"gaussian"`` (:class:`ActuationNoiseConfig`, :class:`ActuationNoise`): the base
executes ``v_exec = v * (1 + b_v + e_v[t])`` and ``w_exec = w * (1 + b_w + e_w[t])``, where
``b`` is a per-episode gain error (drawn at reset, ``N(0, bias_*)`` truncated at 3 sigma) and
``e[t]`` a per-control-step AR(1) error with stationary std ``sigma_*`` and correlation time
``tau_s`` (truncated at 3 sigma). The factor ``1 + b + e`` is kept >= 0.05, so the base never
moves against the command and stands still when told to. Magnitudes follow the LoCoBot
noise model of PyRobot (Murali et al. 2019) as Habitat's realistic PointNav uses it (Habitat
Challenge 2020: LoCoBot, proportional controller, noise multiplier 0.5), turned into relative
errors of the 0.25 m forward step and the 30 deg turn; see :class:`ActuationNoiseConfig`.

All noise is drawn from the ``np.random.Generator`` passed in, so a seeded env reproduces it.
Model ``"none"`` leaves depth and commands unchanged and draws nothing.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import numpy as np

from simn_sim.config import Config, require


@dataclasses.dataclass(frozen=True)
class DepthNoiseConfig(Config):
    """D435i depth noise (model ``"d435i"``; ``"none"`` is exact depth).

    Sources: ``baseline_m`` 0.05 m, D435/D435i datasheet; ``sigma_disparity_px`` 0.08 px, the
    typical subpixel RMS of Intel's depth-tuning whitepaper (RMS error = z^2 * subpixel /
    (f * baseline)); ``subpixel_steps`` 32, Intel's subpixel-linearity whitepaper (1/32 px
    disparity step); ``edge_rel_jump``, ``edge_dropout`` and ``random_dropout``: chosen, not
    measured.
    """

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


@dataclasses.dataclass(frozen=True)
class ActuationNoiseConfig(Config):
    """Actuation noise of the base: the executed ``[v, w]`` differs from the command (model
    ``"gaussian"``; ``"none"`` executes the command exactly). See the module docstring.

    Sources: the LoCoBot model of PyRobot (Murali et al. 2019) in habitat-sim's
    ``pyrobot_noisy_controls``, proportional controller, at the noise multiplier 0.5 of the Habitat
    Challenge 2020 PointNav configuration (0.25 m forward step, 30 deg turn). Its along-track
    error of a forward step has mean 0.0085 m and std 0.042 m (3.4 % and 16.7 % of 0.25 m); its
    rotation error of a turn has mean 0.0215 rad and std 0.065 rad (4.1 % and 12.5 % of 30 deg).

    - ``sigma_v``, ``sigma_w``: stationary std of the per-step relative error, the step stds above;
    - ``bias_v``, ``bias_w``: std of the per-episode relative gain error, the size of the mean
      overshoot above (a random gain per episode rather than an overshoot every step: chosen);
    - ``tau_s``: correlation time of the per-step error, 0.5 s (chosen, not measured: about the
      duration of one 0.25 m step; 0 gives white noise).

    The model's lateral drift and the heading drift of a forward step are not modelled.
    """

    model: Literal["none", "gaussian"] = "none"
    bias_v: float = 0.034
    bias_w: float = 0.041
    sigma_v: float = 0.167
    sigma_w: float = 0.125
    tau_s: float = 0.5

    def validate(self) -> None:
        n = "ActuationNoiseConfig"
        for f in ("bias_v", "bias_w", "sigma_v", "sigma_w"):
            require(0.0 <= getattr(self, f) <= 1.0, n, f, "must be in [0, 1] (a relative error)")
        require(self.tau_s >= 0, n, "tau_s", "must be >= 0 s")


class ActuationNoise:
    """The per-episode state of the actuation noise: the gain errors ``b`` and the AR(1) errors
    ``e`` of v and w. ``reset`` at every episode start, then ``apply`` once per control step."""

    def __init__(self, cfg: ActuationNoiseConfig, dt: float):
        self.cfg = cfg
        self.a = math.exp(-dt / cfg.tau_s) if cfg.tau_s > 0 else 0.0  # AR(1) coefficient
        self.sigma = np.array([cfg.sigma_v, cfg.sigma_w])
        self.bias = np.zeros(2)
        self.err = np.zeros(2)

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the episode's gain errors and the stationary initial step errors."""
        if self.cfg.model == "none":
            return
        b_std = np.array([self.cfg.bias_v, self.cfg.bias_w])
        self.bias = b_std * np.clip(rng.standard_normal(2), -3.0, 3.0)
        self.err = self.sigma * rng.standard_normal(2)

    def apply(self, v: float, w: float, rng: np.random.Generator) -> tuple[float, float]:
        """The executed ``(v, w)`` for the command ``(v, w)``; advances the AR(1) errors."""
        if self.cfg.model == "none":
            return v, w
        a = self.a
        self.err = a * self.err + math.sqrt(1.0 - a * a) * self.sigma * rng.standard_normal(2)
        e = np.clip(self.err, -3.0 * self.sigma, 3.0 * self.sigma)
        gain = np.maximum(1.0 + self.bias + e, 0.05)
        return float(v * gain[0]), float(w * gain[1])


def odometry_step(
    odom: np.ndarray,
    prev_pose: np.ndarray,
    pose: np.ndarray,
    trans_std: float,
    rot_std: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Wheel odometry ``odom`` (3,) ``(x, y, yaw)`` in the start frame after the base moved from
    ``prev_pose`` to ``pose`` ((3,) world ``(x, y, yaw)``, the motion it executed).

    Drift: the step's translation is scaled by ``1 + N(0, trans_std)`` and its heading change
    gets ``N(0, rot_std) * (|dyaw| + distance)``, drawn fresh each step (zero-mean, no
    systematic error). Both zero: the exact pose, and nothing is drawn.
    """
    c, s = math.cos(prev_pose[2]), math.sin(prev_pose[2])
    dxw, dyw = pose[0] - prev_pose[0], pose[1] - prev_pose[1]
    dx, dy = c * dxw + s * dyw, -s * dxw + c * dyw
    dth = _wrap(pose[2] - prev_pose[2])
    dist = math.hypot(dx, dy)
    if trans_std > 0 or rot_std > 0:
        scale = 1.0 + rng.normal(0.0, trans_std)
        dx, dy = dx * scale, dy * scale
        dth = dth + rng.normal(0.0, rot_std) * (abs(dth) + dist)
    co, so = math.cos(odom[2]), math.sin(odom[2])
    return np.array(
        [odom[0] + co * dx - so * dy, odom[1] + so * dx + co * dy, _wrap(odom[2] + dth)]
    )


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
