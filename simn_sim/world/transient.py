"""Transient obstacles: what appears where the camera saw free space is let go when unseen.

In a static scene nothing appears in space the camera has seen to be empty. A person walking
through a doorway does: the robot sees the doorway open, then the person in it, then turns
away, and the person's last position stays in the local frames' stores (carving removes a
point only when a later view sees through it). The doorway is then closed on the map, and the
planner routes round it. dyn-L1-004 (office_dynamic_v1): a person walked through the room's
only doorway as the robot approached it 2.4 m away; the route's cost-to-go jumped from 14.3 to
17.9 m, the robot turned away, and it timed out after 1000 steps with the doorway still closed
on its map by the person's points.

:class:`TransientCells` keeps, on a grid of ``cell`` metres in the planning frame (x-y) with
``n_heights`` height slabs over the collision model's band, the last view at which each slab of
each cell was *seen free* and the last view at which an obstacle point fell in it:

- *seen free*: the slab's centre projects into the depth image and the measured depth lies
  beyond it by ``margin`` + ``margin_per_m2`` x depth^2 (the projective free-space test; the
  stereo noise grows with depth^2), for cells within ``max_range`` of the camera; and every
  slab of the cells under the robot's footprint (it stands there);
- a slab that receives obstacle points at most ``window`` views after it and the same slab
  of its 8 neighbour cells were seen free has *appeared* (the neighbours: the cells at a
  static object's edge, partly covered, are seen through at their centre; with the cell
  alone, nav2-ref-004's look-around in a static office made 205 appear events in 75 steps);
  with the per-point test (``point_share``), it appears only if this view's points in it,
  projected into the view that last saw it free, were seen through at their own pixel there
  (a desk leg inside the cell is seen past at the cell's centre, but its own points land on
  it: :meth:`TransientCells._points_seen_free`);
  it is *expired* once ``keep_views`` views have passed without an obstacle point in it, or
  once a view has seen it free after its last point, and the points in expired slabs are left
  out of the planning models (:meth:`expired`). A later view that puts points in it again
  brings it back. An appeared slab stays appeared: carving, which tests each stored point
  against its own pixel, leaves some of a person's points in slabs whose centre is seen free
  (dyn-L2-003: 27 of the 282 slabs a person walked through were seen free 1-10 views after
  their last point and kept their points, narrowing the corridor for the rest of the episode).

Slabs, not whole columns: the D435i mount (1.0 m up, pitched 24 deg down, 42.5 deg vertical
field of view) sees nothing above 2.75 deg below the horizontal and no floor within 0.99 m, so
a whole column of the 0.06-1.0 m band is in view only about 0.9-1.0 m from the camera. A
column test marked almost nothing free beyond the footprint, and a person's points 2-3 m away
never appeared (dyn-L1-004 with ``keep_views`` 30 timed out as without). A slab is judged on
its own evidence: a table top above the view is never seen free, so it never appears.

A person standing in view keeps their slabs; a person out of view for ``keep_views`` is let
go, as is a static obstacle that a wrong free-space reading (pose error, depth noise beyond
the margin) made appear. The grid is dense (``extent`` metres each side of the start).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from scipy import ndimage

from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics
from simn_sim.world.shadow import beyond, project_points, seen_through

_NEVER = np.iinfo(np.int32).min // 2


@dataclasses.dataclass(frozen=True)
class TransientConfig(Config):
    """keep_views: views an appeared cell stays in the models without an obstacle point in it
    (0: off, nothing is transient). window: an obstacle point in a cell at most this many views
    after the cell was seen free makes it appear. cell: grid edge (m). max_range: cells tested
    for free space within this horizontal range of the camera (m). n_heights: height slabs of
    the collision model's band, each tested at its centre. margin, margin_per_m2: the
    free-space test's margin (m, and m per m^2 of depth). extent: the grid covers this far
    (m) each side of the start; cells beyond are never transient. grow_share: a connected blob
    of recently occupied slabs of which at least this share appeared appears whole (0: off;
    see :meth:`TransientCells._grow`). point_share: a slab that passes the slab rule appears
    only if at least this share of its points was seen through at their own pixel in the view
    that last saw the slab free, and at least ``point_min`` of them (0: off; see
    :meth:`TransientCells._points_seen_free`). point_deg: that test reads the nearest depth
    within this angle (deg) of the pixel. It keeps the last ``window`` + 1 depth images
    (float16): 15.5 MB at 320x240, 62 MB at 640x480 with ``window`` 100. mask_tracking: the
    front-end leaves the points that fall in appeared slabs (at the predicted pose) out of
    registration (tracking and revisit checks) and out of the maps it registers against (the
    surface store and the learned map); the obstacle stores keep them (see
    :meth:`~simn_sim.slam.pipeline.SimnSlam.process`, ``dynamic``). follow_points (on by
    default since 2026-12-07; off: the slab each point is in now): the models judge each
    stored point by the slab it was observed in (the world through the anchors of that view),
    not the slab its frame's current anchor puts it in: when the pose graph moves an anchor,
    the frame's points move into slabs whose records never saw them arrive, and a person's
    points there never expire (dyn-L5-000: an anchor move of 0.11 m carried 48 of a person's
    points near the goal into such slabs, and the robot stood 0.47 m from the goal, its plan
    ending short of it, for 100 steps)."""

    keep_views: int = 0
    window: int = 100
    cell: float = 0.1
    max_range: float = 3.5
    n_heights: int = 4
    margin: float = 0.1
    margin_per_m2: float = 0.01
    extent: float = 40.0
    grow_share: float = 0.4
    point_share: float = 0.5
    point_min: int = 3
    point_deg: float = 0.5
    mask_tracking: bool = False
    follow_points: bool = True

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
        require(0 <= self.grow_share <= 1, n, "grow_share", "must be in [0, 1] (0: off)")
        require(0 <= self.point_share <= 1, n, "point_share", "must be in [0, 1] (0: off)")
        require(self.point_min >= 1, n, "point_min", "must be >= 1")
        require(0 <= self.point_deg <= 10, n, "point_deg", "must be in [0, 10] deg")


class TransientCells:
    """See the module docstring. ``z_band``: (z_min, z_max) of the collision model (m);
    ``robot_radius``: the footprint marked free at every view (m). Arrays are indexed
    (i, j, slab)."""

    def __init__(self, cfg: TransientConfig, z_band: tuple[float, float], robot_radius: float):
        self.cfg = cfg
        lo, hi = (float(z) for z in z_band)
        if not hi > lo:
            raise ValueError(f"z_band must be (z_min, z_max) with z_max > z_min, got {z_band}")
        self.z_lo, self.slab_h = lo, (hi - lo) / cfg.n_heights
        self.heights = lo + self.slab_h * (np.arange(cfg.n_heights) + 0.5)  # slab centres
        self.robot_radius = float(robot_radius)
        self.n = int(np.ceil(2 * cfg.extent / cfg.cell))
        shape = (self.n, self.n, cfg.n_heights)
        self.free_at = np.full(shape, _NEVER, np.int32)
        self.occ_at = np.full(shape, _NEVER, np.int32)
        self.appeared = np.zeros(shape, bool)
        self.view = -1
        r = int(np.ceil(cfg.max_range / cfg.cell))
        g = np.arange(-r, r + 1)
        self._ring = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        self._ring = self._ring[np.hypot(*self._ring.T) * cfg.cell <= cfg.max_range]
        f = int(np.ceil(self.robot_radius / cfg.cell))
        g = np.arange(-f, f + 1)
        foot = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        self._foot = foot[np.hypot(*foot.T) * cfg.cell <= self.robot_radius]
        g = np.arange(-1, 2)
        self._nb = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        self.n_appeared = 0  # slabs that appeared (events)
        self.n_grown = 0  # of them, slabs that appeared by growth (:meth:`_grow`)
        self._live = np.zeros(0, np.int64)  # flat indices of the appeared slabs
        self._freed_now = False  # an appeared slab with points was seen free at the last view
        # the last ``window`` + 1 views for the per-point test: nearest depth near each pixel
        # (float16 m, 0: no return), camera pose, view number (-1: empty)
        self._past_depth: np.ndarray | None = None
        self._past_T = np.zeros((cfg.window + 1, 4, 4))
        self._past_view = np.full(cfg.window + 1, -1, np.int64)

    def _index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat (cell, slab) indices of ``points`` (N, 3) and the (N,) mask of those on the
        grid (a point above or below the band counts in the nearest slab)."""
        P = np.asarray(points, np.float64).reshape(-1, 3)
        ij, on = self._cells(P[:, :2])
        k = np.clip(np.floor((P[:, 2] - self.z_lo) / self.slab_h), 0, self.cfg.n_heights - 1)
        flat = (ij[:, 0] * self.n + ij[:, 1]) * self.cfg.n_heights + k.astype(np.int64)
        return flat, on

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
        c, view, nh = self.cfg, self.view, self.cfg.n_heights
        # occupied slabs of this view
        flat, on = self._index(obstacle_points)
        oi = np.unique(flat[on])
        # the free-space test of the slabs around the camera
        T = np.asarray(T_world_cam, np.float64)
        cam_ij, cam_on = self._cells(T[None, :2, 3])
        free = np.zeros(0, np.int64)
        if cam_on[0]:
            cells = cam_ij[0] + self._ring
            cells = cells[np.all((cells >= 0) & (cells < self.n), axis=1)]
            ctr = (cells - self.n // 2 + 0.5) * c.cell
            P = np.column_stack([np.repeat(ctr, nh, axis=0), np.tile(self.heights, len(ctr))])
            through = seen_through(P, T, d, intr, c.margin, c.margin_per_m2)
            slab = np.repeat((cells[:, 0] * self.n + cells[:, 1]) * nh, nh) + np.tile(
                np.arange(nh), len(cells)
            )
            free = slab[through]
        b_ij, b_on = self._cells(np.asarray(base_xy, np.float64).reshape(1, 2))
        if b_on[0]:
            foot = b_ij[0] + self._foot
            foot = foot[np.all((foot >= 0) & (foot < self.n), axis=1)]
            fs = ((foot[:, 0] * self.n + foot[:, 1]) * nh)[:, None] + np.arange(nh)
            free = np.union1d(free, fs.ravel())
        free = np.setdiff1d(free, oi, assume_unique=True)  # this view's points win
        fa, oa, ap = self.free_at.ravel(), self.occ_at.ravel(), self.appeared.ravel()
        # appeared slabs that held points since they were last seen free, now seen free
        self._freed_now = bool(np.any(ap[free] & (oa[free] > fa[free])))
        if c.keep_views > 0 and len(oi):
            # the slab and its 8 neighbours in the same height slab seen free within the
            # window: a static object's edge cell, partly covered with its centre seen
            # through, has a neighbour inside the object that never is
            cell, k = np.divmod(oi, nh)
            i, j = np.divmod(cell, self.n)
            ii = np.clip(i[:, None] + self._nb[:, 0], 0, self.n - 1)
            jj = np.clip(j[:, None] + self._nb[:, 1], 0, self.n - 1)
            nb = (ii * self.n + jj) * nh + k[:, None]
            new = (view - fa[nb] <= c.window).all(axis=1) & ~ap[oi]
            if c.point_share > 0 and new.any():
                pts = np.asarray(obstacle_points, np.float64).reshape(-1, 3)[on]
                new[new] = self._points_seen_free(oi[new], flat[on], pts, intr)
            ap[oi[new]] = True
            self.n_appeared += int(new.sum())
            self._live = np.union1d(self._live, oi[new])
        oa[oi] = view
        fa[free] = view
        if c.keep_views > 0 and c.point_share > 0:
            self._remember(d, T, intr)
        if c.keep_views > 0 and c.grow_share > 0 and len(oi) and cam_on[0]:
            self._grow(cam_ij[0])

    def _remember(self, depth: np.ndarray, T_world_cam: np.ndarray, intr: Intrinsics) -> None:
        """Keep this view for :meth:`_points_seen_free`: its depth with each pixel replaced by
        the nearest return within ``point_deg`` of it (no return there: 0)."""
        d = np.asarray(depth, np.float32)
        if self._past_depth is None or self._past_depth.shape[1:] != d.shape:
            self._past_depth = np.zeros((self.cfg.window + 1, *d.shape), np.float16)
            self._past_view[:] = -1
        r = int(np.ceil(max(intr.fx, intr.fy) * np.tan(np.deg2rad(self.cfg.point_deg))))
        near = np.where(np.isfinite(d) & (d > 0), d, np.inf).astype(np.float32)
        if r > 0:
            near = cv2.erode(near, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
        near[~np.isfinite(near)] = 0.0
        np.minimum(near, 1e4, out=near)  # float16 holds up to 65504 (MuJoCo's far plane may not)
        s = self.view % (self.cfg.window + 1)
        self._past_depth[s] = near
        self._past_T[s] = T_world_cam
        self._past_view[s] = self.view

    def _points_seen_free(
        self, cand: np.ndarray, flat: np.ndarray, points: np.ndarray, intr: Intrinsics
    ) -> np.ndarray:
        """(K,) bool for the candidate slabs ``cand`` (flat indices that passed the slab
        rule): whether this view's points in each (``points`` (N, 3) with slab indices
        ``flat``), projected into the view that last saw the slab free, were seen through at
        their own pixel: at least ``point_share`` of those that view framed, and at least
        ``point_min`` of them. A slab none of whose points that view framed (out of the
        image, behind the camera, under the robot's footprint, or a view no longer kept)
        passes: the slab rule's evidence stands.

        The slab rule tests the slab's centre. A desk or chair leg (4-5 cm) inside a 0.1 m
        cell is seen past on every side, so its cell and all 8 neighbours are seen free
        whenever D435i noise moves the leg's points along their rays into the next cell for a
        view; the next view's points there pass the slab rule. nav2-L1-005 (a static office):
        20 of the 24 appear events by step 320 lay at desk and chair legs, each expired 30
        views after it was last seen. The leg's own points, projected into that earlier view,
        land on the leg: the depth there is the leg's, not beyond it. The nearest depth within
        ``point_deg`` of the pixel absorbs the pose error between the two views; ``point_min``
        the single noisy point displaced along its ray off the leg as seen from the other
        view."""
        c = self.cfg
        sel = np.isin(flat, cand)
        P, f = points[sel], flat[sel]
        when = self.free_at.ravel()[f]
        framed = np.zeros(len(P), bool)
        through = np.zeros(len(P), bool)
        for u in np.unique(when):
            s = int(u) % (c.window + 1)
            if self._past_depth is None or self._past_view[s] != u:
                continue
            m = np.flatnonzero(when == u)
            z, px, py, fr = project_points(P[m], self._past_T[s], intr)
            meas = np.zeros(len(z))
            meas[fr] = self._past_depth[s][py[fr], px[fr]]
            framed[m] = fr
            through[m] = fr & beyond(meas, z, c.margin, c.margin_per_m2)
        pos = np.searchsorted(cand, f)  # cand is sorted (a subset of np.unique's output)
        n_framed = np.bincount(pos, weights=framed, minlength=len(cand))
        n_through = np.bincount(pos, weights=through, minlength=len(cand))
        return (n_framed == 0) | (
            (n_through >= c.point_share * n_framed) & (n_through >= c.point_min)
        )

    def _grow(self, centre: np.ndarray) -> None:
        """Blob growth around the camera's cell ``centre``: the slabs occupied within the last
        ``keep_views`` views form blobs (8-connected cells, any slab); where at least
        ``grow_share`` of a blob's slabs appeared, the rest appear too.

        The free-space test cannot judge every slab of a moving person: the slabs where they
        were first seen (at the edge of the mapped range, never in the test's reach while free)
        and those behind them (hidden by their own body) stay put. dyn-L2-003 (office_dynamic_v1):
        a person walking down the corridor towards the robot left 282 occupied slabs, of which
        152 appeared and expired; the other 130 closed the corridor on the map for the rest of
        the episode. A static object's blob has at most a few appeared slabs at its edge (the
        neighbour rule), far below the share; a blob joined to a wall is mostly wall."""
        c = self.cfg
        k = int(np.ceil(c.max_range / c.cell)) + 10
        i0, j0 = max(int(centre[0]) - k, 0), max(int(centre[1]) - k, 0)
        i1, j1 = min(int(centre[0]) + k + 1, self.n), min(int(centre[1]) + k + 1, self.n)
        recent = (self.view - self.occ_at[i0:i1, j0:j1]) <= c.keep_views
        ap = self.appeared[i0:i1, j0:j1]  # a view: writes reach self.appeared
        lab, m = ndimage.label(recent.any(axis=2), structure=np.ones((3, 3), bool))
        if m == 0:
            return
        L = np.broadcast_to(lab[..., None], recent.shape)
        tot = np.bincount(L[recent], minlength=m + 1)
        app = np.bincount(L[recent & ap], minlength=m + 1)
        grow = (app > 0) & (app >= c.grow_share * tot)
        grow[0] = False
        sel = recent & ~ap & grow[L]
        if not sel.any():
            return
        ap[sel] = True
        i, j, s = np.nonzero(sel)
        flat = ((i + i0) * self.n + (j + j0)) * c.n_heights + s
        self.n_grown += len(flat)
        self.n_appeared += len(flat)
        self._live = np.union1d(self._live, flat)

    def expired(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3, planning frame) in expired slabs (appeared and without
        an obstacle point for more than ``keep_views`` views)."""
        out = np.zeros(len(points), bool)
        if self.cfg.keep_views <= 0 or not len(points):
            return out
        flat, on = self._index(points)
        out[on] = self._expired_flat(flat[on])
        return out

    def appeared_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: the points (N, 3, planning frame) in appeared slabs, expired or not (what
        the static model leaves out: :attr:`ObstacleMap.static_safety`)."""
        out = np.zeros(len(points), bool)
        if self.cfg.keep_views <= 0 or not len(points):
            return out
        flat, on = self._index(points)
        out[on] = self.appeared.ravel()[flat[on]]
        return out

    def _expired_flat(self, flat: np.ndarray) -> np.ndarray:
        """(K,) bool: the slabs of flat indices ``flat`` that are expired (appeared, and without
        points for ``keep_views`` views or seen free since their last point)."""
        oa = self.occ_at.ravel()[flat]
        return self.appeared.ravel()[flat] & (
            (self.view - oa > self.cfg.keep_views) | (self.free_at.ravel()[flat] > oa)
        )

    def counts(self) -> tuple[int, int]:
        """(slabs appeared now, of them expired now)."""
        return len(self._live), int(self._expired_flat(self._live).sum())

    def expiring_now(self) -> bool:
        """Whether a slab expired at the last view (the models must be rebuilt to drop it)."""
        if self.cfg.keep_views <= 0:
            return False
        just = self.view - self.cfg.keep_views - 1
        return self._freed_now or bool(np.any(self.occ_at.ravel()[self._live] == just))
