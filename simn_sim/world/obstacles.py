"""The planner's view of a world model: occupancy for planning and safety, soft shadows, bumps.

:class:`ObstacleMap` holds three :class:`~simn_sim.planning.collision.CollisionChecker` s over
the same obstacle points: ``planning`` (robot radius + margin), ``safety`` (radius + at most
3 cm: the follower's blocked check and the recovery trigger, so a path that grazes the planning
margin does not make the robot dither at the margin's edge) and ``shadows``, the cells that
may hide an obstacle (:mod:`simn_sim.world.shadow`): plans are pushed away from them where there
is room, they never block a plan. Bump points (an obstacle the base ran into but the camera did
not see) are kept across rebuilds. Unknown space is free.

With transient cells on, a fourth, ``static_safety`` (kept only after :meth:`ObstacleMap.keep_static`),
is the safety model without the points in appeared slabs (what moved into space seen free:
people): the cost-to-go map may price a route through them instead of closing it
(``costmap.transient_weight``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import transform_points
from simn_sim.planning import CollisionChecker, CollisionConfig
from simn_sim.semantics import OBSTACLE
from simn_sim.slam.frames import LocalFrames
from simn_sim.world.shadow import OcclusionShadow, below_top_contour, may_continue_below_view
from simn_sim.world.transient import TransientCells, TransientConfig


@dataclasses.dataclass(frozen=True)
class ObstacleConfig(Config):
    """collision: the planning model (the safety model uses min(3 cm, margin)).
    rebuild_every: control steps between rebuilds of the models from the local frames' stores
    (which drop points seen through: no ghosts); anchors moved by the pose graph also rebuild.
    shadow_depth: occlusion shadows, the space up to this far (m) behind each seen obstacle
    point below its continued camera ray (a chair seen from behind hides its seat); 0: off.
    shadow_range: only obstacle points within this horizontal range (m) of the camera cast.
    shadow_edge_jump: only points of surfaces whose top edge is in view cast (contours are depth
    jumps above this, m): walls and door jambs do not. blind_shadow_depth: an obstacle point at
    the image's lower border, unless on a surface seen to be vertical, may go on towards the
    camera beneath the view; the hidden space up to this far (m) is shadow too; 0: off.
    bump_ttl: views after which a bump's points leave the models; 0: never. transient:
    obstacles that appear in space seen free (a person walking through a doorway) leave the
    models after ``transient.keep_views`` views unseen (:mod:`simn_sim.world.transient`);
    30 by default (0: off)."""

    collision: CollisionConfig = CollisionConfig(margin=0.1, z_min=0.06, z_max=1.0)
    rebuild_every: int = 20
    shadow_depth: float = 0.3
    shadow_range: float = 1.5
    shadow_edge_jump: float = 0.15
    blind_shadow_depth: float = 0.6
    # a bump's arc of points is dropped from the models after this many views (a bump at a
    # door jamb otherwise closes the doorway for good); 0: kept for the episode
    bump_ttl: int = 300
    transient: TransientConfig = TransientConfig(keep_views=30)

    def validate(self) -> None:
        n = type(self).__name__
        res = self.collision.resolution
        require(self.rebuild_every >= 1, n, "rebuild_every", "must be >= 1")
        for f in ("shadow_depth", "blind_shadow_depth"):
            v = getattr(self, f)
            require(
                v == 0 or v >= res,
                n,
                f,
                f"must be 0 (off) or >= the collision resolution ({res} m)",
            )
        require(self.shadow_range > 0, n, "shadow_range", "must be > 0")
        require(self.shadow_edge_jump > 0, n, "shadow_edge_jump", "must be > 0")
        require(self.bump_ttl >= 0, n, "bump_ttl", "must be >= 0 (0: kept)")


class ObstacleMap:
    """See the module docstring."""

    def __init__(self, cfg: ObstacleConfig) -> None:
        self.cfg = cfg
        c = cfg.collision
        self.planning = CollisionChecker(c)
        self.safety = CollisionChecker(c.replace(margin=min(0.03, c.margin)))
        self.shadow = (
            OcclusionShadow(c.resolution, cfg.shadow_depth) if cfg.shadow_depth > 0 else None
        )
        self._shadow_map = CollisionChecker(c) if self.shadow is not None else None
        self._shadow_dirty = False  # shadow cells were cleared since the shadow model was built
        self.transient = (
            TransientCells(cfg.transient, (c.z_min, c.z_max), c.robot_radius)
            if cfg.transient.keep_views > 0
            else None
        )
        # kept only when asked for (:meth:`keep_static`)
        self.static_safety: CollisionChecker | None = None
        self.bump_points: list[np.ndarray] = []
        self._bump_views: list[int] = []  # the view count when each bump was added
        self._views = 0  # views integrated (the rebuild schedule)
        self._anchors_version = 0  # of the local frames at the last rebuild
        # local frames with a lower id are left out of the models (:meth:`forget`)
        self.min_frame = 0
        self._forgot = False  # rebuild at the next view
        self.clears = 0

    # ---- obstacles ---------------------------------------------------------------------------
    def add(self, points: np.ndarray, appeared: np.ndarray | None = None) -> None:
        """Add (N, 3) obstacle points (agent frame) to the planning and safety models (and to
        the static model those outside appeared transient slabs; ``appeared``: (N,) bool, which
        are in one, when not the slabs at ``points``)."""
        if len(points):
            lab = np.full(len(points), OBSTACLE, np.int8)
            self.planning.update(points, lab)
            self.safety.update(points, lab)
            if self.static_safety is not None:
                if appeared is None:
                    appeared = self.transient.appeared_at(points)
                keep = ~appeared
                self.static_safety.update(points[keep], lab[keep])

    def keep_static(self) -> None:
        """Keep ``static_safety`` from now on (a no-op without transient cells). Its upkeep
        costs about half of :meth:`add` again, so only the cost map's transient pricing asks
        for it; asked after views were integrated, the next view rebuilds all models."""
        if self.transient is None or self.static_safety is not None:
            return
        self.static_safety = CollisionChecker(self.safety.cfg)
        self._forgot |= self._views > 0

    def model_points(self, frames: LocalFrames) -> np.ndarray:
        """(N, 3) the points the models are built from: the obstacle points of the local frames
        from ``min_frame`` on (world coordinates) but those in expired transient cells, plus
        the bump points."""
        return self._model_points(frames)[0]

    def _model_points(self, frames: LocalFrames) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`model_points` and which of them lie in appeared transient slabs (None: judge
        them where they are). With ``transient.follow_points`` a stored point is judged in the
        slab it was observed in (:meth:`LocalFrames.obstacle_points_observed`), not the one
        its frame's current anchor puts it in."""
        pts = frames.obstacle_points_world(self.min_frame)
        appeared = None
        if self.transient is not None:
            tc = self.transient
            at = frames.obstacle_points_observed(self.min_frame) if tc.cfg.follow_points else pts
            keep = ~tc.expired(at)
            pts = pts[keep]
            if tc.cfg.follow_points and self.static_safety is not None:
                appeared = tc.appeared_at(at[keep])
        if self.bump_points:
            bumps = np.concatenate(self.bump_points)
            pts = np.concatenate([pts, bumps])
            if appeared is not None:
                appeared = np.concatenate([appeared, tc.appeared_at(bumps)])
        return pts, appeared

    def rebuild(self, frames: LocalFrames) -> None:
        """Both models anew from :meth:`model_points` (bumps older than ``bump_ttl`` views
        dropped first)."""
        ttl = self.cfg.bump_ttl
        if ttl > 0 and self._bump_views and self._views - self._bump_views[0] >= ttl:
            keep = [k for k, v in enumerate(self._bump_views) if self._views - v < ttl]
            self.bump_points = [self.bump_points[k] for k in keep]
            self._bump_views = [self._bump_views[k] for k in keep]
        self.planning.reset()
        self.safety.reset()
        if self.static_safety is not None:
            self.static_safety.reset()
        self.add(*self._model_points(frames))

    def forget(self, min_frame: int) -> None:
        """Clear the map, as a recovery (the clear-costmap recovery of ROS navigation): from the
        next view on, the models hold only the obstacle points of the local frames with id >=
        ``min_frame``; bump points are dropped. Old frames stay in the topological map (for
        tracking and revisits) and their floor stays known; what they held as obstacles is
        seen again, by the frames that see it next. For a map whose old frames disagree (a
        doorway closed by a copy of its jamb from a frame anchored a few cm off)."""
        self.min_frame = max(self.min_frame, int(min_frame))
        self.bump_points, self._bump_views = [], []
        self._forgot = True
        self.clears += 1

    def add_bump(self, T_world_base: np.ndarray, robot_radius: float, angle: float = 0.0) -> None:
        """An obstacle at the hull that the camera cannot see: an arc of points 80 deg wide
        centred on ``angle`` (rad, base frame: 0 is straight ahead)."""
        a = angle + np.radians(np.linspace(-40, 40, 9))
        r = robot_radius + 0.03
        local = np.c_[r * np.cos(a), r * np.sin(a), np.full_like(a, 0.3)]
        pts = transform_points(T_world_base, local)
        self.bump_points.append(pts)
        self._bump_views.append(self._views)
        self.add(pts)

    # ---- shadows -----------------------------------------------------------------------------
    def shadow_model(self) -> CollisionChecker | None:
        """The shadow cells' obstacle model (None: shadows off), rebuilt first if cells were
        cleared since."""
        if self._shadow_map is not None and self._shadow_dirty:
            self._shadow_map.reset()
            self._shadow_dirty = False
            self.add_shadow(self.shadow.shadow)
        return self._shadow_map

    def add_shadow(self, keys: np.ndarray) -> None:
        if self._shadow_map is None or not len(keys):
            return
        c = self.cfg.collision
        xy = self.shadow.centres(keys)
        z = np.full((len(xy), 1), 0.5 * (c.z_min + c.z_max))
        self._shadow_map.update(np.hstack([xy, z]), np.full(len(xy), OBSTACLE, np.int8))

    def observe_shadow(
        self,
        obstacle_points: np.ndarray,
        T_wc: np.ndarray,
        base_xy: np.ndarray,
        depth: np.ndarray,
        intr: Intrinsics,
        pixels: np.ndarray,
    ) -> np.ndarray:
        """Feed one view to the shadows; returns the keys of the new shadow cells.

        obstacle_points: (N, 3) this view's obstacle points (agent frame); pixels: (N, 2) their
        (row, column) in ``depth`` (the strided depth image, ``intr`` its intrinsics)."""
        if self.shadow is None:
            return np.zeros(0, np.int64)
        cfg, c = self.cfg, self.cfg.collision
        in_z = (obstacle_points[:, 2] >= c.z_min) & (obstacle_points[:, 2] <= c.z_max)
        band = in_z & (np.hypot(*(obstacle_points[:, :2] - T_wc[:2, 3]).T) <= cfg.shadow_range)
        if band.any():  # the top contours only matter for points that may cast
            hw = max(1, round(3 * depth.shape[1] / 320))
            topped = below_top_contour(depth, cfg.shadow_edge_jump, hw)
            band &= topped[pixels[:, 0], pixels[:, 1]]
        n_cleared = self.shadow.traverse(base_xy, c.robot_radius)
        new, n_seen = self.shadow.observe(obstacle_points[band], T_wc, depth, intr)
        self._shadow_dirty |= n_cleared + n_seen > 0
        if cfg.blind_shadow_depth > 0 and len(obstacle_points):
            H = depth.shape[0]
            rows = max(2, math.ceil(0.02 * H))  # the bottom 2 % of the image
            bottom = in_z & (pixels[:, 0] >= H - rows)
            if bottom.any():
                step = max(2, round(0.01 * H))
                cont = may_continue_below_view(depth, intr, T_wc, rows, step, cfg.shadow_edge_jump)
                sel = np.flatnonzero(bottom)
                sel = sel[cont[pixels[sel, 0], pixels[sel, 1]]]
                if len(sel):
                    blind = self.shadow.cast_below_view(
                        obstacle_points[sel], T_wc, intr, cfg.blind_shadow_depth
                    )
                    new = np.union1d(new, blind)
        return new

    def integrate(
        self,
        obstacle_points: np.ndarray,
        pixels: np.ndarray,
        T_wc: np.ndarray,
        base_xy: np.ndarray,
        depth: np.ndarray,
        intr: Intrinsics,
        frames: LocalFrames,
    ) -> None:
        """One view: shadows, then the view's obstacle points added, or, every ``rebuild_every``
        views and whenever the pose graph moved the anchors, both models rebuilt from the local
        frames' stores (which drop points seen through: no ghosts)."""
        new_shadow = self.observe_shadow(obstacle_points, T_wc, base_xy, depth, intr, pixels)
        expiring = False
        if self.transient is not None:
            c = self.cfg.collision
            z = obstacle_points[:, 2]
            band = obstacle_points[(z >= c.z_min) & (z <= c.z_max)]
            self.transient.observe(band, T_wc, base_xy, depth, intr)
            expiring = self.transient.expiring_now()
        moved = frames.anchors_version != self._anchors_version
        if moved or expiring or self._forgot or self._views % self.cfg.rebuild_every == 0:
            self._anchors_version = frames.anchors_version
            self._forgot = False
            self.rebuild(frames)
        else:
            self.add(obstacle_points)
        self.add_shadow(new_shadow)
        self._views += 1
