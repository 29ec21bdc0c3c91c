"""Transient obstacles: what appears where the camera saw free space is let go when unseen.

In a static scene nothing appears in space the camera has seen to be empty. A person walking
through a doorway does: the robot sees the doorway open, then the person in it, then turns
away, and the person's last position stays in the local frames' stores (carving removes a
point only when a later view sees through it). The doorway is then closed on the map, and the
planner routes round it. dyn-L1-004 (office_dynamic_v1): a person walked through the room's
only doorway as the robot approached it 2.4 m away; the route's cost-to-go jumped from 14.3 to
17.9 m, the robot turned away, and it timed out after 1000 steps with the doorway still closed
on its map by the person's points.

:class:`TransientCells` keeps, on a grid of ``cell`` metres in the planning frame (x-y), the
last view at which each cell's column was *seen free* and the last view at which an obstacle
point fell in it:

- *seen free*: every one of ``heights`` samples of the column (within the collision model's
  height band) projects into the depth image and the measured depth lies beyond it by
  ``margin`` + ``margin_per_m2`` x depth^2 (the projective free-space test; the stereo noise
  grows with depth^2), for cells within ``max_range`` of the camera; and the cells under the
  robot's footprint (it stands there);
- a cell that receives obstacle points at most ``window`` views after it was seen free has
  *appeared*; an appeared cell is *expired* once ``keep_views`` views have passed without an
  obstacle point in it, and the points in expired cells are left out of the planning models
  (:meth:`expired`). A later view that puts points in it again brings it back; a view that
  sees it free ends it (carving then removes the stored points too).

A person standing in view keeps their cells; a person out of view for ``keep_views`` is let
go, as is a static obstacle that a wrong free-space reading (pose error, depth noise beyond
the margin) made appear. The grid is dense (``extent`` metres each side of the start).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics
from simn_sim.world.shadow import seen_through

_NEVER = np.iinfo(np.int32).min // 2


@dataclasses.dataclass(frozen=True)
class TransientConfig(Config):
    """keep_views: views an appeared cell stays in the models without an obstacle point in it
    (0: off, nothing is transient). window: an obstacle point in a cell at most this many views
    after the cell was seen free makes it appear. cell: grid edge (m). max_range: cells tested
    for free space within this horizontal range of the camera (m). n_heights: column samples,
    spread over the collision model's height band. margin, margin_per_m2: the free-space test's
    margin (m, and m per m^2 of depth). extent: the grid covers this far (m) each side of the
    start; cells beyond are never transient."""

    keep_views: int = 0
    window: int = 100
    cell: float = 0.1
    max_range: float = 3.5
    n_heights: int = 4
    margin: float = 0.1
    margin_per_m2: float = 0.01
    extent: float = 40.0

    def validate(self) -> None:
        n = type(self).__name__
        require(self.keep_views >= 0, n, "keep_views", "must be >= 0 (0: off)")
        require(self.window >= 1, n, "window", "must be >= 1")
        require(0 < self.cell <= 1.0, n, "cell", "must be in (0, 1] m")
        require(self.max_range > 0, n, "max_range", "must be > 0")
        require(self.n_heights >= 1, n, "n_heights", "must be >= 1")
        require(self.margin >= 0, n, "margin", "must be >= 0")
        require(self.margin_per_m2 >= 0, n, "margin_per_m2", "must be >= 0")
        require(self.extent >= 1.0, n, "extent", "must be >= 1 m")


class TransientCells:
    """See the module docstring. ``z_band``: (z_min, z_max) of the collision model (m);
    ``robot_radius``: the footprint marked free at every view (m)."""

    def __init__(self, cfg: TransientConfig, z_band: tuple[float, float], robot_radius: float):
        self.cfg = cfg
        lo, hi = z_band
        pad = 0.05 * (hi - lo)
        self.heights = np.linspace(lo + pad, hi - pad, cfg.n_heights)
        self.robot_radius = float(robot_radius)
        self.n = int(np.ceil(2 * cfg.extent / cfg.cell))
        self.free_at = np.full((self.n, self.n), _NEVER, np.int32)
        self.occ_at = np.full((self.n, self.n), _NEVER, np.int32)
        self.appeared = np.zeros((self.n, self.n), bool)
        self.view = -1
        r = int(np.ceil(cfg.max_range / cfg.cell))
        g = np.arange(-r, r + 1)
        self._ring = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        self._ring = self._ring[np.hypot(*self._ring.T) * cfg.cell <= cfg.max_range]
        f = int(np.ceil(self.robot_radius / cfg.cell))
        g = np.arange(-f, f + 1)
        foot = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        self._foot = foot[np.hypot(*foot.T) * cfg.cell <= self.robot_radius]
        self.n_appeared = 0  # cells that appeared (events)
        self._live = np.zeros(0, np.int64)  # flat indices of the appeared cells

    def _cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, 2) grid indices of points ``xy`` (N, 2) and the (N,) mask of those on the grid."""
        ij = np.floor(xy / self.cfg.cell).astype(np.int64) + self.n // 2
        on = np.all((ij >= 0) & (ij < self.n), axis=1)
        return ij, on

    def observe(
        self,
        obstacle_points: np.ndarray,
        T_world_cam: np.ndarray,
        base_xy: np.ndarray,
        depth: np.ndarray,
        intr: Intrinsics,
    ) -> None:
        """One view: ``obstacle_points`` (N, 3) this view's obstacle points in the collision
        model's height band (planning frame), seen from ``T_world_cam`` with ``depth`` (H, W)
        metres (0 or NaN: no return) of intrinsics ``intr``; ``base_xy`` the robot's position."""
        d = np.asarray(depth)
        if d.shape != (intr.height, intr.width):
            raise ValueError(
                f"depth shape {d.shape} does not match the intrinsics ({intr.height}, {intr.width})"
            )
        self.view += 1
        c, view = self.cfg, self.view
        # occupied cells of this view
        ij, on = self._cells(np.asarray(obstacle_points, np.float64)[:, :2])
        oi = np.unique(ij[on][:, 0] * self.n + ij[on][:, 1])
        # the free-space test of the cells around the camera
        T = np.asarray(T_world_cam, np.float64)
        cam_ij, cam_on = self._cells(T[None, :2, 3])
        free = np.zeros(0, np.int64)
        if cam_on[0]:
            cells = cam_ij[0] + self._ring
            cells = cells[np.all((cells >= 0) & (cells < self.n), axis=1)]
            ctr = (cells - self.n // 2 + 0.5) * c.cell
            nh = len(self.heights)
            P = np.column_stack([np.repeat(ctr, nh, axis=0), np.tile(self.heights, len(ctr))])
            through = seen_through(P, T, d, intr, c.margin, c.margin_per_m2)
            col = through.reshape(-1, nh).all(axis=1)
            free = cells[col, 0] * self.n + cells[col, 1]
        b_ij, b_on = self._cells(np.asarray(base_xy, np.float64).reshape(1, 2))
        if b_on[0]:
            foot = b_ij[0] + self._foot
            foot = foot[np.all((foot >= 0) & (foot < self.n), axis=1)]
            free = np.union1d(free, foot[:, 0] * self.n + foot[:, 1])
        free = np.setdiff1d(free, oi, assume_unique=True)  # this view's points win
        fa, oa, ap = self.free_at.ravel(), self.occ_at.ravel(), self.appeared.ravel()
        if c.keep_views > 0 and len(oi):
            new = (view - fa[oi] <= c.window) & ~ap[oi]
            ap[oi[new]] = True
            self.n_appeared += int(new.sum())
            self._live = np.union1d(self._live, oi[new])
        oa[oi] = view
        fa[free] = view
        ap[free] = False
        self._live = self._live[ap[self._live]]

    def expired(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, >= 2, planning frame) in expired cells (appeared and
        without an obstacle point for more than ``keep_views`` views)."""
        out = np.zeros(len(points), bool)
        if self.cfg.keep_views <= 0 or not len(points):
            return out
        ij, on = self._cells(np.asarray(points, np.float64)[:, :2])
        k = ij[on]
        out[on] = self.appeared[k[:, 0], k[:, 1]] & (
            self.view - self.occ_at[k[:, 0], k[:, 1]] > self.cfg.keep_views
        )
        return out

    def expiring_now(self) -> bool:
        """Whether a cell expired at the last view (the models must be rebuilt to drop it)."""
        if self.cfg.keep_views <= 0:
            return False
        just = self.view - self.cfg.keep_views - 1
        return bool(np.any(self.occ_at.ravel()[self._live] == just))
