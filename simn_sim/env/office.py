"""``SimnOffice-v0``: a mobile base in a procedural office with a D435i RGB-D camera.

The env owns all MuJoCo state. Scene building (:mod:`.scene`), the layout (:mod:`.layout`), the
exact free space (:class:`~simn_sim.geometry.freespace.FreeSpace2D`), episode specs
(:mod:`.episodes`) and metrics (:mod:`simn_sim.metrics`) are separate pieces that it reads.

Observation (``Dict``):
  - ``rgb``: (H, W, 3) uint8 colour image.
  - ``depth``: (H, W) float32 metric depth along the optical axis, aligned to colour; 0 outside
    ``[depth_min, depth_max]`` (0.28-10 m) and where the noise model drops a pixel.
  - ``goal``: (2,) float32 goal position (x, y) in the episode's start frame (the base frame at
    reset: x forward, y left).
  - ``odometry``: (3,) float32 base pose (x, y, yaw) in the start frame, integrated from wheel
    odometry of the executed motion with configurable drift (``odom_noise_*``; zero gives the
    exact pose).
Action: ``Box([v_min, -w_max], [v_max, w_max])``: forward speed v (m/s) and turn rate w (rad/s)
of a unicycle. Defaults v in [-0.3, 1.0] m/s, w in [-1.5, 1.5] rad/s. A NaN/inf, wrongly shaped
or out-of-bounds action raises ``ValueError``; wrap with ``gymnasium.wrappers.ClipAction`` to clip.
The base executes the command through the actuation noise model (``actuation_noise``).
Sensing: ``EnvConfig.sensing`` ``"realistic"`` (default: D435i depth, odometry drift, actuation
noise) or ``"ideal"`` (env id ``SimnOfficeIdeal-v0``); all noise comes from generators seeded
from ``reset(seed=...)``. See docs/env.md.
``info``: ``T_world_base``, ``T_world_cam`` (4x4, OpenCV optical frame), ``collided``,
``distance_to_goal``, ``geodesic_distance_to_goal``, after a step ``executed_action`` ((2,)
float64 ``[v, w]`` the base executed) and, at the end of an episode, ``episode``
(the metrics of :class:`simn_sim.metrics.EpisodeMetrics`). The true poses are for metrics and
oracle agents only. ``reset`` also returns ``camera`` (:class:`CameraInfo`: intrinsics and
``T_base_cam``) in ``info``.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from simn_sim.env.episodes import EpisodeSpec
from simn_sim.env.layout import Layout, generate_layout
from simn_sim.env.noise import ActuationNoise, apply_depth_noise, odometry_step
from simn_sim.env.office_config import CameraInfo, EnvConfig, env_config_from_file
from simn_sim.env.people import _People
from simn_sim.env.scene import (
    ROBOT_GROUP,
    ROBOT_RADIUS,
    ROBOT_Z_BAND,
    SceneModel,
    build_scene,
)
from simn_sim.env.sensors import OffscreenCamera
from simn_sim.geometry.camera import T_MJCAM_CV, Intrinsics
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.geometry.se3 import inv_T, make_T, planar_T
from simn_sim.metrics import EpisodeMetrics
from simn_sim.paths import envs_dir

__all__ = [
    "REFERENCE_LAYOUT",
    "CameraInfo",
    "EnvConfig",
    "SimnOfficeEnv",
    "env_config_from_file",
    "load_layout",
]

REFERENCE_LAYOUT = "office_reference.json"


def load_layout(layout_seed: int | None) -> Layout:
    if layout_seed is None:
        return Layout.load(envs_dir() / REFERENCE_LAYOUT)
    return generate_layout(layout_seed)


class SimnOfficeEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array", "depth_array", "rgbd_tuple"], "render_fps": 10}

    def __init__(
        self,
        render_mode: str | None = None,
        config: EnvConfig | dict | None = None,
        **overrides: Any,
    ):
        if isinstance(config, EnvConfig):
            cfg = config.replace(**overrides) if overrides else config
        else:
            cfg = EnvConfig.from_dict({**(config or {}), **overrides})
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode {render_mode!r} is not one of {self.metadata['render_modes']}"
            )
        self.cfg = cfg
        self.render_mode = render_mode
        self.intrinsics = Intrinsics.from_fovy(cfg.width, cfg.height, cfg.fovy_deg)
        self.action_space = spaces.Box(
            np.array([cfg.v_min, -cfg.w_max], np.float32),
            np.array([cfg.v_max, cfg.w_max], np.float32),
            dtype=np.float32,
        )
        self.observation_space = spaces.Dict(
            {
                "rgb": spaces.Box(0, 255, (cfg.height, cfg.width, 3), np.uint8),
                "depth": spaces.Box(0.0, cfg.depth_max, (cfg.height, cfg.width), np.float32),
                "goal": spaces.Box(-np.inf, np.inf, (2,), np.float32),
                "odometry": spaces.Box(-np.inf, np.inf, (3,), np.float32),
            }
        )
        self.layout: Layout | None = None
        self._layout_key: int | None = None
        self._scene: SceneModel | None = None
        self._cam: OffscreenCamera | None = None
        self._overview: OffscreenCamera | None = None
        self._load_layout(cfg.layout_seed)
        self.metadata = {**self.metadata, "render_fps": int(round(cfg.control_hz))}
        self._episode: EpisodeSpec | None = None

    # ---- scene -------------------------------------------------------------------------------
    def _load_layout(self, layout_seed: int | None) -> None:
        if self._scene is not None and self._layout_key == layout_seed:
            return
        self.close()
        self._layout_key = layout_seed
        self.layout = load_layout(layout_seed)
        self._scene = build_scene(
            self.layout, self.cfg.width, self.cfg.height, n_people=self.cfg.n_people
        )
        self.model = self._scene.model
        self.data = mujoco.MjData(self.model)
        self.frame_skip = max(1, int(round(1.0 / (self.cfg.control_hz * self.model.opt.timestep))))
        self.dt = self.frame_skip * self.model.opt.timestep
        self.free_space = FreeSpace2D(
            self.layout.footprints(ROBOT_Z_BAND),
            robot_radius=ROBOT_RADIUS,
            bounds=self.layout.bounds,
        )
        # camera pose on the base (static): MuJoCo camera frame -> OpenCV optical frame
        mujoco.mj_forward(self.model, self.data)
        cid = self._scene.camera_id
        T_body_mjcam = make_T(
            _quat_to_mat(self.model.cam_quat[cid]), self.model.cam_pos[cid].astype(float)
        )
        self.T_base_cam = T_body_mjcam @ T_MJCAM_CV
        self.camera_info = CameraInfo(
            self.intrinsics, self.T_base_cam.copy(), self.cfg.depth_min, self.cfg.depth_max
        )

    def _camera(self) -> OffscreenCamera:
        if self._cam is None:
            hidden = (ROBOT_GROUP,)
            self._cam = OffscreenCamera(
                self.model, self._scene.camera_id, self.cfg.width, self.cfg.height, hidden
            )
        return self._cam

    # ---- state helpers -----------------------------------------------------------------------
    def _pose2d(self) -> np.ndarray:
        q = self.data.qpos[self._scene.qpos_adr]
        return np.array([q[0], q[1], q[2]], float)

    def _set_pose2d(self, x: float, y: float, yaw: float) -> None:
        self.data.qpos[self._scene.qpos_adr] = [x, y, yaw]
        self.data.qvel[self._scene.dof_adr] = 0.0

    @property
    def T_world_base(self) -> np.ndarray:
        x, y, yaw = self._pose2d()
        return planar_T(x, y, yaw)

    def _hull_in_contact(self) -> bool:
        hull = self._scene.hull_geom
        n = self.data.ncon
        if n == 0:
            return False
        g1 = self.data.contact.geom1[:n]
        g2 = self.data.contact.geom2[:n]
        dist = self.data.contact.dist[:n]
        return bool(np.any(((g1 == hull) | (g2 == hull)) & (dist < 0)))

    def _hull_contact_with_people(self) -> bool:
        if not self._scene.people_mocap:
            return False
        n = self.data.ncon
        hull = self._scene.hull_geom
        g1 = self.data.contact.geom1[:n]
        g2 = self.data.contact.geom2[:n]
        other = np.where(g1 == hull, g2, np.where(g2 == hull, g1, -1))
        other = other[(other >= 0) & (self.data.contact.dist[:n] < 0)]
        return bool(np.any(self._scene.geom_semantic[other] == 4))

    # ---- gym API -----------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        ep = options.get("episode")
        if ep is not None:
            ep = ep if isinstance(ep, EpisodeSpec) else EpisodeSpec.from_dict(ep)
            self._load_layout(ep.layout_seed)
        else:
            ep = self._sample_episode()
        start, goal = np.asarray(ep.start, float), np.asarray(ep.goal, float)
        if not self.free_space.is_free(start[None, :2])[0]:
            raise ValueError(
                f"episode {ep.episode_id}: start {start[:2].tolist()} is not in free space"
            )
        if not self.free_space.is_free(goal[None])[0]:
            raise ValueError(f"episode {ep.episode_id}: goal {goal.tolist()} is not in free space")
        self._episode = ep
        mujoco.mj_resetData(self.model, self.data)
        self._set_pose2d(*start)
        noise_seed = int(self.np_random.integers(2**63))
        self._noise_rng = np.random.default_rng(noise_seed)  # depth and odometry
        # actuation: its own stream from the same draw (np_random's later draws stay as they were)
        self._act_rng = np.random.default_rng([noise_seed, 1])
        self._actuation = ActuationNoise(self.cfg.actuation_noise, self.dt)
        self._actuation.reset(self._act_rng)
        self._people = _People(
            self.free_space,
            self.cfg.n_people,
            np.random.default_rng(self.np_random.integers(2**63)),
            yield_to_robot=self.cfg.people_yield,
        )
        self._place_people()
        mujoco.mj_forward(self.model, self.data)
        self.goal_world = goal
        self.T_world_start = planar_T(*start)
        self._goal_field = self.free_space.distance_field_to(goal)
        geo0 = float(self._goal_field.distance(start[None, :2])[0])
        if not math.isfinite(geo0):
            raise ValueError(f"episode {ep.episode_id}: goal is unreachable from the start")
        self._odom = np.zeros(3)
        self._prev_pose = start.copy()
        self._steps = 0
        self._collisions_people = 0
        self._touching_person = False
        self._prev_geo = geo0
        self.metrics = EpisodeMetrics(dt=self.dt)
        self.metrics.reset(start[:2], geo0)
        obs = self._observe()
        info = self._info(collided=False, geo=geo0)
        info["camera"] = self.camera_info
        info["episode_spec"] = ep.to_dict()
        return obs, info

    def _sample_episode(self) -> EpisodeSpec:
        rng = self.np_random
        fs = self.free_space
        margin = ROBOT_RADIUS + self.cfg.start_clearance
        for _ in range(200):
            s = fs.sample_free(rng, 1, min_clearance=margin)[0]
            field = fs.distance_field_to(s)
            cands = fs.sample_free(rng, 32, min_clearance=margin)
            d = field.distance(cands)
            ok = np.flatnonzero((d >= self.cfg.min_geodesic) & (d <= self.cfg.max_geodesic))
            if len(ok):
                g = cands[ok[0]]
                yaw = float(rng.uniform(-math.pi, math.pi))
                return EpisodeSpec(
                    episode_id=f"sampled-{int(rng.integers(1 << 31))}",
                    layout_seed=self.cfg.layout_seed,
                    start=(float(s[0]), float(s[1]), yaw),
                    goal=(float(g[0]), float(g[1])),
                )
        raise RuntimeError("could not sample a start/goal pair within the geodesic range")

    def _check_action(self, action: Any) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        lo, hi = self.action_space.low, self.action_space.high
        bounds = f"v in [{lo[0]:g}, {hi[0]:g}] m/s, w in [{lo[1]:g}, {hi[1]:g}] rad/s"
        if a.shape != (2,):
            raise ValueError(
                f"action must have shape (2,) = [v, w], got shape {a.shape}; bounds: {bounds}"
            )
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action {a.tolist()} contains NaN or inf; bounds: {bounds}")
        eps = 1e-6
        if np.any(a < lo - eps) or np.any(a > hi + eps):
            raise ValueError(
                f"action {a.tolist()} is out of bounds ({bounds}); wrap the env with "
                "gymnasium.wrappers.ClipAction to clip"
            )
        return a

    def step(self, action):
        if self._episode is None:
            raise RuntimeError("call reset() before step()")
        v_cmd, w_cmd = self._check_action(action)
        v, w = self._actuation.apply(v_cmd, w_cmd, self._act_rng)
        v, w = float(np.clip(v, -2.0, 2.0)), float(np.clip(w, -4.0, 4.0))  # actuator ctrlrange
        collided = False
        qa = self._scene.qpos_adr
        for _ in range(self.frame_skip):
            yaw = self.data.qpos[qa[2]]
            self.data.ctrl[:3] = [v * math.cos(yaw), v * math.sin(yaw), w]
            mujoco.mj_step(self.model, self.data)
            collided |= self._hull_in_contact()
        if self._people.pos.shape[0]:
            self._people.advance(self.dt, self._pose2d()[:2])
            self._place_people()
        # after mj_step the body and camera poses in ``data`` are those of the state before the
        # last integration; recompute them so the image is rendered at the pose ``info`` reports
        mujoco.mj_forward(self.model, self.data)
        if self._people.pos.shape[0]:
            hit_person = self._hull_contact_with_people()
            collided |= hit_person
            # collision events with people (rising edges), like EpisodeMetrics.collisions
            self._collisions_people += int(hit_person and not self._touching_person)
            self._touching_person = hit_person
        self._steps += 1
        pose = self._pose2d()
        self._integrate_odometry(pose)
        xy = pose[:2]
        dist = float(np.hypot(*(self.goal_world - xy)))
        geo = float(self._goal_field.distance(xy[None])[0])
        clearance = float(self.free_space.clearance(xy[None])[0]) - ROBOT_RADIUS
        self.metrics.step(xy, collided, clearance)
        success = dist <= self.cfg.success_distance
        too_many = (
            self.cfg.max_collisions is not None
            and self.metrics.collisions >= self.cfg.max_collisions
        )
        terminated = bool(success or too_many)
        truncated = bool(not terminated and self._steps >= self.cfg.max_episode_steps)
        progress = (self._prev_geo - geo) if math.isfinite(geo) else 0.0
        self._prev_geo = geo if math.isfinite(geo) else self._prev_geo
        r_success = 10.0 if success else 0.0
        r_collision = -0.5 if collided else 0.0
        reward = float(progress + r_success + r_collision - 0.01)
        obs = self._observe()
        info = self._info(collided=collided, geo=geo)
        info["executed_action"] = np.array([v, w])
        info["reward_terms"] = {
            "progress": progress,
            "success": r_success,
            "collision": r_collision,
            "time": -0.01,
        }
        if terminated or truncated:
            reason = "success" if success else ("collisions" if too_many else "timeout")
            final = self.metrics.finish(reason, dist, geo, self.cfg.success_distance)
            final["collisions_with_people"] = self._collisions_people
            final["episode_id"] = self._episode.episode_id
            info["episode"] = final
        return obs, reward, terminated, truncated, info

    def _place_people(self) -> None:
        for k, mid in enumerate(self._scene.people_mocap):
            x, y = self._people.pos[k]
            self.data.mocap_pos[mid] = [x, y, 0.0]

    def _integrate_odometry(self, pose: np.ndarray) -> None:
        self._odom = odometry_step(
            self._odom,
            self._prev_pose,
            pose,
            self.cfg.odom_noise_trans,
            self.cfg.odom_noise_rot,
            self._noise_rng,
        )
        self._prev_pose = pose.copy()

    def _observe(self) -> dict[str, np.ndarray]:
        rgb, depth = self._camera().render_rgbd(self.data)
        depth = apply_depth_noise(depth, self.intrinsics.fx, self.cfg.depth_noise, self._noise_rng)
        depth = np.where(
            (depth >= self.cfg.depth_min) & (depth <= self.cfg.depth_max), depth, 0.0
        ).astype(np.float32)
        goal_start = inv_T(self.T_world_start) @ np.array([*self.goal_world, 0.0, 1.0])
        self._last_obs = {
            "rgb": rgb,
            "depth": depth,
            "goal": goal_start[:2].astype(np.float32),
            "odometry": self._odom.astype(np.float32),
        }
        return self._last_obs

    def _info(self, collided: bool, geo: float) -> dict[str, Any]:
        T_wb = self.T_world_base
        info = {
            "T_world_base": T_wb,
            "T_world_cam": T_wb @ self.T_base_cam,
            "collided": bool(collided),
            "distance_to_goal": float(np.hypot(*(self.goal_world - T_wb[:2, 3]))),
            "geodesic_distance_to_goal": float(geo),
            "step": self._steps,
        }
        if self.cfg.segmentation:
            seg = self._camera().render_segmentation(self.data)
            sem = np.where(seg >= 0, self._scene.geom_semantic[np.maximum(seg, 0)], 0)
            info["segmentation"] = sem.astype(np.int32)
        return info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode")
            return None
        if self.render_mode == "rgb_array":
            if self._overview is None:
                self._overview = OffscreenCamera(
                    self.model, self._scene.overview_camera_id, 640, 480
                )
            return self._overview.render_rgb(self.data)
        rgb, depth = self._last_obs["rgb"], self._last_obs["depth"]
        return depth if self.render_mode == "depth_array" else (rgb, depth)

    def close(self) -> None:
        for attr in ("_cam", "_overview"):
            cam = getattr(self, attr, None)
            if cam is not None:
                cam.close()
                setattr(self, attr, None)

    # ---- pickling: the GL context cannot be pickled; rebuild it on load ----------------------
    def __getstate__(self) -> dict[str, Any]:
        st = {k: v for k, v in self.__dict__.items() if k not in ("_cam", "_overview")}
        st["_cam"] = None
        st["_overview"] = None
        return st

    def __setstate__(self, st: dict[str, Any]) -> None:
        self.__dict__.update(st)


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, float))
    return m.reshape(3, 3)
