"""Heading from the walls: the Manhattan-frame yaw of a depth frame's vertical surfaces.

Office walls share two horizontal directions, 90 deg apart. The horizontal normals of a
frame's vertical surfaces, rotated into a gravity-aligned frame, cluster at those directions;
their angle modulo 90 deg is the frame's wall direction, and its change from one frame to
another, measured through the estimated rotations, is the heading error accumulated between
them (modulo 90 deg). Clutter at other angles (rotated desks, boxes) only thins the peak.

Normals come from the organised point image sampled every ``stride`` pixels (a central
difference over ``stride`` pixels: per-pixel normals of D435i depth are too noisy to locate a
peak, docs/navigation.md "The same default on another CPU").

:class:`WallHeading` turns it into a heading correction for the SLAM front-end
(``SlamConfig.heading``): the vertical-surface normals of a local frame's views are pooled in
its anchor coordinates; when the frame closes, the pool's wall direction is compared with a
reference (the first pool whose peak is clear enough), and the next frame's anchor is turned
toward it by ``gain`` times the residual, within ``gate_deg``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics, pixel_rays
from simn_sim.semantics import normals_from_organized

__all__ = ["ManhattanYaw", "WallHeading", "WallHeadingConfig", "frame_normals", "manhattan_yaw"]


@dataclasses.dataclass(frozen=True)
class ManhattanYaw:
    """``yaw_deg``: the wall direction modulo 90 deg, in (-45, 45]; ``support``: the share of
    the vertical surfaces' normals within ``support_deg`` of it (modulo 90 deg);
    ``n_vertical``: how many normals were vertical surfaces'."""

    yaw_deg: float
    support: float
    n_vertical: int


def frame_normals(
    depth: np.ndarray, intr: Intrinsics, stride: int = 8, max_depth: float = 3.0
) -> np.ndarray:
    """(M, 3) unit normals (OpenCV camera frame) of a depth image's points nearer than
    ``max_depth``, from the point image sampled every ``stride`` pixels. Zero, NaN and
    infinite depths are invalid pixels (no normal touches them)."""
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise ValueError(f"depth must be float metres, got dtype {d.dtype}")
    if int(stride) < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    if not (np.isfinite(max_depth) and max_depth > 0):
        raise ValueError(f"max_depth must be > 0, got {max_depth}")
    if d.shape != (intr.height, intr.width):
        raise ValueError(
            f"depth is {d.shape[1]}x{d.shape[0]} but intrinsics are {intr.width}x{intr.height}"
        )
    rx, ry = pixel_rays(intr, stride)  # only the sampled pixels are back-projected
    z = d[::stride, ::stride].astype(np.float32, copy=False)
    P = np.stack([rx * z, ry * z, z], axis=-1).astype(np.float64)
    z = P[..., 2]
    P[~(np.isfinite(z) & (z > 0))] = np.nan
    N = normals_from_organized(P, max_jump=0.05 * stride)
    ok = np.isfinite(N).all(-1) & (z < max_depth)
    return N[ok]


def manhattan_yaw(
    normals_world: np.ndarray,
    vertical_max_nz: float = 0.2,
    min_normals: int = 200,
    peak_halfwidth_deg: float = 4.0,
    support_deg: float = 2.0,
) -> ManhattanYaw | None:
    """The wall direction of gravity-aligned normals (N, 3) (z up); None with fewer than
    ``min_normals`` vertical-surface normals (``|n_z| < vertical_max_nz``). The angles are
    taken modulo 90 deg (as 4x the angle on the circle), the peak of a 0.25 deg histogram
    (smoothed over 3 bins) is refined by the circular mean within ``peak_halfwidth_deg``."""
    n = np.asarray(normals_world, dtype=np.float64)
    if n.ndim != 2 or n.shape[1] != 3:
        raise ValueError(f"normals_world must be (N, 3), got shape {n.shape}")
    n = n[np.isfinite(n).all(1)]
    v = n[np.abs(n[:, 2]) < vertical_max_nz]
    if len(v) < max(int(min_normals), 1):
        return None
    a = np.angle(np.exp(4j * np.arctan2(v[:, 1], v[:, 0])))  # 4 x angle, in (-pi, pi]
    h, edges = np.histogram(a, bins=360, range=(-np.pi, np.pi))
    hs = h + np.roll(h, 1) + np.roll(h, -1)
    k = int(np.argmax(hs))
    c = 0.5 * (edges[k] + edges[k + 1])
    d = np.angle(np.exp(1j * (a - c)))
    near = np.abs(d) < np.radians(4 * peak_halfwidth_deg)
    c = c + float(np.angle(np.mean(np.exp(1j * d[near]))))
    yaw = float(np.degrees(np.angle(np.exp(1j * c)))) / 4.0
    if yaw <= -45.0:
        yaw += 90.0
    d = np.angle(np.exp(1j * (a - c)))
    support = float(np.mean(np.abs(d) < np.radians(4 * support_deg)))
    return ManhattanYaw(yaw_deg=yaw, support=support, n_vertical=len(v))


@dataclasses.dataclass(frozen=True)
class WallHeadingConfig(Config):
    """Heading correction from the walls (:class:`WallHeading`); off unless ``enabled``.

    Each view's normals (:func:`frame_normals` with ``stride`` and ``max_depth``) nearer than
    vertical (``|n_z| < vertical_max_nz`` in the floor plane's coordinates) join the open local
    frame's pool, at most ``max_pool`` of them (every k-th beyond). A pool of at least
    ``min_normals`` gives the frame's wall direction (:func:`manhattan_yaw`). The first pool
    with ``ref_min_support`` sets the reference; a later pool with ``min_support`` whose
    residual to it (modulo 90 deg) is within ``gate_deg`` turns the next anchor by ``-gain``
    times the residual and, with ``prior_sigma_deg`` > 0, puts a heading prior (the residual
    taken out, that sigma) on the closed frame's anchor for the pose graph, so that a later
    loop closure against that frame does not turn the correction back."""

    enabled: bool = False
    stride: int = 8
    max_depth: float = 3.0
    vertical_max_nz: float = 0.2
    min_normals: int = 200
    max_pool: int = 20000
    ref_min_support: float = 0.4
    min_support: float = 0.3
    gate_deg: float = 3.0
    gain: float = 0.5
    prior_sigma_deg: float = 0.0

    def validate(self) -> None:
        n = type(self).__name__
        require(self.stride >= 1, n, "stride", f"must be >= 1, got {self.stride}")
        for f in ("max_depth", "gate_deg"):
            v = getattr(self, f)
            require(math.isfinite(v) and v > 0, n, f, f"must be > 0, got {v}")
        require(0 < self.vertical_max_nz < 1, n, "vertical_max_nz", "must be in (0, 1)")
        require(self.min_normals >= 1, n, "min_normals", "must be >= 1")
        require(self.max_pool >= self.min_normals, n, "max_pool", "must be >= min_normals")
        for f in ("ref_min_support", "min_support"):
            v = getattr(self, f)
            require(0 <= v <= 1, n, f, f"must be in [0, 1], got {v}")
        require(0 < self.gain <= 1, n, "gain", f"must be in (0, 1], got {self.gain}")
        v = self.prior_sigma_deg
        require(math.isfinite(v) and v >= 0, n, "prior_sigma_deg", f"must be >= 0, got {v}")
        require(self.gate_deg < 45, n, "gate_deg", "must be < 45 (walls repeat every 90 deg)")


def wrap90(deg: float) -> float:
    """An angle modulo 90 deg, in [-45, 45)."""
    return float((deg + 45.0) % 90.0 - 45.0)


class WallHeading:
    """The wall-direction pool of the open local frame and the reference it is held to.

    ``observe(depth, R_anchor_cam, R_plane_anchor)`` pools a view; ``residual(R_plane_anchor)``
    closes the pool (the frame's anchor rotation in the floor plane's coordinates, z up, as
    it is then) and returns its residual to the reference in degrees (None: none usable), then
    empties it.
    Counters: ``n_pools`` closed, ``n_clear`` with a clear peak, ``n_corrections`` applied,
    ``n_gated`` beyond the gate; ``reference_deg`` once set.
    """

    def __init__(self, cfg: WallHeadingConfig, intr: Intrinsics) -> None:
        cfg.validate()
        self.cfg, self.intr = cfg, intr
        self.reference_deg: float | None = None
        self._pool: list[np.ndarray] = []
        self._n = 0
        self.n_pools = self.n_clear = self.n_corrections = self.n_gated = 0
        self.last_residual_deg = float("nan")

    def observe(self, depth: np.ndarray, R_anchor_cam: np.ndarray, R_plane_anchor: np.ndarray):
        """Pool one view's near-vertical normals, in anchor coordinates."""
        c = self.cfg
        if self._n >= c.max_pool:
            return
        n = frame_normals(depth, self.intr, c.stride, c.max_depth) @ np.asarray(R_anchor_cam).T
        up = n @ np.asarray(R_plane_anchor)[2]  # z of the floor plane, in anchor coordinates
        n = n[np.abs(up) < c.vertical_max_nz]
        if len(n) > c.max_pool - self._n:
            n = n[:: int(math.ceil(len(n) / (c.max_pool - self._n)))]
        if len(n):
            self._pool.append(n)
            self._n += len(n)

    def residual(self, R_plane_anchor: np.ndarray) -> float | None:
        """Close the pool: its heading residual (deg, about the plane's z; the estimate is
        that much too far left), or None (too few normals, no clear peak, no reference yet,
        or beyond the gate)."""
        c = self.cfg
        pool, self._pool, self._n = self._pool, [], 0
        if not pool:
            return None
        self.n_pools += 1
        m = manhattan_yaw(
            np.concatenate(pool) @ np.asarray(R_plane_anchor).T,
            vertical_max_nz=c.vertical_max_nz,
            min_normals=c.min_normals,
        )
        if m is None:
            return None
        if self.reference_deg is None:
            if m.support >= c.ref_min_support:
                self.reference_deg = m.yaw_deg
                self.n_clear += 1
            return None
        if m.support < c.min_support:
            return None
        self.n_clear += 1
        e = wrap90(m.yaw_deg - self.reference_deg)
        self.last_residual_deg = e
        if abs(e) > c.gate_deg:
            self.n_gated += 1
            return None
        self.n_corrections += 1
        return e
