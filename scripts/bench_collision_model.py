"""Which part of the learned local frames should the planner's collision model come from?

Drives the default ``simn`` agent (the learned map) through episodes and, every ``--every``
steps and at the end, builds candidate obstacle maps from its local frames and judges their
x-y cells (the collision model's 5 cm grid and 0.06-1.0 m band) against the layout's true
footprints (:mod:`simn_sim.eval.occupancy`):

* ``stores``: the frames' carved obstacle stores (what the planner uses now);
* ``keypoints``: the learned map's neural key points labelled obstacle (never carved: key
  points are only ever added);
* ``stores, |sdf| <= t``: the store points where the frame's learned SDF F_theta is within t
  of its zero level (points the decoder does not place on a surface are dropped);
* ``keypoints, |sdf| <= t``: the same filter on the labelled key points.

Each frame's points go to the world through the **true** camera pose at the frame's opening
(the frame's coordinates are that camera's), so localization drift between frames does not
enter: the figures compare map sources, not poses. ``stores (estimated anchors)`` is the store
map as the planner places it (estimated anchors, aligned at frame 0), for scale.

Per candidate: cells, phantom cells (centre further than ``--tol`` from every footprint),
precision, recall against the union of all candidates' true cells, and the time to build it.
The agent's behaviour is not changed (the collision model it plans with stays the stores).

    MUJOCO_GL=egl .venv/bin/python scripts/bench_collision_model.py --out F.json \\
        [--episode-file envs/episodes/office_nav_v2.json --per-layout 1] [--dynamic 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import simn_sim  # noqa: E402,F401
from simn_sim.agents import make_agent  # noqa: E402
from simn_sim.env.episodes import EpisodeSet  # noqa: E402
from simn_sim.eval.occupancy import cells_of, occupancy_scores  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary
from simn_sim.geometry.se3 import inv_T, transform_points  # noqa: E402
from simn_sim.mapping.mapper import ImplicitMap  # noqa: E402
from simn_sim.paths import envs_dir  # noqa: E402
from simn_sim.semantics import OBSTACLE  # noqa: E402

RES = 0.05  # the collision model's cell (CollisionConfig default)
Z_BAND = (0.06, 1.0)  # its height band (ObstacleConfig.collision)
SDF_TOLS = (0.05, 0.10)


def _sdf_keep(imap: ImplicitMap, P: np.ndarray, tol: float) -> np.ndarray:
    if len(P) == 0:
        return np.zeros(0, bool)
    q = imap.query(P.astype(np.float32))
    return q.valid & (np.abs(np.nan_to_num(q.sdf, nan=np.inf)) <= tol)


def candidates(agent, T_anchor_true: list[np.ndarray]) -> tuple[dict, dict]:
    """World points of each candidate map (true anchors) and the ms each took to build."""
    slam = agent.world.slam
    slam.sync()  # the last frame's training chunk (train_async) is written back
    frames = agent.world.frames
    min_frame = agent.obstacles.min_frame
    out: dict[str, list[np.ndarray]] = {}
    ms: dict[str, float] = {}

    def add(name: str, fid: int, P: np.ndarray) -> None:
        out.setdefault(name, []).append(transform_points(T_anchor_true[fid], P.astype(np.float64)))

    for fid, st in frames.states.items():
        if fid < min_frame:
            continue
        S = st.obstacles.points
        t = time.perf_counter()
        add("stores", fid, S)
        ms["stores"] = ms.get("stores", 0.0) + (time.perf_counter() - t) * 1e3
        imap = st.frame.map
        if not isinstance(imap, ImplicitMap):
            continue
        t = time.perf_counter()
        pts = imap.points
        K = pts.positions[pts.labels == OBSTACLE].cpu().numpy()
        add("keypoints", fid, K)
        ms["keypoints"] = ms.get("keypoints", 0.0) + (time.perf_counter() - t) * 1e3
        for src, P in (("stores", S), ("keypoints", K)):
            for tol in SDF_TOLS:
                name = f"{src}, |sdf| <= {tol:.2f}"
                t = time.perf_counter()
                add(name, fid, P[_sdf_keep(imap, P, tol)])
                ms[name] = ms.get(name, 0.0) + (time.perf_counter() - t) * 1e3
    pts = {k: np.concatenate(v) for k, v in out.items()}
    # the store map as the planner places it, aligned at frame 0's true anchor
    T_align = T_anchor_true[0] @ inv_T(frames.topo.anchor(0))
    pts["stores (estimated anchors)"] = (
        transform_points(T_align, agent.obstacles.model_points(frames).astype(np.float64))
        if not agent.obstacles.bump_points
        else transform_points(T_align, frames.obstacle_points_world(min_frame).astype(np.float64))
    )
    return pts, ms


def judge(pts: dict, footprints: list, tol: float) -> dict:
    scores = {
        k: occupancy_scores(cells_of(P, RES, Z_BAND), footprints, RES, tol) for k, P in pts.items()
    }
    ref = frozenset().union(*(s["true_set"] for k, s in scores.items() if "estimated" not in k))
    for s in scores.values():
        s["recall"] = len(s["true_set"] & ref) / len(ref) if ref else None
        s["ref_cells"] = len(ref)
        del s["true_set"]
    return scores


def run_episode(
    env_id: str, ep, env_cfg: dict, every: int, max_steps: int, tol: float, agent_cfg: dict
) -> dict:
    env = gym.make(env_id, config=env_cfg)
    obs, info = env.reset(seed=ep.seed, options={"episode": ep.to_dict()})
    agent = make_agent("simn", env.unwrapped, agent_cfg)
    agent.reset(obs, info)
    layout = env.unwrapped.layout
    footprints = layout.footprints(Z_BAND)
    true_cam = [np.asarray(info["T_world_cam"], float)]
    snaps, steps, ms_acc = [], 0, {}
    while True:
        a = agent.act(obs)
        obs, _, term, trunc, info = env.step(a)
        steps += 1
        end = term or trunc or steps >= max_steps
        if steps % every == 0 or end:
            ev = agent.revisit_events()
            frame_obs = ev["frame_obs"] if ev is not None else None
            if frame_obs is None:
                raise RuntimeError("the agent reports no frame openings (revisit checks off?)")
            T_anchor_true = [true_cam[i] for i in frame_obs]
            pts, ms = candidates(agent, T_anchor_true)
            for k, v in ms.items():
                ms_acc.setdefault(k, []).append(v)
            snaps.append({"step": steps, "n_frames": len(frame_obs), **judge(pts, footprints, tol)})
        if end:
            termination = info["episode"]["termination"] if term or trunc else "cut"
            break
        true_cam.append(np.asarray(info["T_world_cam"], float))
    agent.world.close()
    env.close()
    return {
        "episode": ep.episode_id,
        "env_id": env_id,
        "steps": steps,
        "termination": termination,
        "snapshots": snaps,
        "build_ms_mean": {k: float(np.mean(v)) for k, v in ms_acc.items()},
    }


def pooled(episodes: list[dict]) -> dict:
    """Cells, phantoms and true cells summed over every snapshot of every episode."""
    tot: dict[str, dict[str, float]] = {}
    for e in episodes:
        for s in e["snapshots"]:
            for k, v in s.items():
                if not isinstance(v, dict):
                    continue
                t = tot.setdefault(
                    k, {"cells": 0, "true": 0, "phantom": 0, "recall_num": 0.0, "ref": 0}
                )
                t["cells"] += v["cells"]
                t["true"] += v["true"]
                t["phantom"] += v["phantom"]
                if v["recall"] is not None:
                    t["recall_num"] += v["recall"] * v["ref_cells"]
                    t["ref"] += v["ref_cells"]
    out = {}
    for k, t in tot.items():
        out[k] = {
            "cells": t["cells"],
            "phantom": t["phantom"],
            "precision": t["true"] / t["cells"] if t["cells"] else None,
            "recall": t["recall_num"] / t["ref"] if t["ref"] else None,
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episode-file", type=Path, default=envs_dir() / "episodes/office_nav_v2.json")
    ap.add_argument("--per-layout", type=int, default=1, help="first N episodes of each layout")
    ap.add_argument(
        "--episode-ids", default="", help="comma-separated ids (instead of --per-layout)"
    )
    ap.add_argument("--dynamic", type=int, default=0, help="first N episodes of office_dynamic_v1")
    ap.add_argument("--every", type=int, default=100, help="steps between snapshots")
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--tol", type=float, default=0.10, help="m from a footprint for a true cell")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument(
        "--agent-config", type=json.loads, default={}, help="JSON, e.g. '{\"slam\": {...}}'"
    )
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    env_cfg = {"width": args.width, "height": args.height}
    todo = []
    eset = EpisodeSet.load(args.episode_file)
    seen: dict[str, int] = {}
    ids = [i for i in args.episode_ids.split(",") if i]
    for ep in eset.episodes:
        if ids:
            if ep.episode_id in ids:
                todo.append((eset.env_id, ep))
            continue
        key = str(ep.layout_seed)
        if seen.get(key, 0) < args.per_layout:
            seen[key] = seen.get(key, 0) + 1
            todo.append((eset.env_id, ep))
    if args.dynamic:
        dset = EpisodeSet.load(envs_dir() / "episodes/office_dynamic_v1.json")
        todo += [(dset.env_id, ep) for ep in dset.episodes[: args.dynamic]]
    results = []
    for env_id, ep in todo:
        r = run_episode(
            env_id, ep, env_cfg, args.every, args.max_steps, args.tol, args.agent_config
        )
        results.append(r)
        last = r["snapshots"][-1]
        print(
            f"{r['episode']}: {r['steps']} steps ({r['termination']}), "
            + ", ".join(
                f"{k}: {v['precision']:.3f}/{v['recall']:.3f}"
                for k, v in last.items()
                if isinstance(v, dict) and v["precision"] is not None
            ),
            flush=True,
        )
    static = [r for r in results if "Dynamic" not in r["env_id"]]
    dynamic = [r for r in results if "Dynamic" in r["env_id"]]
    report = {
        "machine": f"{machine_summary()}, Python {platform.python_version()}",
        "args": {k: str(v) for k, v in vars(args).items()},
        "resolution": RES,
        "z_band": Z_BAND,
        "pooled_static": pooled(static),
        "pooled_dynamic": pooled(dynamic) if dynamic else None,
        "episodes": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    for name, p in (("static", report["pooled_static"]), ("dynamic", report["pooled_dynamic"])):
        if not p:
            continue
        print(f"\n{name}: candidate | cells | phantom | precision | recall | build ms")
        ms = {}
        for r in static if name == "static" else dynamic:
            for k, v in r["build_ms_mean"].items():
                ms.setdefault(k, []).append(v)
        for k, v in p.items():
            b = f"{np.mean(ms[k]):.1f}" if k in ms else "-"
            print(
                f"{k} | {v['cells']} | {v['phantom']} | {v['precision']:.3f} | {v['recall']:.3f} | {b}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
