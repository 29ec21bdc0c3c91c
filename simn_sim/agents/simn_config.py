"""The ``simn`` / ``rrtstar`` agent's config (:class:`SimnAgentConfig`): planner, world model,
follower, the judge around the RRT* and the recoveries. Each knob's measured effect is in
docs/navigation.md."""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

from simn_sim.config import Config, ConfigError, require
from simn_sim.planning import FollowerConfig, GoalVectorConfig, RRTStarConfig
from simn_sim.planning.costmap import CostMapConfig
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.presets import slam_config_from_preset
from simn_sim.world import ObstacleConfig

__all__ = ["MOVED_KEYS", "SimnAgentConfig", "points_ablation_config"]

# Keys of SimnAgentConfig before the world-model redesign and where they are now.
MOVED_KEYS: dict[str, str] = {
    "collision": "obstacles.collision",
    "rebuild_every": "obstacles.rebuild_every",
    "shadow_depth": "obstacles.shadow_depth",
    "shadow_range": "obstacles.shadow_range",
    "shadow_edge_jump": "obstacles.shadow_edge_jump",
    "blind_shadow_depth": "obstacles.blind_shadow_depth",
    "carve": "slam.stores.carve (both world models carve the local frames' stores)",
    "carve_margin": "slam.stores.carve_margin",
    "carve_voxel": "slam.stores.obstacle_voxel",
    "obstacle_stride": "slam.perception.stride (both world models perceive the same way)",
    "obstacle_max_depth": "slam.classifier.max_obstacle_range",
    "floor_tolerance": "slam.classifier (the floor classifier labels points in both world models)",
    "floor_tolerance_per_m2": "slam.classifier.floor_tol_per_m2",
    "robot_height": "obstacles.collision.z_max",
}


@dataclasses.dataclass(frozen=True)
class SimnAgentConfig(Config):
    planner: Literal["goal_vector", "uniform"] = "goal_vector"
    # which world model makes the pose: "slam" (the method: the SIMN front-end) or "odometry"
    # (ablation: wheel odometry, same perception, stores and obstacle view)
    pose_source: Literal["slam", "odometry"] = "slam"
    # the front-end's config; a mapping given here changes the agent preset
    # (SlamConfig.for_agent: the learned map at 320x240 on a CPU) only in the keys it names;
    # {preset: points_agent, ...} starts from SlamConfig.for_points_agent (the point-store
    # ablation, also the agent ``simn_points``)
    slam: SlamConfig = dataclasses.field(default_factory=SlamConfig.for_agent)
    obstacles: ObstacleConfig = ObstacleConfig()
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
    # a scheduled replan replaces the path only if shorter than this x remaining
    switch_gain: float = 0.9
    # a plan's vertices are pushed away from mapped obstacles (and shadows) up to this distance
    # (m) where there is room (an elastic-band repair: shortcut paths hug the inflated
    # obstacles, and the unseen parts of chairs and boxes lie just beyond them); 0: off
    path_clearance: float = 0.5
    replan_every: int = 10  # control steps between scheduled replans
    # RRT* iterations per control step for scheduled replans (the robot keeps following its
    # path meanwhile); 0: the whole budget in one step. Event replans (blocked, stale, no
    # path) always run the whole budget at once.
    plan_slice: int = 200
    # look around before the first plan: turn in place by this angle (deg) so the map holds
    # the robot's surroundings; 0: no scan
    initial_scan_deg: float = 360.0
    scan_rate: float = 1.2  # rad/s while scanning
    topo_guidance: bool = True  # sub-goals on the route over the topological map
    topo_reach: float = 0.6  # a route node this close to the robot counts as reached (m)
    window: float = 6.0  # uniform RRT* samples the known map's box padded by this (m)
    # ---- around the RRT* (simn_sim.planning.costmap): every planning cycle the candidate
    # paths (the committed one, the fresh RRT* plan, the cost map's own route) are judged on
    # the cost-to-go map (unknown space and the planning margin weighed); False: the plain
    # RRT* loop (length-only switching, grid fallback), for ablations
    judge: bool = True
    costmap: CostMapConfig = CostMapConfig()
    # the RRT* plan is kept unless its judged cost exceeds the cost map's route by this factor
    homotopy_slack: float = 1.25
    # lost progress: the cost-to-go on the agent's own map has not fallen below its best by
    # progress_eps (m) for stall_steps control steps -> look around, then follow the cost
    # map's route for force_steps steps
    stall_steps: int = 150
    progress_eps: float = 0.5
    force_steps: int = 100
    # when the goal is unreachable on the map under the safety margin (a doorway closed by
    # depth noise on its jambs), plan once more with the robot radius shrunk by this (m) and no
    # margin, and follow that route for force_steps steps under the same model; 0: off (the
    # default: on office_nav_v2 0.05 won one episode, lost one and added 9 collision events in
    # 43, docs/navigation.md)
    squeeze: float = 0.0
    # no route on the map for clear_after control steps in a row (the goal closed off by map
    # errors: copies of a door jamb from frames anchored a few cm apart, a bump arc in a
    # doorway) -> clear the map (ObstacleMap.forget: only the local frames from the current
    # one on, no bumps) and look around; at most once per clear_cooldown steps; 0: off
    clear_after: int = 30
    clear_cooldown: int = 200
    # when the follower refuses even a fresh plan (blocked right after replanning): False,
    # command zero velocity (the robot stands until lost progress or a map change moves it);
    # True, treat it as no route (look around, clear the map after clear_after steps).
    # office_nav_v2 with this and costmap.exact_segments: docs/navigation.md
    refused_plan_no_route: bool = False
    # a forward-commanded step whose odometry shows less than this share of the commanded
    # distance is a contact sign (two in four steps are a bump; BumpDetector). 0.5 before
    # 2026-12-06: the actuation noise alone fired it (docs/navigation.md, "False bumps")
    bump_min_progress: float = 0.3
    # > 0: also a contact sign below this share of the median progress ratio of the last 5
    # forward steps (BumpDetector.rel_progress); 0: off. 0.5: no false bump in the free drives
    # of scripts/bench_bumps.py, and nav2-ref-009's turn past a low box caught (docs/navigation.md)
    bump_rel_progress: float = 0.5
    # > 0 (rad/s): also a contact sign when a forward step's odometry yaw rate is off the
    # command by more than this plus half the command (BumpDetector.yaw_tol: friction turning
    # the base, e.g. sliding past a person beside it, outside the camera's view); 0: off.
    # 0.2 since 2026-12-06: no false bump in 6002 free forward steps of scripts/bench_bumps.py
    # down to 0.1; person-contact edges 6 -> 2 on office_dynamic_v1 (docs/navigation.md)
    bump_yaw_tol: float = 0.2
    seed: int = 0

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SimnAgentConfig:
        """As :meth:`Config.from_dict`; ``slam`` given as a mapping changes the agent preset;
        a pre-redesign key fails with a message naming where it lives now."""
        data = dict(data or {})
        moved = sorted(set(data) & set(MOVED_KEYS))
        if moved:
            where = "; ".join(f"'{k}' -> {MOVED_KEYS[k]}" for k in moved)
            raise ConfigError(f"SimnAgentConfig: key(s) moved: {where}")
        if isinstance(data.get("slam"), dict):
            data["slam"] = slam_config_from_preset(data["slam"], default="agent")
        elif data.get("slam") is None:
            data.pop("slam", None)
        return super().from_dict(data)

    def validate(self) -> None:
        n = "SimnAgentConfig"
        require(self.replan_every >= 1, n, "replan_every", "must be >= 1")
        require(self.plan_slice >= 0, n, "plan_slice", "must be >= 0 (0: no slicing)")
        require(0 <= self.initial_scan_deg <= 720, n, "initial_scan_deg", "must be in [0, 720]")
        require(self.scan_rate > 0, n, "scan_rate", "must be > 0")
        require(self.window > 0, n, "window", "must be > 0")
        require(self.path_clearance >= 0, n, "path_clearance", "must be >= 0 (0: off)")
        require(self.topo_reach > 0, n, "topo_reach", "must be > 0")
        require(0 < self.switch_gain <= 1, n, "switch_gain", "must be in (0, 1]")
        require(self.homotopy_slack >= 1, n, "homotopy_slack", "must be >= 1")
        require(self.stall_steps >= 1, n, "stall_steps", "must be >= 1")
        require(self.progress_eps > 0, n, "progress_eps", "must be > 0")
        require(self.force_steps >= 0, n, "force_steps", "must be >= 0")
        require(self.clear_after >= 0, n, "clear_after", "must be >= 0 (0: off)")
        require(self.clear_cooldown >= 1, n, "clear_cooldown", "must be >= 1")
        require(0 < self.bump_min_progress < 1, n, "bump_min_progress", "must be in (0, 1)")
        require(0 <= self.bump_rel_progress < 1, n, "bump_rel_progress", "must be in [0, 1)")
        require(self.bump_yaw_tol >= 0, n, "bump_yaw_tol", "must be >= 0 rad/s (0: off)")
        require(
            0 <= self.squeeze < self.obstacles.collision.robot_radius,
            n,
            "squeeze",
            "must be in [0, robot radius)",
        )


def points_ablation_config(config: dict[str, Any]) -> dict[str, Any]:
    """The agent config of the point-store ablation (agent ``simn_points``): ``config`` with
    each local frame's map a surface point store (:meth:`SlamConfig.for_points_agent`)
    instead of the learned map; a ``slam`` mapping in ``config`` changes that preset."""
    cfg = dict(config)
    slam = cfg.get("slam")
    if slam is not None and not isinstance(slam, dict):
        raise ConfigError("simn_points: 'slam' must be a mapping of SlamConfig changes")
    slam = dict(slam or {})
    if slam.get("preset", "points_agent") != "points_agent":
        raise ConfigError(
            f"simn_points: slam.preset is 'points_agent' for this agent, got {slam['preset']!r}"
        )
    cfg["slam"] = {**slam, "preset": "points_agent"}
    return cfg
