"""Trace one closed-loop episode step by step, for finding why an agent fails.

Writes ``OUT/<episode_id>.jsonl`` (one line per step: true and estimated pose in the world
frame, the estimate's position error ``pos_err`` against the pose of the observation it was
made from (``true`` is the pose after the step's action, so ``est`` lags it by one step), the
agent's state and route kind, the front-end's tracking outcome (``track``), the people's
true positions (``people``, dynamic env), the remaining planned length, the true and the
agent's own distance to the goal, the action) and ``OUT/<episode_id>.png`` (the floor plan, the
true and the estimated trajectory, the goal, and the planned path every ``--path-every`` steps).

    python scripts/trace_episode.py --episode-file envs/episodes/office_nav_v1.json \
        --episode nav-ref-000 --config runs/c320_real.yaml --out runs/trace
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

import simn_sim  # noqa: F401  (registers the env ids)
from simn_sim.agents import make_agent
from simn_sim.env.episodes import EpisodeSet
from simn_sim.experiments.plots import FLOORPLAN_Z_BAND, _plt
from simn_sim.geometry.paths import path_length
from simn_sim.geometry.se3 import inv_T, yaw_of


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def trace(
    env_id, env_cfg, agent_name, agent_cfg, episode, out: Path, path_every: int, snap_steps=()
) -> dict:
    env = gym.make(env_id, config=env_cfg)
    obs, info = env.reset(seed=episode.seed, options={"episode": episode})
    agent = make_agent(agent_name, env.unwrapped, agent_cfg)
    agent.reset(obs, info)
    T_ws = info["T_world_base"].copy()
    goal_w = np.asarray(episode.goal, float)
    rows, paths = [], []
    snaps: dict[int, tuple] = {}

    def paths_w(path):
        P = np.c_[np.asarray(path)[:, :2], np.zeros(len(path)), np.ones(len(path))]
        return (T_ws @ P.T).T[:, :2]

    step = 0
    while True:
        a = agent.act(obs, info)
        dbg = agent.debug()
        T_obs = info["T_world_base"].copy()  # the pose the estimate of this step refers to
        obs, _, term, trunc, info = env.step(a)
        step += 1
        T_true = info["T_world_base"]
        T_est = dbg.get("T_world_base_est")
        est = None if T_est is None else (T_ws @ np.asarray(T_est, float))
        path = dbg.get("path")
        row = {
            "step": step,
            "true": [float(T_true[0, 3]), float(T_true[1, 3])],
            "yaw": float(np.degrees(yaw_of(T_true))),
            "odom": [float(v) for v in obs["odometry"]],  # (x, y, yaw rad) after the step
            "est": None if est is None else [float(est[0, 3]), float(est[1, 3])],
            "state": agent.state(),
            "route": dbg.get("route"),
            "ctg": dbg.get("cost_to_go"),
            "path_len": None if path is None else float(path_length(np.asarray(path))),
            "geo": float(info["geodesic_distance_to_goal"]),
            "dist": float(info["distance_to_goal"]),
            "action": [float(a[0]), float(a[1])],
            "collided": bool(info["collided"]),
        }
        slam = getattr(getattr(agent, "world", None), "slam", None)
        last = getattr(slam, "last", None)
        if last is not None:  # the front-end's step: tracking outcome, frame, revisit
            row["track"] = {
                "ok": bool(last.success),
                "reason": last.reason,
                "rms": _finite(last.inlier_rms),
                "frame": int(last.frame_id),
                "new_frame": bool(last.new_local_frame),
                "revisit": last.revisit_frame,
                "window_sigmas": _finite(slam.tracker.window_sigmas),
            }
        people = getattr(env.unwrapped, "_people", None)
        if people is not None and len(people.pos):  # true positions after the step (world)
            row["people"] = np.round(np.asarray(people.pos, float), 3).tolist()
        if est is not None:
            row["yaw_err"] = float(np.degrees(yaw_of(inv_T(T_obs) @ est)))  # (-180, 180]
            row["dist_est"] = float(np.hypot(*(goal_w - est[:2, 3])))
            row["pos_err"] = float(np.hypot(*(est[:2, 3] - T_obs[:2, 3])))
        rows.append(row)
        if path is not None and step % path_every == 0:
            P = np.c_[np.asarray(path)[:, :2], np.zeros(len(path)), np.ones(len(path))]
            paths.append((T_ws @ P.T).T[:, :2])
        if step in snap_steps:
            occ = agent.obstacles.planning.occupied_centres()
            P = np.c_[occ[:, :2], np.zeros(len(occ)), np.ones(len(occ))]
            snaps[step] = ((T_ws @ P.T).T[:, :2], None if path is None else paths_w(path))
        if term or trunc:
            break
    ep = info["episode"]
    out.mkdir(parents=True, exist_ok=True)
    with open(out / f"{episode.episode_id}.jsonl", "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 8))
    for poly in env.unwrapped.layout.footprints(FLOORPLAN_Z_BAND):
        p = np.asarray(poly)
        ax.fill(p[:, 0], p[:, 1], color="0.6", lw=0)
    for k, p in enumerate(paths):
        ax.plot(p[:, 0], p[:, 1], color=plt.cm.viridis(k / max(len(paths) - 1, 1)), lw=0.6)
    tr = np.array([r["true"] for r in rows])
    ax.plot(tr[:, 0], tr[:, 1], "k-", lw=1.5, label="true")
    es = np.array([r["est"] for r in rows if r["est"] is not None])
    if len(es):
        ax.plot(es[:, 0], es[:, 1], "r--", lw=1.0, label="estimate")
    ax.plot(*episode.start[:2], "bo", label="start")
    ax.plot(*goal_w, "g*", ms=14, label="goal")
    ax.set_aspect("equal")
    ax.legend(loc="upper right")
    ax.set_title(
        f"{episode.episode_id}: {ep['termination']}, path {ep['path_length_m']:.1f} m, "
        f"geodesic {ep['geodesic_distance_m']:.1f} m"
    )
    fig.savefig(out / f"{episode.episode_id}.png", dpi=90)
    plt.close(fig)
    if snaps:  # the planning obstacles (world x-y) at each snapshot step, for analysis
        np.savez_compressed(
            out / f"{episode.episode_id}_snaps.npz", **{f"step{k}": v[0] for k, v in snaps.items()}
        )
    for k, (occ, pw) in snaps.items():
        fig, ax = plt.subplots(figsize=(8, 8))
        for poly in env.unwrapped.layout.footprints(FLOORPLAN_Z_BAND):
            p = np.asarray(poly)
            ax.fill(p[:, 0], p[:, 1], color="0.8", lw=0)
        ax.plot(occ[:, 0], occ[:, 1], "r.", ms=1)
        if pw is not None:
            ax.plot(pw[:, 0], pw[:, 1], "b-")
        ax.plot(*rows[k - 1]["true"], "ko")
        ax.plot(*goal_w, "g*", ms=14)
        ax.set_aspect("equal")
        ax.set_title(f"{episode.episode_id} step {k}: planning obstacles (red), path (blue)")
        fig.savefig(out / f"{episode.episode_id}_step{k:03d}.png", dpi=90)
        plt.close(fig)
    env.close()
    return {k: ep[k] for k in ("termination", "path_length_m", "geodesic_distance_m", "spl")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episode-file", type=Path, required=True)
    ap.add_argument("--episode", action="append", required=True, help="episode id (repeatable)")
    ap.add_argument("--agent", default="simn")
    ap.add_argument("--config", type=Path, help="env config YAML")
    ap.add_argument("--agent-config", type=Path, help="agent config YAML")
    ap.add_argument("--out", type=Path, default=Path("runs/trace"))
    ap.add_argument("--path-every", type=int, default=20)
    ap.add_argument("--snap", type=int, nargs="*", default=[], help="steps to draw the map at")
    args = ap.parse_args()
    es = EpisodeSet.load(args.episode_file)
    by_id = {e.episode_id: e for e in es.episodes}
    env_cfg = yaml.safe_load(args.config.read_text()) if args.config else {}
    agent_cfg = yaml.safe_load(args.agent_config.read_text()) if args.agent_config else {}
    for eid in args.episode:
        if eid not in by_id:
            raise SystemExit(f"episode {eid!r} is not in {args.episode_file}")
        r = trace(
            es.env_id,
            env_cfg,
            args.agent,
            agent_cfg,
            by_id[eid],
            args.out,
            args.path_every,
            set(args.snap),
        )
        print(eid, r)


if __name__ == "__main__":
    main()
