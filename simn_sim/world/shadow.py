"""Occlusion shadows: space hidden behind seen obstacles counts as occupied until seen free.

A depth camera sees the near face of an obstacle, not its extent. A chair seen from behind
shows its back; the seat behind it is hidden at the camera's height (1.0 m, looking down),
and a collision model built from the seen points alone lets a path pass beside the back,
through the seat. Here each obstacle point ``p``, seen from the camera centre ``c``, casts a
shadow: along the horizontal direction from ``c`` through ``p``, from one cell behind ``p``
up to ``depth`` metres behind it, the part of each cell's column below the continued ray
(which descends from ``p``) is occluded. A column is sampled at fixed heights
(``heights``); a shadow cell *requires* the samples below the ray and in the robot's height
band, and is treated as occupied until every required sample has been *seen free*: a later
depth image measured a surface beyond it on the pixel it projects to (the projective
free-space test; by ``margin`` plus ``margin_per_m2`` x depth^2 for stereo noise).

A floor observation does not clear a shadow: the floor under a chair's seat is visible from
afar through the legs, while the seat stays hidden behind the back. Cells the robot's own
footprint has covered, and cells cleared by free-space evidence, are known free (``free``)
and never become shadow again: the scene is assumed static.

Cells are keyed on a fixed grid of edge ``resolution`` in the planning frame (x-y, z up) and
kept as sorted unique int64 keys with per-cell bit masks (required / seen heights), so all
updates are vectorised ``numpy`` set operations.
"""

from __future__ import annotations

import numpy as np

from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.se3 import inv_T, transform_points

_BITS = 31
_OFF = 1 << (_BITS - 1)


def _pack(ij: np.ndarray) -> np.ndarray:
    return ((ij[:, 0] + _OFF) << _BITS) | (ij[:, 1] + _OFF)


def _unpack(keys: np.ndarray) -> np.ndarray:
    return np.stack([(keys >> _BITS) - _OFF, (keys & ((1 << _BITS) - 1)) - _OFF], 1)


def _check_points(p: np.ndarray, name: str, dim: int) -> np.ndarray:
    a = np.asarray(p, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] < dim:
        raise ValueError(f"{name}: expected an (N, {dim}) array, got shape {a.shape}")
    if not np.all(np.isfinite(a[:, :dim])):
        raise ValueError(f"{name}: non-finite coordinates")
    return a[:, :dim]


def project_points(
    P: np.ndarray, T_world_cam: np.ndarray, intr: Intrinsics
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Camera depth z (N,), pixel column u and row v (N,) of world points ``P`` (N, 3) seen
    from ``T_world_cam``, and the (N,) mask of those that project into the image at least
    0.1 m in front of the camera."""
    pc = transform_points(inv_T(T_world_cam), P)
    z = pc[:, 2]
    front = z > 0.1
    zz = np.where(front, z, 1.0)
    u = np.round(intr.fx * pc[:, 0] / zz + intr.cx).astype(np.int64)
    v = np.round(intr.fy * pc[:, 1] / zz + intr.cy).astype(np.int64)
    return z, u, v, front & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)


def seen_through(
    P: np.ndarray,
    T_world_cam: np.ndarray,
    depth: np.ndarray,
    intr: Intrinsics,
    margin: float,
    margin_per_m2: float,
) -> np.ndarray:
    """(N,) bool: the projective free-space test of world points ``P`` (N, 3): each projects
    into ``depth`` (H, W, metres, 0 or NaN: no return; intrinsics ``intr``) at least 0.1 m in
    front of the camera, and the measured depth lies beyond it by ``margin`` +
    ``margin_per_m2`` x depth^2."""
    z, u, v, ok = project_points(P, T_world_cam, intr)
    meas = np.zeros(len(z))
    meas[ok] = depth[v[ok], u[ok]]
    return ok & beyond(meas, z, margin, margin_per_m2)


def beyond(meas: np.ndarray, z: np.ndarray, margin: float, margin_per_m2: float) -> np.ndarray:
    """(N,) bool: measured depths ``meas`` lie beyond depths ``z`` by ``margin`` +
    ``margin_per_m2`` x z^2 (the stereo noise grows with depth^2); NaN is not beyond."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(meas) & (meas > z + margin + margin_per_m2 * z**2)


def below_top_contour(depth: np.ndarray, jump: float, half_width: int = 3) -> np.ndarray:
    """(H, W) bool: pixels on a surface whose top is in view. Each image column is cut into
    segments where the depth changes by more than ``jump`` metres between adjacent rows; a
    segment has a visible top when the pixel above its first row is farther by more than
    ``jump`` (or has no return). A chair back, a box or a table edge has one; a wall, a door
    jamb or a tall shelf reaches the top of the image (the camera sees nothing above 1 m), so
    the space behind it is a room, not more of the same object, and it casts no shadow.

    A top contour must be horizontal over ``half_width`` pixels to each side (all the pixels
    above them are farther): with the camera pitched down, a vertical edge such as a door
    jamb projects as a slanted line, which a column crosses from the wall to the room behind
    it, but its neighbours on the wall side do not."""
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {d.shape}")
    if not (np.isfinite(jump) and jump > 0) or half_width < 0:
        raise ValueError(
            f"below_top_contour: jump must be > 0 and half_width >= 0, got {jump}, {half_width}"
        )
    valid = np.isfinite(d) & (d > 0)
    dd = np.where(valid, d, np.inf)  # no return: infinitely far
    with np.errstate(invalid="ignore"):
        diff = dd[1:] - dd[:-1]  # this row minus the row above; inf - inf = nan: no break
        brk = np.zeros(d.shape, bool)
        brk[1:] = np.abs(diff) > jump
        # nearest of the pixels above within +-half_width columns
        # beyond the image's sides counts as near: a contour there cannot be checked
        # (a running minimum over the 2 half_width + 1 shifted copies: the same values as a
        # min over a sliding-window view, about 5x faster)
        pad = np.pad(dd[:-1], ((0, 0), (half_width, half_width)), constant_values=0.0)
        w = d.shape[1]
        above_min = pad[:, :w].copy()
        for s in range(1, 2 * half_width + 1):
            np.minimum(above_min, pad[:, s : s + w], out=above_min)
        top = np.zeros(d.shape, bool)
        top[1:] = brk[1:] & (above_min - dd[1:] > jump)  # the row above is farther throughout
    rows = np.arange(d.shape[0])[:, None]
    start = np.maximum.accumulate(np.where(brk, rows, 0), axis=0)
    return valid & np.take_along_axis(top, start, axis=0)


def may_continue_below_view(
    depth: np.ndarray,
    intr: Intrinsics,
    T_world_cam: np.ndarray,
    rows: int,
    step: int,
    jump: float,
    max_slope_deg: float = 60.0,
) -> np.ndarray:
    """(H, W) bool: pixels in the image's bottom ``rows`` rows whose surface may go on towards
    the camera beneath the view (a box top or a seat seen up to the image's lower border).
    Only a surface seen to be vertical is ruled out: a wall or a box's side ends where it is
    seen. A pixel is on a vertical surface when the pixel ``step`` rows above it in the same
    column is on the same surface (depth within ``jump`` metres) and, both back-projected into
    the planning frame (z up), the height between them changes by more than
    tan(``max_slope_deg``) x the change of horizontal range. A pixel whose neighbour above is
    farther by more than ``jump`` (a top edge: a thin sliver of a top is all that is in view)
    or has no return may continue."""
    d = np.asarray(depth, dtype=np.float64)
    if d.shape != (intr.height, intr.width):
        raise ValueError(
            f"depth shape {d.shape} does not match the intrinsics ({intr.height}, {intr.width})"
        )
    H, W = d.shape
    if not (step >= 1 and 1 <= rows <= H - step):
        raise ValueError(
            f"may_continue_below_view: need step >= 1 and 1 <= rows <= H - step, got {rows}, {step}"
        )
    T = np.asarray(T_world_cam, dtype=np.float64)
    # the bottom rows and the rows ``step`` above them, back-projected in one band
    v0 = H - rows - step
    band_intr = Intrinsics(W, rows + step, intr.fx, intr.fy, intr.cx, intr.cy - v0)
    Pc = backproject(d[v0:], band_intr).reshape(-1, 3).astype(np.float64)
    band = transform_points(T, Pc).reshape(rows + step, W, 3)
    lo, hi = band[step:], band[:rows]
    zl, zh = d[H - rows :], d[v0 : H - step]
    cam = T[:2, 3]
    dr = np.abs(
        np.hypot(hi[..., 0] - cam[0], hi[..., 1] - cam[1])
        - np.hypot(lo[..., 0] - cam[0], lo[..., 1] - cam[1])
    )
    dz = np.abs(hi[..., 2] - lo[..., 2])
    valid = np.isfinite(zl) & (zl > 0)
    same = valid & np.isfinite(zh) & (zh > 0) & (np.abs(zh - zl) <= jump)
    vertical = same & (dz > np.tan(np.radians(max_slope_deg)) * dr)
    out = np.zeros((H, W), bool)
    out[H - rows :] = valid & ~vertical
    return out


class OcclusionShadow:
    """Shadow cells behind observed obstacle points, with per-height free-space evidence."""

    def __init__(
        self,
        resolution: float,
        depth: float,
        heights: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9),
        margin: float = 0.05,
        margin_per_m2: float = 0.01,
        max_range: float = 4.0,
    ) -> None:
        if not (np.isfinite(resolution) and resolution > 0):
            raise ValueError(f"OcclusionShadow.resolution must be > 0, got {resolution}")
        if not (np.isfinite(depth) and depth >= resolution):
            raise ValueError(
                f"OcclusionShadow.depth must be >= resolution ({resolution}), got {depth}"
            )
        h = np.asarray(heights, dtype=np.float64)
        if h.ndim != 1 or not 1 <= len(h) <= 8 or not np.all(np.isfinite(h)):
            raise ValueError(f"OcclusionShadow.heights must be 1-8 finite values, got {heights}")
        if not (margin > 0 and margin_per_m2 >= 0 and max_range > 0):
            raise ValueError(
                "OcclusionShadow: margin must be > 0, margin_per_m2 >= 0, max_range > 0"
            )
        self.resolution = float(resolution)
        self.depth = float(depth)
        self.heights = np.sort(h)
        self.margin, self.margin_per_m2, self.max_range = margin, margin_per_m2, max_range
        # along-ray sample spacing: half a cell, so a ray crossing cells diagonally hits each
        self._t = np.arange(self.resolution, self.depth + 1e-9, 0.5 * self.resolution)
        self.shadow = np.zeros(0, np.int64)  # active shadow cells (sorted keys)
        self.required = np.zeros(0, np.uint8)  # per cell: bit k = height k is occluded
        self.seen = np.zeros(0, np.uint8)  # per cell: bit k = height k was seen free since
        # cells known free: covered by the robot's footprint, or every occluded height seen
        # through; they never become shadow again (the scene is assumed static)
        self.free = np.zeros(0, np.int64)
        self.cleared = 0  # shadow cells cleared by free-space evidence (cumulative)

    def __len__(self) -> int:
        return len(self.shadow)

    def keys(self, xy: np.ndarray) -> np.ndarray:
        """Sorted unique cell keys of (N, 2+) points."""
        ij = np.floor(_check_points(xy, "xy", 2) / self.resolution).astype(np.int64)
        return np.unique(_pack(ij))

    def centres(self, keys: np.ndarray | None = None) -> np.ndarray:
        """(N, 2) cell centres of ``keys`` (default: the active shadow cells)."""
        k = self.shadow if keys is None else keys
        return (_unpack(k).astype(np.float64) + 0.5) * self.resolution

    # ------------------------------------------------------------------ updates
    def traverse(self, xy: np.ndarray, radius: float) -> int:
        """The robot's footprint (a disk of ``radius`` at ``xy``) is free space: its cells stop
        being shadow and never become shadow again. Returns the number of cells cleared."""
        c = np.asarray(xy, dtype=np.float64).reshape(-1)[:2]
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"xy must be a finite (x, y), got {xy}")
        r = self.resolution
        n = int(np.ceil(radius / r))
        g = np.arange(-n, n + 1) * r
        gx, gy = np.meshgrid(g, g)
        off = np.stack([gx.ravel(), gy.ravel()], 1)
        ij = np.floor((c + off) / r).astype(np.int64)
        ctr = (ij + 0.5) * r
        inside = np.hypot(*(ctr - c).T) <= radius
        k = np.unique(_pack(ij[inside]))
        self.free = np.union1d(self.free, k)
        return self._drop(np.isin(self.shadow, k, assume_unique=True))

    def observe(
        self,
        obstacle_points: np.ndarray,
        T_world_cam: np.ndarray,
        depth: np.ndarray,
        intr: Intrinsics,
    ) -> tuple[np.ndarray, int]:
        """Add one depth view. ``obstacle_points``: (N, 3) obstacle points of this view in the
        planning frame (z up); ``T_world_cam``: (4, 4) planning frame <- OpenCV camera;
        ``depth``: (H, W) metres (0 = no return) with intrinsics ``intr``. First the view's
        free space is tested against the existing shadow cells, then its obstacle points cast
        new shadow. Returns the keys of the cells that became shadow and the number cleared."""
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_world_cam must be a finite (4, 4) pose, got shape {T.shape}")
        d = np.asarray(depth)
        if d.shape != (intr.height, intr.width):
            raise ValueError(
                f"depth shape {d.shape} does not match the intrinsics ({intr.height}, {intr.width})"
            )
        n_cleared = self._see_free(T, d, intr)
        new = self._cast(_check_points(obstacle_points, "obstacle_points", 3), T[:3, 3])
        return new, n_cleared

    def _drop(self, mask: np.ndarray) -> int:
        n = int(mask.sum())
        if n:
            keep = ~mask
            self.shadow, self.required, self.seen = (
                self.shadow[keep],
                self.required[keep],
                self.seen[keep],
            )
        return n

    def _see_free(self, T: np.ndarray, depth: np.ndarray, intr: Intrinsics) -> int:
        """Projective free-space test of the open (required, not yet seen) column samples."""
        if not len(self.shadow):
            return 0
        ctr = self.centres()
        near = np.hypot(*(ctr - T[:2, 3]).T) <= self.max_range
        open_bits = self.required & ~self.seen
        idx = np.flatnonzero(near & (open_bits != 0))
        if not len(idx):
            return 0
        nh = len(self.heights)
        bit = (open_bits[idx, None] >> np.arange(nh, dtype=np.uint8)) & 1
        ci, hk = np.nonzero(bit)
        P = np.column_stack([ctr[idx[ci]], self.heights[hk]])
        through = seen_through(P, T, depth, intr, self.margin, self.margin_per_m2)
        if through.any():
            add = np.zeros(len(self.shadow), np.uint8)
            np.bitwise_or.at(add, idx[ci[through]], (1 << hk[through]).astype(np.uint8))
            self.seen |= add
        done = (self.required & ~self.seen) == 0
        if done.any():
            self.free = np.union1d(self.free, self.shadow[done])
        n = self._drop(done)
        self.cleared += n
        return n

    def _cast(self, p: np.ndarray, cam: np.ndarray) -> np.ndarray:
        """Shadow of obstacle points ``p`` (N, 3) seen from ``cam`` (3,): new cell keys."""
        if not len(p):
            return np.zeros(0, np.int64)
        # per cell only the highest point matters: its continued ray lies above those of the
        # lower points of the column at every distance behind, so its shadow contains theirs
        pk = _pack(np.floor(p[:, :2] / self.resolution).astype(np.int64))
        order = np.lexsort((p[:, 2], pk))
        last = np.r_[pk[order][1:] != pk[order][:-1], True]
        obstacle_cells = pk[order][last]  # sorted unique
        p = p[order][last]
        dxy = p[:, :2] - cam[:2]
        r = np.linalg.norm(dxy, axis=1)
        ok = (r > 1e-6) & (p[:, 2] < cam[2])  # points above the camera hide nothing below
        if not ok.any():
            return np.zeros(0, np.int64)
        p, dxy, r = p[ok], dxy[ok], r[ok]
        u = dxy / r[:, None]
        slope = (cam[2] - p[:, 2]) / r  # height the continued ray loses per metre
        h_ray = p[:, 2, None] - slope[:, None] * self._t[None, :]
        below = self.heights[None, None, :] <= h_ray[..., None]  # (N, T, H)
        mask = (below * (1 << np.arange(len(self.heights)))[None, None, :]).sum(-1)
        sel = mask > 0
        if not sel.any():
            return np.zeros(0, np.int64)
        # one representative per cell: three parallel rays across the cell's width (offsets
        # -1/2, 0, +1/2 cell perpendicular to the ray) so neighbouring cells' shadows join
        nrm = np.stack([-u[:, 1], u[:, 0]], 1)
        xy = p[:, None, :2] + u[:, None, :] * self._t[None, :, None]  # (N, T, 2)
        xy = (
            xy[None]
            + (np.array([-0.5, 0.0, 0.5]) * self.resolution)[:, None, None, None]
            * (nrm[None, :, None, :])
        )  # (3, N, T, 2)
        ij = np.floor(xy[:, sel] / self.resolution).astype(np.int64).reshape(-1, 2)
        return self._merge(_pack(ij), np.tile(mask[sel].astype(np.uint8), 3), obstacle_cells)

    def cast_below_view(
        self,
        points: np.ndarray,
        T_world_cam: np.ndarray,
        intr: Intrinsics,
        depth: float,
        height_tol: float = 0.05,
    ) -> np.ndarray:
        """Blind-zone shadow of obstacle points ``points`` (N, 3, planning frame) that lie at
        the bottom edge of the view on a surface not seen to be vertical
        (``may_continue_below_view``): a box top or a seat seen up to the image's lower border
        may go on towards the camera
        beneath the view, where the camera cannot see it from here (a 0.34 m box is out of
        view within about 0.65 m of a camera at 1.0 m pitched down 24 deg). Along the
        horizontal direction from each point towards the camera, up to ``depth`` metres, the
        column samples at heights up to the point's own (+ ``height_tol``) that project below
        the image's lower border (or behind the camera) become required shadow samples; samples
        in view are not (this image shows what is there). They clear like occlusion shadows:
        once a later view sees through them, or the robot's footprint covers them. Returns the
        keys of the new shadow cells."""
        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_world_cam must be a finite (4, 4) pose, got shape {T.shape}")
        if not (np.isfinite(depth) and depth >= self.resolution):
            raise ValueError(f"cast_below_view: depth must be >= {self.resolution}, got {depth}")
        p = _check_points(points, "points", 3)
        if not len(p):
            return np.zeros(0, np.int64)
        pk = _pack(np.floor(p[:, :2] / self.resolution).astype(np.int64))
        obstacle_cells = np.unique(pk)
        cam = T[:3, 3]
        dxy = p[:, :2] - cam[:2]
        r = np.linalg.norm(dxy, axis=1)
        ok = r > self.resolution
        if not ok.any():
            return np.zeros(0, np.int64)
        p, dxy, r = p[ok], dxy[ok], r[ok]
        u = dxy / r[:, None]
        t = np.arange(self.resolution, depth + 1e-9, 0.5 * self.resolution)
        tt = np.minimum(t[None, :], r[:, None])  # never past the camera
        xy = p[:, None, :2] - u[:, None, :] * tt[..., None]  # (N, T, 2) towards the camera
        nh = len(self.heights)
        P = np.concatenate(
            [
                np.broadcast_to(xy[:, :, None, :], (*xy.shape[:2], nh, 2)),
                np.broadcast_to(self.heights[None, None, :, None], (*xy.shape[:2], nh, 1)),
            ],
            axis=-1,
        ).reshape(-1, 3)
        pc = transform_points(inv_T(T), P)
        z = pc[:, 2]
        v = intr.fy * pc[:, 1] / np.where(z > 1e-6, z, 1.0) + intr.cy
        hidden = (z <= 1e-6) | (v > intr.height - 0.5)
        hidden = hidden.reshape(len(p), len(t), nh)
        hidden &= self.heights[None, None, :] <= p[:, 2, None, None] + height_tol
        mask = (hidden * (1 << np.arange(nh))[None, None, :]).sum(-1)
        sel = mask > 0
        if not sel.any():
            return np.zeros(0, np.int64)
        ij = np.floor(xy[sel] / self.resolution).astype(np.int64)
        return self._merge(_pack(ij), mask[sel].astype(np.uint8), obstacle_cells)

    def _merge(self, k: np.ndarray, m: np.ndarray, obstacle_cells: np.ndarray) -> np.ndarray:
        """Add cells ``k`` with required-height masks ``m`` (OR-ed per cell), except obstacle
        cells and known-free cells; returns the keys of the cells that are new."""
        order = np.argsort(k, kind="stable")
        k, m = k[order], m[order]
        uk, start = np.unique(k, return_index=True)
        um = np.bitwise_or.reduceat(m, start)
        # not in the obstacle points' own cells (they are obstacles) or in known-free cells
        excl = np.union1d(obstacle_cells, self.free)
        keep = ~np.isin(uk, excl, assume_unique=True)
        uk, um = uk[keep], um[keep]
        pos = np.searchsorted(self.shadow, uk)
        pos_c = np.minimum(pos, max(len(self.shadow) - 1, 0))
        exists = (
            (pos < len(self.shadow)) & (self.shadow[pos_c] == uk)
            if len(self.shadow)
            else (np.zeros(len(uk), bool))
        )
        if exists.any():  # more of an existing cell's column may be occluded now
            self.required[pos[exists]] |= um[exists]
        new, nm = uk[~exists], um[~exists]
        if len(new):
            allk = np.concatenate([self.shadow, new])
            order = np.argsort(allk, kind="stable")
            self.shadow = allk[order]
            self.required = np.concatenate([self.required, nm])[order]
            self.seen = np.concatenate([self.seen, np.zeros(len(new), np.uint8)])[order]
        return new
