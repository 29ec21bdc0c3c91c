"""``simn`` and ``rrtstar`` agents: the SIMN pipeline in the closed loop.

One control step (``act``), all in the agent's own frame (the episode's start frame, z up, the
floor at z = 0; the goal and the odometry arrive in it):

1. pose prior: the wheel-odometry increment applied to the previous estimate;
2. ``pose_source="slam"``: :class:`~simn_sim.slam.pipeline.SimnSlam` registers the frame to the
   current local frame's implicit map, trains it, opens local frames, grows the topological map
   and closes loops; ``"odometry"``: the prior is used as is (ablation);
3. semantics: the frame's points (pixel stride ``obstacle_stride``) are labelled floor /
   obstacle with the geometric classifier (floor plane z = 0 known from the camera mount);
4. collision model: obstacle points within the robot's height band go into the shared
   :class:`~simn_sim.planning.collision.CollisionChecker` (unknown space is free);
5. planning: topological guidance (a sub-goal on the route over the topological map when the goal
   lies beyond the current local frame), then goal-vector RRT* (``simn``) or uniform RRT*
   (``rrtstar``) on a replanning schedule, or when the follower reports the path blocked or stale;
6. control: pure pursuit -> ``[v, w]`` within the env's action bounds.

The agent never reads the true pose. A failed plan or a lost track does not end the episode:
the agent reports its state (``state()``) and keeps acting (turning in place to look around when
it has no plan).
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Literal

import numpy as np

from simn_sim.agents.base import register_agent
from simn_sim.agents.shadow import OcclusionShadow, below_top_contour, may_continue_below_view
from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.se3 import inv_T, orthonormalize, planar_T, transform_points, yaw_of
from simn_sim.planning import (
    CollisionChecker,
    CollisionConfig,
    FollowerConfig,
    GoalVectorConfig,
    PathFollower,
    RRTStarConfig,
    goal_vector_rrt_star,
    uniform_rrt_star,
)
from simn_sim.planning.gridpath import grid_shortest_path
from simn_sim.planning.smoothing import push_from_obstacles
from simn_sim.semantics import FLOOR, OBSTACLE


@dataclasses.dataclass(frozen=True)
class SimnAgentConfig(Config):
    planner: Literal["goal_vector", "uniform"] = "goal_vector"
    # "slam" (the method): SimnSlam tracks every frame against the current local frame's map,
    # opens local frames, grows the topological map and closes loops; the collision model is
    # built from the local frames' obstacle stores and topological guidance picks sub-goals.
    # "odometry": the wheel-odometry pose and one accumulated obstacle map (ablation).
    pose_source: Literal["slam", "odometry"] = "slam"
    obstacle_stride: int = 4  # pixel stride of the points that feed the collision model
    obstacle_max_depth: float = 3.5  # farther points are noisier (D435i error grows with z^2)
    floor_tolerance: float = 0.06  # |z| below this is floor (at zero range) ...
    floor_tolerance_per_m2: float = 0.01  # ... plus this x range^2 (stereo error grows with z^2)
    robot_height: float = 1.0  # points above this do not hit the base
    collision: CollisionConfig = CollisionConfig(margin=0.1, z_min=0.06, z_max=1.0)
    # iteration budget only (no wall-clock budget): the same seed gives the same plans
    rrt: RRTStarConfig = RRTStarConfig(time_budget_ms=0.0, max_iterations=600)
    goal_vector: GoalVectorConfig = GoalVectorConfig()
    # turn in place while the path bearing exceeds 30 deg (about the camera's half horizontal
    # field of view at 320x240): the robot drives only towards space it has in view
    follower: FollowerConfig = FollowerConfig(
        lookahead=0.5,
        v_max=0.8,
        goal_tolerance=0.15,
        slow_clearance=0.3,
        min_clearance_scale=0.5,
        turn_in_place_deg=30.0,
    )
    switch_gain: float = (
        0.9  # a scheduled replan replaces the path only if shorter than this x remaining
    )
    # a plan's vertices are pushed away from mapped obstacles up to this distance (m) where
    # there is room (an elastic-band repair: shortcut paths hug the inflated obstacles, and the
    # parts of chairs and boxes the camera has not seen yet lie just beyond them); 0: off
    path_clearance: float = 0.5
    replan_every: int = 10  # control steps between scheduled replans
    # RRT* iterations per control step for scheduled replans (the robot keeps following its
    # path meanwhile); 0: the whole budget in one step. Event replans (blocked, stale, no
    # path) always run the whole budget at once.
    plan_slice: int = 200
    # look around before the first plan: turn in place by this angle (deg) at the start of an
    # episode so the map holds the robot's surroundings (what lies beside and behind it at the
    # start is otherwise first seen when the robot turns into it); 0: no scan
    initial_scan_deg: float = 360.0
    scan_rate: float = 1.2  # rad/s while scanning
    rebuild_every: int = 20  # slam: rebuild the collision model from the local frames' stores
    # occlusion shadows (``simn_sim.agents.shadow``, pose_source "slam"): the space up to this
    # far (m) behind each seen obstacle point, below its continued camera ray, may be occupied
    # (a chair seen from behind hides its seat behind its back) until a depth image sees
    # through it. Shadows are a soft constraint: plans are pushed away from them like from
    # obstacles (path_clearance) where there is room, but they never block a plan; 0: off
    shadow_depth: float = 0.3
    # only obstacle points within this horizontal range of the camera cast shadows: what is
    # hidden near the robot is what it can hit next, while a shadow cast from afar through a
    # door jamb seen at a slant closes the doorway until the robot has looked through it
    shadow_range: float = 1.5
    # only points of surfaces whose top edge is in view cast shadows (``below_top_contour``,
    # contours are depth jumps above this many metres): walls and door jambs do not
    shadow_edge_jump: float = 0.15
    # blind-zone shadows (pose_source "slam", with shadows on): an obstacle point at the
    # image's lower border, unless on a surface seen to be vertical (a box top, a seat, a
    # sliver of a top edge: ``may_continue_below_view``), may go on towards
    # the camera beneath the view, where the camera cannot see from where it stands (a 0.34 m
    # box is out of view within about 0.65 m of the camera). The hidden space up to this far
    # (m) from the point towards the camera is soft shadow like the occlusion shadows; 0: off
    blind_shadow_depth: float = 0.6
    # topological guidance over the local frames (pose_source="slam"): see SimnAgent._subgoal
    topo_guidance: bool = True
    topo_reach: float = 0.6  # a route node this close to the robot counts as reached (m)
    window: float = 6.0  # uniform RRT* samples the known map's box padded by this (m)
    # SlamConfig values (pose_source="slam") applied over SlamConfig.for_agent(), the preset
    # for 10 Hz at 320x240 on a CPU
    slam: dict[str, Any] | None = None
    # odometry mode, dynamic scenes: keep obstacle points in a voxel store, delete the ones the
    # current depth image sees through (free-space carving: a person who walked away), and
    # rebuild the collision model from the store every ``rebuild_every`` steps
    carve: bool = False
    carve_voxel: float = 0.05
    carve_margin: float = 0.15  # a point is seen through when the depth there is this much farther
    seed: int = 0

    def validate(self) -> None:
        n = "SimnAgentConfig"
        require(self.obstacle_stride >= 1, n, "obstacle_stride", "must be >= 1")
        require(self.obstacle_max_depth > 0.3, n, "obstacle_max_depth", "must be > 0.3 m")
        require(self.floor_tolerance > 0, n, "floor_tolerance", "must be > 0")
        require(self.floor_tolerance_per_m2 >= 0, n, "floor_tolerance_per_m2", "must be >= 0")
        require(
            self.robot_height > self.floor_tolerance,
            n,
            "robot_height",
            "must exceed floor_tolerance",
        )
        require(self.replan_every >= 1, n, "replan_every", "must be >= 1")
        require(self.plan_slice >= 0, n, "plan_slice", "must be >= 0 (0: no slicing)")
        require(0 <= self.initial_scan_deg <= 720, n, "initial_scan_deg", "must be in [0, 720]")
        require(self.scan_rate > 0, n, "scan_rate", "must be > 0")
        require(self.rebuild_every >= 1, n, "rebuild_every", "must be >= 1")
        require(
            self.shadow_depth == 0 or self.shadow_depth >= self.collision.resolution,
            n,
            "shadow_depth",
            f"must be 0 (off) or >= the collision resolution ({self.collision.resolution} m)",
        )
        require(
            self.blind_shadow_depth == 0 or self.blind_shadow_depth >= self.collision.resolution,
            n,
            "blind_shadow_depth",
            f"must be 0 (off) or >= the collision resolution ({self.collision.resolution} m)",
        )
        require(self.shadow_range > 0, n, "shadow_range", "must be > 0")
        require(self.shadow_edge_jump > 0, n, "shadow_edge_jump", "must be > 0")
        require(self.window > 0, n, "window", "must be > 0")
        require(self.path_clearance >= 0, n, "path_clearance", "must be >= 0 (0: off)")
        require(self.topo_reach > 0, n, "topo_reach", "must be > 0")
        require(0 < self.switch_gain <= 1, n, "switch_gain", "must be in (0, 1]")
        require(self.carve_voxel > 0, n, "carve_voxel", "must be > 0")
        require(self.carve_margin > 0, n, "carve_margin", "must be > 0")


def strided(depth: np.ndarray, intr: Intrinsics, stride: int) -> tuple[np.ndarray, Intrinsics]:
    """Every ``stride``-th pixel of ``depth`` and the intrinsics of that sub-image."""
    if stride == 1:
        return depth, intr
    d = depth[::stride, ::stride]
    return d, Intrinsics(
        d.shape[1],
        d.shape[0],
        intr.fx / stride,
        intr.fy / stride,
        intr.cx / stride,
        intr.cy / stride,
    )


def label_points_world(
    points_world: np.ndarray, floor_tol: float, robot_height: float
) -> np.ndarray:
    """Floor (|z| < floor_tol) / obstacle (floor_tol <= z <= robot_height) / unknown labels for
    (N, 3) points in a frame whose floor is z = 0 (the camera mount gives it)."""
    z = points_world[:, 2]
    lab = np.zeros(len(z), np.int8)
    lab[np.abs(z) < floor_tol] = FLOOR
    lab[(z >= floor_tol) & (z <= robot_height)] = OBSTACLE
    return lab


class SimnAgent:
    """The SIMN navigation agent (``planner="goal_vector"``) and its RRT* baseline
    (``planner="uniform"``); see the module docstring."""

    def __init__(
        self, env: Any, config: dict[str, Any] | SimnAgentConfig | None = None, name: str = "simn"
    ):
        self.cfg = (
            config if isinstance(config, SimnAgentConfig) else SimnAgentConfig.from_dict(config)
        )
        self.name = name
        lo, hi = env.action_space.low, env.action_space.high
        f = self.cfg.follower
        self.follower_cfg = f.replace(
            v_min=max(f.v_min, float(lo[0])),
            v_max=min(f.v_max, float(hi[0])),
            w_min=max(f.w_min, float(lo[1])),
            w_max=min(f.w_max, float(hi[1])),
        )
        self.control_dt = float(getattr(env, "dt", 0.1))

    def config_dict(self) -> dict[str, Any]:
        """The resolved config, with the SLAM front-end's full config when it runs."""
        d = self.cfg.to_dict()
        if self.cfg.pose_source == "slam":
            from simn_sim.slam.config import SlamConfig

            d["slam"] = SlamConfig.for_agent(**(self.cfg.slam or {})).to_dict()
        return d

    # ---- episode ---------------------------------------------------------------------------
    def reset(self, obs: dict, info: dict) -> None:
        cam = info["camera"]
        self.intr: Intrinsics = cam.intrinsics
        self.T_base_cam = np.asarray(cam.T_base_cam, float)
        self.rng = np.random.default_rng(self.cfg.seed)
        # planning checker (robot radius + margin) and a tighter safety checker (radius + 3 cm):
        # the follower's blocked check and the recovery trigger use the safety one, so a path that
        # grazes the planning margin does not make the robot dither at the margin's edge
        self.checker = CollisionChecker(self.cfg.collision)
        self.safety = CollisionChecker(
            self.cfg.collision.replace(margin=min(0.03, self.cfg.collision.margin))
        )
        self.follower = PathFollower(self.follower_cfg, self.safety)
        self.goal = np.asarray(obs["goal"], float)
        self.T_odom_prev = self._odom_T(obs)
        self.T_base_est = self.T_odom_prev.copy()
        self.path: np.ndarray | None = None
        self.tree_edges: np.ndarray | None = None
        self.steps = 0
        self.since_plan = 0
        self.plan_failures = 0
        self.fallback_plans = 0
        self.bumps = 0
        self.track_failures = 0
        self.revisits = 0
        self._bump_points: list[np.ndarray] = []
        self._obst_store = np.zeros((0, 3))
        self._carved_since_rebuild = False
        self.carved_points = 0
        self._last_cmd = np.zeros(2)
        self._stuck_steps = 0
        self._state = "starting"
        self._plan_ms: float | None = None
        self._job: dict[str, Any] | None = None  # a scheduled plan being grown over steps
        w_scan = min(self.cfg.scan_rate, self.follower_cfg.w_max)
        self._scan_steps = int(
            math.ceil(math.radians(self.cfg.initial_scan_deg) / (w_scan * self.control_dt))
        )
        self._map_ms: float | None = None
        self._track_ms: float | None = None
        self.slam = None
        self._anchors_version = 0
        self.shadow = (
            OcclusionShadow(self.cfg.collision.resolution, self.cfg.shadow_depth)
            if self.cfg.shadow_depth > 0 and self.cfg.pose_source == "slam"
            else None
        )
        self._shadow_dirty = False  # shadow cells were cleared since shadow_map was built
        # the shadow cells as an obstacle model of their own (for push_from_obstacles)
        self.shadow_map = CollisionChecker(self.cfg.collision) if self.shadow is not None else None
        self._best_goal_dist = math.inf  # the robot's closest approach to the goal so far
        self._route_kind = "goal_unexplored"
        if self.cfg.pose_source == "slam":
            from simn_sim.slam.pipeline import SimnSlam, SlamConfig

            self.slam = SimnSlam(
                SlamConfig.for_agent(**(self.cfg.slam or {})), self.intr, T_base_cam=self.T_base_cam
            )
        self._perceive(obs, self.T_base_est @ self.T_base_cam)

    @staticmethod
    def _odom_T(obs: dict) -> np.ndarray:
        o = np.asarray(obs["odometry"], float)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise ValueError(f"odometry must be a finite (x, y, yaw), got {o}")
        return planar_T(o[0], o[1], o[2])

    # ---- perception + mapping ----------------------------------------------------------------
    def _perceive(
        self, obs: dict, T_world_cam_prior: np.ndarray, T_odom: np.ndarray | None = None
    ) -> np.ndarray:
        """Pose estimate, map update and collision-model update; returns T_world_cam.

        ``T_world_cam_prior``: the odometry increment applied to the previous estimate (the pose
        in odometry mode). SimnSlam is given the raw odometry pose ``T_odom`` instead: it uses
        only the change between consecutive calls, and the change between two priors that
        already contain its own corrections would apply each correction again on every later
        frame (a 10 cm correction became 10 cm of drift per frame)."""
        t0 = time.perf_counter()
        T_wc = T_world_cam_prior
        self._map_ms = self._track_ms = None
        if self.slam is not None:
            T_odom_cam = (self._odom_T(obs) if T_odom is None else T_odom) @ self.T_base_cam
            fr = self.slam.process(
                self.steps * self.control_dt, obs["rgb"], obs["depth"], T_odom_cam
            )
            T_wc = fr.T_world_cam
            self._track_ms, self._map_ms = fr.track_ms, fr.map_ms
            self.track_failures += int(not fr.success)
            self.revisits += int(fr.revisit_accepted)
            new_shadow = self._observe_shadow(
                fr.obstacle_points_world,
                T_wc,
                obs["depth"],
                self.intr,
                None if fr.pixels is None else fr.pixels[fr.labels == OBSTACLE],
            )
            rebuild = (
                self.slam.anchors_version != self._anchors_version
                or self.steps % self.cfg.rebuild_every == 0
            )
            if rebuild:
                # anchors moved (pose graph) or periodic refresh: rebuild the collision model from
                # the local frames' obstacle stores (which drop points seen through: no ghosts)
                self._anchors_version = self.slam.anchors_version
                self._rebuild_maps(self.slam.obstacle_points_world())
            else:
                P = fr.obstacle_points_world
                self._update_maps(P, np.full(len(P), OBSTACLE, np.int8))
            self._add_shadow(new_shadow)
            return T_wc
        d, intr = strided(obs["depth"], self.intr, self.cfg.obstacle_stride)
        P = backproject(np.where(d <= self.cfg.obstacle_max_depth, d, 0.0), intr).reshape(-1, 3)
        P = P[P[:, 2] > 0]
        if len(P):
            Pw = transform_points(T_wc, P.astype(np.float64))
            tol = (
                self.cfg.floor_tolerance
                + self.cfg.floor_tolerance_per_m2 * P[:, 2].astype(np.float64) ** 2
            )
            lab = label_points_world(Pw, tol, self.cfg.robot_height)
            if self.cfg.carve:
                self._carve_and_store(d, intr, T_wc, Pw[lab == OBSTACLE])
            else:
                self._update_maps(Pw, lab)
        if self.slam is None:
            self._map_ms = (time.perf_counter() - t0) * 1e3
        return T_wc

    def _carve_and_store(
        self, depth: np.ndarray, intr: Intrinsics, T_wc: np.ndarray, new_obst: np.ndarray
    ) -> None:
        """Free-space carving over the agent's obstacle voxel store (see ``SimnAgentConfig.carve``)."""
        st = self._obst_store
        if len(st):
            pc = transform_points(inv_T(T_wc), st)
            z = pc[:, 2]
            front = z > 0.3
            zz = np.where(front, z, 1.0)
            u = np.round(intr.fx * pc[:, 0] / zz + intr.cx).astype(int)
            v = np.round(intr.fy * pc[:, 1] / zz + intr.cy).astype(int)
            inside = front & (u >= 0) & (u < depth.shape[1]) & (v >= 0) & (v < depth.shape[0])
            zo = np.zeros(len(z))
            zo[inside] = depth[v[inside], u[inside]]
            through = inside & (zo > 0) & (zo > z + self.cfg.carve_margin)
            if through.any():
                st = st[~through]
                self.carved_points += int(through.sum())
                self._carved_since_rebuild = True
        if len(new_obst):
            allp = np.concatenate([st, new_obst]) if len(st) else new_obst
            _, keep = np.unique(
                np.floor(allp / self.cfg.carve_voxel).astype(np.int64), axis=0, return_index=True
            )
            st = allp[np.sort(keep)]
            self._update_maps(new_obst, np.full(len(new_obst), OBSTACLE, np.int8))
        self._obst_store = st
        if self._carved_since_rebuild and self.steps % self.cfg.rebuild_every == 0:
            self._rebuild_maps(st)
            self._carved_since_rebuild = False

    def _rebuild_maps(self, obstacle_points: np.ndarray) -> None:
        """Rebuild both collision models from ``obstacle_points`` plus the bump points."""
        self.checker.reset()
        self.safety.reset()
        pts = (
            np.concatenate([obstacle_points, *self._bump_points])
            if self._bump_points
            else obstacle_points
        )
        self._update_maps(pts, np.full(len(pts), OBSTACLE, np.int8))

    def _shadow_model(self) -> CollisionChecker | None:
        """The shadow cells' obstacle model, rebuilt first if cells were cleared since."""
        if self.shadow_map is not None and self._shadow_dirty:
            self.shadow_map.reset()
            self._shadow_dirty = False
            self._add_shadow(self.shadow.shadow)
        return self.shadow_map

    def _observe_shadow(
        self,
        obstacle_points: np.ndarray,
        T_wc: np.ndarray,
        depth: np.ndarray,
        intr: Intrinsics,
        pixels: np.ndarray | None,
    ) -> np.ndarray:
        """Feed one view to the occlusion shadows; returns the keys of the new shadow cells.
        ``pixels``: (row, column) of each obstacle point in ``depth``; only points below a
        visible top contour cast shadows (``below_top_contour``)."""
        if self.shadow is None:
            return np.zeros(0, np.int64)
        c = self.cfg.collision
        in_z = (obstacle_points[:, 2] >= c.z_min) & (obstacle_points[:, 2] <= c.z_max)
        band = in_z & (np.hypot(*(obstacle_points[:, :2] - T_wc[:2, 3]).T) <= self.cfg.shadow_range)
        if pixels is None:
            raise ValueError("occlusion shadows need the pixel of each obstacle point")
        if band.any():  # the top contours only matter for points that may cast
            hw = max(1, round(3 * depth.shape[1] / 320))
            topped = below_top_contour(depth, self.cfg.shadow_edge_jump, hw)
            band &= topped[pixels[:, 0], pixels[:, 1]]
        xy = (T_wc @ inv_T(self.T_base_cam))[:2, 3]
        n_cleared = self.shadow.traverse(xy, c.robot_radius)
        new, n_seen = self.shadow.observe(obstacle_points[band], T_wc, depth, intr)
        self._shadow_dirty |= n_cleared + n_seen > 0
        if self.cfg.blind_shadow_depth > 0 and len(obstacle_points):
            H = depth.shape[0]
            rows = max(2, math.ceil(0.02 * H))  # the bottom 2 % of the image
            bottom = in_z & (pixels[:, 0] >= H - rows)
            if bottom.any():
                step = max(2, round(0.01 * H))
                cont = may_continue_below_view(
                    depth, intr, T_wc, rows, step, self.cfg.shadow_edge_jump
                )
                sel = np.flatnonzero(bottom)
                sel = sel[cont[pixels[sel, 0], pixels[sel, 1]]]
                if len(sel):
                    blind = self.shadow.cast_below_view(
                        obstacle_points[sel], T_wc, intr, self.cfg.blind_shadow_depth
                    )
                    new = np.union1d(new, blind)
        return new

    def _add_shadow(self, keys: np.ndarray) -> None:
        """Shadow cells go into their own model (``shadow_map``), never into the planning or
        the safety model: they steer plans, they do not block them."""
        if self.shadow_map is None or not len(keys):
            return
        xy = self.shadow.centres(keys)
        z = np.full((len(xy), 1), 0.5 * (self.cfg.collision.z_min + self.cfg.collision.z_max))
        self.shadow_map.update(np.hstack([xy, z]), np.full(len(xy), OBSTACLE, np.int8))

    def _update_maps(self, points: np.ndarray, labels: np.ndarray) -> None:
        if len(points):
            self.checker.update(points, labels)
            self.safety.update(points, labels)

    # ---- planning ----------------------------------------------------------------------------
    def _subgoal(self, xy: np.ndarray) -> np.ndarray:
        """Topological guidance (``topo_guidance``): when the goal lies in the region of an
        earlier local frame but not in the current one, aim at the next frame on the route over
        the topological map towards that frame; when no frame covers the goal (unexplored
        space), aim at the goal itself.

        Only frames whose anchor is nearer the goal (by ``topo_reach``) than the robot has ever
        been are route targets: guidance leads to explored places that are progress, and a
        robot that reached the explored place nearest the goal and has to detour from there is
        not sent back to it (without this rule it oscillated between nearby anchors)."""
        if not self.cfg.topo_guidance or self.slam is None or self.slam.current_frame_id < 0:
            return self.goal
        from simn_sim.planning.topo import route_subgoal

        topo = self.slam.topo
        covering = topo.frames_containing(self.goal)
        if not covering or self.slam.current_frame_id in covering:
            self._route_kind = "goal_unexplored" if not covering else "goal_in_frame"
            return self.goal
        dist = {f: float(np.hypot(*(topo.anchor(f)[:2, 3] - self.goal))) for f in covering}
        cands = [f for f in covering if dist[f] < self._best_goal_dist - self.cfg.topo_reach]
        if not cands:
            self._route_kind = "goal_direct"
            return self.goal
        target = min(cands, key=dist.__getitem__)
        r = route_subgoal(
            topo.graph,
            self.slam.current_frame_id,
            self.goal,
            frame_radius=self.cfg.topo_reach,
            goal_node=target,
            from_xy=xy,
            reach=self.cfg.topo_reach,
        )
        self._route_kind = r.kind
        return np.asarray(r.xy, float)

    def _begin_plan(self, xy: np.ndarray) -> dict[str, Any] | None:
        """A new RRT* plan from ``xy`` to the (sub-)goal, begun but not grown (None when the
        start or the goal cannot be made free)."""
        goal = self._subgoal(xy)
        if not self.checker.is_free(goal[None])[0]:
            alt = self._nearest_free(goal)
            goal = alt if alt is not None else goal
        start = xy
        if not self.checker.is_free(xy[None])[0]:  # inside the margin: nearest free point
            alt = self._nearest_free(xy, radius=0.5)
            start = alt if alt is not None else xy
        if not (self.checker.is_free(start[None])[0] and self.checker.is_free(goal[None])[0]):
            return None
        if self.cfg.planner == "goal_vector":
            planner = goal_vector_rrt_star(
                self.checker, self.cfg.rrt, self.cfg.goal_vector, None, self.rng
            )
        else:
            lo = np.minimum(xy, goal) - self.cfg.window
            hi = np.maximum(xy, goal) + self.cfg.window
            b = self.checker.obstacle_bounds()
            if b is not None:
                lo = np.minimum(lo, [b[0], b[1]])
                hi = np.maximum(hi, [b[2], b[3]])
            planner = uniform_rrt_star(
                self.checker, (lo[0], lo[1], hi[0], hi[1]), self.cfg.rrt, self.rng
            )
        planner.begin(start, goal)
        return {"planner": planner, "xy": xy.copy(), "start": start, "goal": goal}

    def _finish_plan(self, job: dict[str, Any] | None, xy: np.ndarray, scheduled: bool) -> None:
        """Take the grown plan (grid fallback when RRT* found nothing). A scheduled replan keeps
        the current path unless the new one is shorter than ``switch_gain`` x the remaining
        length (no dithering between equivalent RRT* solutions) or was invalidated by the map
        growing while it was computed; an event replan (blocked, stale, no path) always
        replaces it."""
        path = None
        self.tree_edges = None
        if job is not None:
            planner, start = job["planner"], job["start"]
            path = planner.finish()
            if path is None:  # RRT* budget exhausted: complete grid search on the same checker
                path = grid_shortest_path(self.checker, start, job["goal"], self.rng)
                self.fallback_plans += int(path is not None)
            if path is not None and self.cfg.path_clearance > 0:
                path = push_from_obstacles(
                    path, self.checker, self.cfg.path_clearance, also_from=self._shadow_model()
                )
            if path is not None and start is not job["xy"]:
                path = np.vstack([job["xy"], path])
            if path is not None and scheduled and not self.checker.path_free(path[1:]):
                path = None  # the map grew across it while it was grown over several steps
            tree = planner.tree
            if tree is not None and len(tree) > 1:
                par = np.asarray(tree.parent[: len(tree)])
                ok = par >= 0
                xy_t = np.asarray(tree.xy[: len(tree)])
                self.tree_edges = np.stack([xy_t[ok], xy_t[par[ok]]], axis=1)
        self.since_plan = 0
        if scheduled and self.path is not None:
            if path is None or _length(path) >= self.cfg.switch_gain * self._remaining(xy):
                return
        if path is None:
            self.plan_failures += 1
            self.path = None
            self._state = "no_plan"
        else:
            self.path = path
            self.follower.set_path(path)
            self._state = "following"

    def _plan(self, xy: np.ndarray, scheduled: bool = False) -> None:
        """Plan now, the whole iteration budget in this control step (cancels a sliced plan)."""
        t = time.perf_counter()
        self._job = None
        job = self._begin_plan(xy)
        if job is not None:
            job["planner"].iterate(self.cfg.rrt.max_iterations)
        self._finish_plan(job, xy, scheduled)
        self._plan_ms = (self._plan_ms or 0.0) + (time.perf_counter() - t) * 1e3

    def _plan_sliced(self, xy: np.ndarray) -> None:
        """A scheduled replan spread over control steps: ``plan_slice`` RRT* iterations per
        step while the robot keeps following its current path (the same rng and budget give
        the same tree as one call; the control step stays short)."""
        t = time.perf_counter()
        if self._job is None:
            self._job = self._begin_plan(xy)
            if self._job is None:
                self._finish_plan(None, xy, scheduled=True)
                self._plan_ms = (time.perf_counter() - t) * 1e3
                return
        job = self._job
        if job["planner"].iterate(self.cfg.plan_slice):
            self._job = None
            self._finish_plan(job, xy, scheduled=True)
        self._plan_ms = (time.perf_counter() - t) * 1e3

    def _remaining(self, xy: np.ndarray) -> float:
        """Length of the current path from the robot's nearest vertex on."""
        p = self.path
        k = int(np.argmin(np.hypot(*(p - xy).T)))
        return float(np.hypot(*(p[k] - xy))) + _length(p[k:])

    def _nearest_free(self, p: np.ndarray, radius: float = 1.0) -> np.ndarray | None:
        ang = np.linspace(0, 2 * math.pi, 24, endpoint=False)
        for r in np.arange(0.1, radius + 1e-9, 0.1):
            cand = p + r * np.c_[np.cos(ang), np.sin(ang)]
            free = self.checker.is_free(cand)
            if free.any():
                return cand[np.flatnonzero(free)[0]]
        return None

    def _detect_bump(self, T_step: np.ndarray) -> None:
        """Wheel odometry shows no motion although the base was commanded forwards: an
        obstacle the camera cannot see (below the view, within its ~0.6 m blind zone) blocks
        it. Add it to the collision model as an arc of points just ahead of the hull."""
        v_cmd = float(self._last_cmd[0])
        moved = float(np.hypot(T_step[0, 3], T_step[1, 3]))
        if v_cmd > 0.1 and moved < 0.2 * v_cmd * self.control_dt:
            self._stuck_steps += 1
        else:
            self._stuck_steps = 0
        if self._stuck_steps >= 2:
            self.bumps += 1
            self._stuck_steps = 0
            T = self.T_base_est
            a = np.radians(np.linspace(-40, 40, 9))
            r = self.cfg.collision.robot_radius + 0.03
            local = np.c_[r * np.cos(a), r * np.sin(a), np.full_like(a, 0.3)]
            pts = transform_points(T, local)
            self._bump_points.append(pts)
            self._update_maps(pts, np.full(len(pts), OBSTACLE, np.int8))
            self.path = None

    def _drive_to(self, pose: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Turn towards ``target`` and creep to it (forwards, or backwards when it is behind)."""
        d = target - pose[:2]
        err = (math.atan2(d[1], d[0]) - pose[2] + math.pi) % (2 * math.pi) - math.pi
        if abs(err) > math.radians(120) and self.follower_cfg.v_min < 0:  # behind: reverse
            err_b = (err + 2 * math.pi) % (2 * math.pi) - math.pi - math.copysign(math.pi, err)
            return np.array(
                [max(self.follower_cfg.v_min, -0.15), float(np.clip(1.5 * err_b, -1.0, 1.0))],
                np.float32,
            )
        if abs(err) > math.radians(45):
            return np.array([0.0, math.copysign(0.8, err)], np.float32)
        return np.array([0.15, float(np.clip(1.5 * err, -1.0, 1.0))], np.float32)

    def _escape(self, pose: np.ndarray) -> np.ndarray:
        """Inside the inflated obstacles: drive towards the freest nearby direction."""
        xy, yaw = pose[:2], pose[2]
        ang = yaw + np.linspace(-math.pi, math.pi, 16, endpoint=False)
        cand = xy + 0.3 * np.c_[np.cos(ang), np.sin(ang)]
        best = ang[int(np.argmax(self.checker.clearance(cand)))]
        err = (best - yaw + math.pi) % (2 * math.pi) - math.pi
        if abs(err) > math.radians(60):
            return np.array([0.0, math.copysign(self.follower_cfg.w_max * 0.6, err)], np.float32)
        return np.array([0.15, 1.5 * err], np.float32)

    # ---- act ---------------------------------------------------------------------------------
    def act(self, obs: dict, info: dict | None = None) -> np.ndarray:  # info ignored: no true pose
        a = self._act(obs)
        self._last_cmd = np.asarray(a, float)
        return a

    def _act(self, obs: dict) -> np.ndarray:
        self.steps += 1
        T_odom = self._odom_T(obs)
        self._detect_bump(inv_T(self.T_odom_prev) @ T_odom)
        T_base_prior = orthonormalize(self.T_base_est @ inv_T(self.T_odom_prev) @ T_odom)
        self.T_odom_prev = T_odom
        T_wc = self._perceive(obs, T_base_prior @ self.T_base_cam, T_odom)
        self.T_base_est = T_wc @ inv_T(self.T_base_cam)
        pose = np.array([self.T_base_est[0, 3], self.T_base_est[1, 3], yaw_of(self.T_base_est)])
        xy = pose[:2]
        self._best_goal_dist = min(self._best_goal_dist, float(np.hypot(*(xy - self.goal))))
        self._plan_ms = None
        if float(self.checker.clearance(xy[None])[0]) < self.cfg.collision.robot_radius + 0.01:
            self._state = "escaping"  # (nearly) touching a mapped obstacle
            self.path = None
            return self._escape(pose)
        if not self.safety.is_free(xy[None])[0]:
            # inside the safety margin (the map grew around the robot): back out to the nearest
            # point free under the planning margin before planning again
            self._state = "recovering"
            self.path = None
            target = self._nearest_free(xy, radius=0.6)
            return self._escape(pose) if target is None else self._drive_to(pose, target)
        if self._scan_steps > 0:  # initial look-around (turning in place sweeps no new space)
            self._scan_steps -= 1
            self._state = "scanning"
            return np.array([0.0, min(self.cfg.scan_rate, self.follower_cfg.w_max)], np.float32)
        self.since_plan += 1
        if self.path is None:
            self._plan(xy)
        elif self._job is not None or self.since_plan >= self.cfg.replan_every:
            if self.cfg.plan_slice > 0:
                self._plan_sliced(xy)
            else:
                self._plan(xy, scheduled=True)
        if self.path is None:  # look around: turning reveals more of the map
            return np.array([0.0, 0.6 * self.follower_cfg.w_max], np.float32)
        cmd = self.follower.step(pose)
        if cmd.status in ("blocked", "stale"):
            self._plan(xy)
            if self.path is None:
                return np.array([0.0, 0.6 * self.follower_cfg.w_max], np.float32)
            cmd = self.follower.step(pose)
        if cmd.status == "reached" and float(np.hypot(*(self.goal - xy))) > 0.2:
            self._plan(xy)  # reached a sub-goal: plan on towards the goal
            if self.path is not None:
                cmd = self.follower.step(pose)
        if cmd.status in ("blocked", "stale"):
            return np.array([0.0, 0.0], np.float32)
        return np.array([cmd.v, cmd.w], np.float32)

    def state(self) -> str:
        return self._state

    def counters(self) -> dict[str, int]:
        return {
            "plan_failures": self.plan_failures,
            "fallback_plans": self.fallback_plans,
            "bumps": self.bumps,
        }

    def debug(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "frame": "start",  # everything below is in the agent's own (episode start) frame
            "T_world_base_est": getattr(self, "T_base_est", None),
            "path": self.path,
            "tree_edges": self.tree_edges,
            "plan_ms": self._plan_ms,
            "map_ms": self._map_ms,
            "track_ms": self._track_ms,
            "route": getattr(self, "_route_kind", None),
        }
        if self.slam is not None and hasattr(self.slam, "debug"):
            d.update(self.slam.debug())
        return d


def _length(path: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(path, axis=0).T))) if len(path) > 1 else 0.0


def _make_simn(env: Any, config: dict[str, Any]) -> SimnAgent:
    return SimnAgent(env, config, name="simn")


def _make_rrtstar(env: Any, config: dict[str, Any]) -> SimnAgent:
    return SimnAgent(env, {"planner": "uniform", **config}, name="rrtstar")


register_agent("simn", _make_simn)
register_agent("rrtstar", _make_rrtstar)
