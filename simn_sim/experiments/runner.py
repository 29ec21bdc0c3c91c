"""Run one episode of an agent in an env and turn it into one JSON record.

``run_episode`` never raises for a failure inside the episode: the record carries the error and
its traceback, so a batch goes on. The record fields are documented in the README (identity,
outcome, costs, ``ate_rmse_m``, ``error``).
"""

from __future__ import annotations

import json
import math
import time
import traceback
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from simn_sim.config import Config
from simn_sim.eval.revisits import revisit_truth

RECORD_FIELDS = (
    "episode_id",
    "layout_seed",
    "seed",
    "agent",
    "env_id",
    "config_hash",
    "success",
    "spl",
    "soft_spl",
    "path_length_m",
    "geodesic_distance_m",
    "collisions",
    "collisions_with_people",
    "min_clearance_m",
    "steps",
    "termination",
    "sim_time_s",
    "wall_time_s",
    "plan_ms_median",
    "plan_ms_p95",
    "map_ms_median",
    "control_ms_median",
    "act_ms_mean",
    "act_ms_p95",
    "tracking_map",
    "ate_rmse_m",
    "revisits_correct",
    "revisits_off_fine",
    "revisit_opportunities",
    "revisit_opportunities_closed",
    "revisit_err_m_median",
    "revisit_err_deg_median",
    "error",
)


def config_hash(env_cfg: dict[str, Any], agent: str, agent_cfg: dict[str, Any]) -> str:
    import hashlib

    blob = json.dumps({"env": env_cfg, "agent": agent, "agent_cfg": agent_cfg}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:12]


def _ate_rmse(true_xy: list[np.ndarray], est_xy: list[np.ndarray]) -> float | None:
    """RMSE of the estimated planar positions, both in the world frame (no alignment: the
    estimate, in the agent's start frame, is mapped through the true start pose)."""
    if not est_xy or len(est_xy) != len(true_xy):
        return None
    d = np.asarray(true_xy) - np.asarray(est_xy)
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def run_episode(
    env_id: str,
    env_cfg: dict[str, Any] | Config,
    agent_name: str,
    agent_cfg: dict[str, Any] | None = None,
    episode: dict[str, Any] | None = None,
    seed: int = 0,
    rerun_path: str | Path | None = None,
    progress: Any = None,
    env: gym.Env | None = None,
    image_every: int = 2,
) -> dict[str, Any]:
    """Run one episode; returns the record (see :data:`RECORD_FIELDS`).

    ``episode``: an episode spec dict (``envs/`` episode files); ``None`` samples one from
    ``seed``. ``env`` may be passed to reuse a created env. ``progress``: an object with
    ``update(n)`` (e.g. tqdm) called once per step. ``image_every``: the recording holds the
    camera images of every n-th step only.
    """
    from simn_sim.agents import make_agent
    from simn_sim.viz import make_recorder

    env_cfg_d = env_cfg.to_dict() if isinstance(env_cfg, Config) else dict(env_cfg)
    agent_cfg = dict(agent_cfg or {})
    rec: dict[str, Any] = {k: None for k in RECORD_FIELDS}
    rec.update(
        episode_id=(episode or {}).get("episode_id", f"seed-{seed}"),
        layout_seed=(episode or {}).get("layout_seed", env_cfg_d.get("layout_seed")),
        seed=int((episode or {}).get("seed", seed)),
        agent=agent_name,
        env_id=env_id,
        config_hash=config_hash(env_cfg_d, agent_name, agent_cfg),
    )
    t0 = time.perf_counter()
    own_env = env is None
    recorder = None
    agent = None
    try:
        if own_env:
            env = gym.make(env_id, config=env_cfg_d)
        options = {"episode": episode} if episode is not None else None
        obs, info = env.reset(seed=rec["seed"], options=options)
        rec["episode_id"] = (
            info["episode_spec"]["episode_id"] if episode is None else rec["episode_id"]
        )
        agent = make_agent(agent_name, env.unwrapped, agent_cfg)
        agent.reset(obs, info)
        recorder = make_recorder(
            rerun_path, env.unwrapped.camera_info.intrinsics, image_every=image_every
        )
        from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND

        free_space = getattr(env.unwrapped, "free_space", None)
        recorder.log_layout(
            env.unwrapped.layout.footprints(ROBOT_Z_BAND),
            np.asarray(info["episode_spec"]["goal"]),
            robot_radius=getattr(free_space, "robot_radius", ROBOT_RADIUS),
            robot_z=ROBOT_Z_BAND,
        )
        true_xy: list[np.ndarray] = []
        est_xy: list[np.ndarray] = []
        true_cam: list[np.ndarray] = []  # the true camera pose of each act()'s observation
        plan_ms: list[float] = []
        map_ms: list[float] = []
        ctl_ms: list[float] = []
        T_ws = info["T_world_base"].copy()
        recorder.set_agent_frame(T_ws)  # drawing only: agents report in their start frame
        step = 0
        recorder.log_step(step, obs, info, agent.debug())
        while True:
            # the pose estimated from this observation is paired with the true pose at this
            # observation (pairing it with the pose after the step added the step's motion to
            # the error: 5 cm ATE for exact odometry at 320x240, docs/slam.md)
            xy_now = info["T_world_base"][:2, 3].copy()
            true_cam.append(np.asarray(info["T_world_cam"], float).copy())
            tc = time.perf_counter()
            action = agent.act(obs, info)
            ctl_ms.append((time.perf_counter() - tc) * 1e3)
            dbg = agent.debug()
            if dbg.get("plan_ms") is not None:
                plan_ms.append(float(dbg["plan_ms"]))
            if dbg.get("map_ms") is not None:
                map_ms.append(float(dbg["map_ms"]))
            T_est = dbg.get("T_world_base_est")
            if T_est is not None:  # the agent's own frame is the episode start frame
                true_xy.append(xy_now)
                est_xy.append((T_ws @ np.asarray(T_est, float))[:2, 3].copy())
            obs, _, term, trunc, info = env.step(action)
            step += 1
            recorder.log_step(step, obs, info, dbg)
            if progress is not None:
                progress.update(1)
            if term or trunc:
                break
        ep = info["episode"]
        for k in RECORD_FIELDS:
            if k in ep and k != "episode_id":
                rec[k] = ep[k]
        rec["plan_ms_median"] = float(np.median(plan_ms)) if plan_ms else None
        rec["plan_ms_p95"] = float(np.percentile(plan_ms, 95)) if plan_ms else None
        rec["map_ms_median"] = float(np.median(map_ms)) if map_ms else None
        rec["control_ms_median"] = float(np.median(ctl_ms)) if ctl_ms else None
        # time per act() call (the whole control step: world model, planning, control)
        rec["act_ms_mean"] = float(np.mean(ctl_ms)) if ctl_ms else None
        rec["act_ms_p95"] = float(np.percentile(ctl_ms, 95)) if ctl_ms else None
        # which map the pose was tracked against ("points", "learned"; None: no tracking)
        rec["tracking_map"] = agent.debug().get("tracking_map")
        rec["ate_rmse_m"] = _ate_rmse(true_xy, est_xy)
        rec["agent_state"] = agent.state()
        rec.update(agent.counters())
        ev = agent.revisit_events() if hasattr(agent, "revisit_events") else None
        if ev is not None:  # revisits judged against the true poses (eval/revisits.py)
            rec.update(
                revisit_truth(ev["frame_obs"], ev["accepted"], true_cam, ev["exclude_recent"])
            )
    except Exception as e:  # noqa: BLE001 - a failing episode is recorded, never fatal
        rec["error"] = f"{type(e).__name__}: {e}\n{traceback.format_exc()}"
        rec["termination"] = "error"
    finally:
        rec["wall_time_s"] = time.perf_counter() - t0
        close = getattr(agent, "close", None)
        if close is not None:
            try:
                close()
            except Exception as e:  # noqa: BLE001 - recorded; the record is kept
                if rec.get("error") is None:
                    rec["error"] = f"agent.close: {type(e).__name__}: {e}"
                    rec["termination"] = "error"
        if recorder is not None:
            recorder.close()
        if own_env and env is not None:
            env.close()
    for k, v in list(rec.items()):
        if isinstance(v, float) and not math.isfinite(v):
            rec[k] = None if math.isnan(v) else v
        if isinstance(v, np.generic):
            rec[k] = v.item()
    return rec


def write_json(path: str | Path, obj: Any) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(obj, indent=2, sort_keys=True, default=str))
