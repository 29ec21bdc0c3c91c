"""The agent's SLAM front-end on recorded closed-loop sequences: record once, replay cheaply.

``record``: run the ``simn`` agent closed loop on a few ``office_nav_v1`` episodes and save, per
step, what its world model saw (rgb, depth, odometry) with the true base pose, plus the camera
(intrinsics, ``T_base_cam``) once; one compressed npz per episode and sensing condition.

``replay``: feed those sequences to the world model's pose alone (the SLAM front-end's
``SimnSlam.process`` per step exactly as ``SlamWorld.update`` calls it from
:class:`~simn_sim.agents.simn.SimnAgent`; the odometry pose source's pose is the odometry) for the
odometry pose source and the SLAM front-end with one or more :class:`SlamConfig` variants
(``SlamConfig.for_points_agent(**changes)``), and report the ATE: RMSE of the estimated base x-y
against the true one, both in the episode start frame, each estimate paired with the true pose
of the observation it was made from. ``lagged`` pairs it with the next step's true pose, as
``experiments.runner`` did before it was fixed.

    OMP_NUM_THREADS=1 MUJOCO_GL=egl .venv/bin/python scripts/bench_agent_slam.py record \\
        --out runs/agent_slam --sensing realistic ideal
    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_agent_slam.py replay --root runs/agent_slam \\
        --variant base '{}' --variant w '{"depth_sigma_per_m2": 0.0026}'

A variant's JSON may name its preset with a ``"preset"`` key: ``"agent"`` (the default,
``SlamConfig.for_points_agent``: the point store) or ``"learned"`` (``SlamConfig.for_agent``:
tracking on the learned map, training on the worker thread); ``--preset`` sets it for the
variants that do not. Points vs learned on the realistic sequences, with the odometry:

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_agent_slam.py replay --odometry \\
        --sequences realistic_nav-L2-004 --variant points '{}' \\
        --variant learned '{"preset": "learned"}'
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

REPO = Path(__file__).resolve().parents[1]
EPISODES = ["nav-ref-002", "nav-ref-006", "nav-L1-004", "nav-L2-004", "nav-L3-000"]


# ---- record ------------------------------------------------------------------------------------
def record(
    out: Path,
    episodes: list[str],
    sensing: list[str],
    width: int,
    height: int,
    episode_file: Path | None = None,
) -> None:
    import gymnasium as gym

    import simn_sim  # noqa: F401  (registers the envs)
    from simn_sim.agents import make_agent

    spec = json.loads((episode_file or REPO / "envs/episodes/office_nav_v1.json").read_text())
    by_id = {e["episode_id"]: e for e in spec["episodes"]}
    unknown = sorted(set(episodes) - set(by_id))
    if unknown:
        raise SystemExit(f"episode id(s) not in the episode file: {unknown}")
    out.mkdir(parents=True, exist_ok=True)
    for sens in sensing:
        cfg = {"width": width, "height": height, "sensing": sens}
        env = gym.make(spec.get("env_id", "SimnOffice-v0"), config=cfg)
        for eid in episodes:
            path = out / f"{sens}_{eid}.npz"
            if path.is_file():
                print(f"{path} exists")
                continue
            ep = by_id[eid]
            t0 = time.perf_counter()
            obs, info = env.reset(seed=int(ep.get("seed", 0)), options={"episode": ep})
            agent = make_agent("simn", env.unwrapped, {})
            agent.reset(obs, info)
            cam = info["camera"]
            rgb, depth, odom, T_wb, est = [], [], [], [], []
            while True:
                rgb.append(obs["rgb"])
                depth.append(obs["depth"])
                odom.append(np.asarray(obs["odometry"], np.float64))
                T_wb.append(np.asarray(info["T_world_base"], np.float64))
                action = agent.act(obs, info)
                est.append(np.asarray(agent.debug().get("T_world_base_est"), np.float64))
                obs, _, term, trunc, info = env.step(action)
                if term or trunc:
                    break
            e = info["episode"]
            intr = cam.intrinsics
            tmp = path.with_suffix(".tmp.npz")
            np.savez_compressed(
                tmp,
                rgb=np.stack(rgb),
                depth=np.stack(depth).astype(np.float32),
                odometry=np.stack(odom),
                T_world_base=np.stack(T_wb),
                T_world_base_est_loop=np.stack(est),
                intrinsics=np.array([intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy]),
                T_base_cam=np.asarray(cam.T_base_cam, np.float64),
                dt=float(env.unwrapped.dt),
                meta=json.dumps(
                    {
                        "episode_id": eid,
                        "sensing": sens,
                        "env_config": env.unwrapped.cfg.to_dict(),
                        "success": e.get("success"),
                        "termination": e.get("termination"),
                    },
                    default=str,
                ),
            )
            tmp.rename(path)
            print(
                f"{path}: {len(rgb)} steps, success {e.get('success')}, "
                f"{time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        env.close()


# ---- replay ------------------------------------------------------------------------------------
def load(path: Path) -> dict[str, Any]:
    z = np.load(path)
    d = {k: z[k] for k in z.files}
    d["meta"] = json.loads(str(d["meta"]))
    return d


def planar_T(x: float, y: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = [x, y]
    return T


PRESETS = ("agent", "learned")


def slam_config(changes: dict[str, Any], preset: str = "agent"):
    """``SlamConfig.for_points_agent(**changes)`` or, with preset ``learned`` (or a ``"preset"`` key in
    ``changes``), ``SlamConfig.for_agent(**changes)``."""
    from simn_sim.slam.config import SlamConfig

    changes = dict(changes)
    preset = changes.pop("preset", preset)
    if preset not in PRESETS:
        raise SystemExit(f"unknown preset {preset!r} (one of {PRESETS})")
    make = SlamConfig.for_agent if preset == "learned" else SlamConfig.for_points_agent
    return make(**changes)


def replay(
    seq: dict[str, Any],
    pose_source: str,
    changes: dict[str, Any],
    steps: int = 0,
    preset: str = "agent",
):
    """Run the world model's pose over ``seq``; per-step estimate / truth (start frame), track ms
    and per-step events. ``slam``: :meth:`SimnSlam.process` per step exactly as
    :meth:`SlamWorld.update` calls it (the obstacle map it then feeds does not change the pose,
    and is skipped); ``odometry``: :class:`OdometryWorld`'s pose is the odometry as it comes."""
    from simn_sim.geometry.camera import Intrinsics
    from simn_sim.geometry.se3 import inv_T
    from simn_sim.slam.pipeline import SimnSlam

    w, h, fx, fy, cx, cy = seq["intrinsics"]
    intr = Intrinsics(int(w), int(h), fx, fy, cx, cy)
    T_bc = seq["T_base_cam"]
    T_cb = inv_T(T_bc)
    slam = SimnSlam(slam_config(changes, preset), intr, T_base_cam=T_bc)
    # tracking cost as CPU time of this process (the shared machine's wall clock measures the
    # other jobs): point selection, prediction and registration, as SlamFrame.track_ms times
    cpu = {"track": 0.0}
    tracker = slam.tracker

    def timed(fn):
        def wrapped(*a, **k):
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                cpu["track"] += time.process_time() - t

        return wrapped

    tracker.track_points = timed(tracker.track_points)
    tracker.track = timed(tracker.track)
    n = len(seq["depth"]) if steps <= 0 else min(steps, len(seq["depth"]))
    T_ws_inv = inv_T(seq["T_world_base"][0])
    est, true, track_ms, step_ms, events = [], [], [], [], []
    dt = float(seq["dt"])
    for k in range(n):
        T_odom = planar_T(*seq["odometry"][k])
        true.append(T_ws_inv @ seq["T_world_base"][k])
        if pose_source == "odometry":
            est.append(T_odom)
            continue
        t0 = time.process_time()
        cpu["track"] = 0.0
        fr = slam.process(k * dt, seq["rgb"][k], seq["depth"][k], T_odom @ T_bc)
        step_ms.append((time.process_time() - t0) * 1e3)
        track_ms.append(cpu["track"] * 1e3)
        est.append(fr.T_world_cam @ T_cb)
        events.append(
            (fr.success, fr.reason, fr.new_local_frame, fr.revisit_accepted, fr.inlier_rms)
        )
    if pose_source != "odometry":
        slam.close()  # the training worker thread (train_async), if any
    return np.array(est), np.array(true), np.array(track_ms), np.array(step_ms), events


def ate(est: np.ndarray, true: np.ndarray, lag: int = 0) -> float:
    e, t = est[: len(est) - lag, :2, 3], true[lag:, :2, 3]
    return float(np.sqrt(np.mean(np.sum((e - t) ** 2, axis=1))))


def yaw_err(est: np.ndarray, true: np.ndarray) -> np.ndarray:
    ye = np.arctan2(est[:, 1, 0], est[:, 0, 0])
    yt = np.arctan2(true[:, 1, 0], true[:, 0, 0])
    return np.degrees(np.angle(np.exp(1j * (ye - yt))))


def summarize(est, true, events) -> dict[str, Any]:
    err = np.hypot(*(est[:, :2, 3] - true[:, :2, 3]).T)
    out = {
        "ate": ate(est, true),
        "ate_lagged": ate(est, true, 1),
        "final_m": float(err[-1]),
        "max_m": float(err.max()),
        "yaw_rms_deg": float(np.sqrt(np.mean(yaw_err(est, true) ** 2))),
    }
    if events:
        ok = np.array([e[0] for e in events[1:]])
        out["fail"] = int((~ok).sum())
        out["weak"] = int(sum("weakly" in e[1] for e in events))
        out["frames"] = int(sum(e[2] for e in events))
        out["revisits"] = int(sum(e[3] for e in events))
        reasons: dict[str, int] = {}
        for e in events[1:]:
            if not e[0]:
                key = e[1].split(" ")[0] if "correction" not in e[1] else e[1].split("(")[0][:12]
                reasons[key] = reasons.get(key, 0) + 1
        out["fail_reasons"] = reasons
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("--out", type=Path, default=REPO / "runs" / "agent_slam")
    r.add_argument("--episodes", nargs="+", default=EPISODES)
    r.add_argument(
        "--episode-file", type=Path, default=None, help="default: envs/episodes/office_nav_v1.json"
    )
    r.add_argument("--sensing", nargs="+", default=["realistic", "ideal"])
    r.add_argument("--width", type=int, default=320)
    r.add_argument("--height", type=int, default=240)
    p = sub.add_parser("replay")
    p.add_argument("--root", type=Path, default=REPO / "runs" / "agent_slam")
    p.add_argument("--sequences", nargs="*", default=None, help="npz stems (default: all)")
    p.add_argument(
        "--variant",
        nargs=2,
        action="append",
        metavar=("NAME", "JSON"),
        help="SlamConfig.for_points_agent changes (repeatable; default: the preset as is)",
    )
    p.add_argument("--odometry", action="store_true", help="also the odometry pose source")
    p.add_argument(
        "--preset",
        choices=PRESETS,
        default="agent",
        help="SlamConfig preset of the variants without a 'preset' key",
    )
    p.add_argument("--steps", type=int, default=0, help="first N steps only (0: all)")
    p.add_argument("--jsonl", type=Path, default=None, help="append one row per run")
    p.add_argument("--per-step", type=Path, default=None, help="npz of per-step errors")
    a = ap.parse_args()
    if a.cmd == "record":
        record(a.out, a.episodes, a.sensing, a.width, a.height, a.episode_file)
        return 0
    import torch

    import simn_sim.slam.pipeline  # noqa: F401  (all code loaded before the long runs start)

    torch.set_num_threads(1)
    variants = a.variant or [["preset", "{}"]]
    paths = sorted(q for q in a.root.glob("*.npz") if not q.name.endswith(".tmp.npz"))
    if a.sequences:
        paths = [q for q in paths if q.stem in a.sequences]
    per_step: dict[str, np.ndarray] = {}
    rows = []
    for q in paths:
        seq = load(q)
        runs = [("odometry", "odometry", {})] if a.odometry else []
        runs += [(name, "slam", json.loads(js)) for name, js in variants]
        for name, src, changes in runs:
            est, true, tms, sms, ev = replay(seq, src, changes, a.steps, a.preset)
            s = summarize(est, true, ev)
            loop = seq["T_world_base_est_loop"][: len(est)]
            if src == "slam" and not changes and a.preset == "agent" and loop.shape == est.shape:
                # the preset replayed must give the closed loop's own estimates
                s["loop_diff_m"] = float(np.abs(loop[:, :2, 3] - est[:, :2, 3]).max())
            s.update(
                seq=q.stem,
                variant=name,
                steps=len(est),
                # CPU ms of this process (time.process_time), not wall time
                track_ms_mean=float(np.nanmean(tms)) if src == "slam" else None,
                track_ms_median=float(np.nanmedian(tms)) if src == "slam" else None,
                step_ms_mean=float(np.mean(sms)) if len(sms) else None,
                step_ms_p95=float(np.percentile(sms, 95)) if len(sms) else None,
                preset=changes.get("preset", a.preset) if src == "slam" else None,
            )
            rows.append(s)
            per_step[f"{q.stem}/{name}/est"] = est
            per_step[f"{q.stem}/{name}/true"] = true
            if ev:
                per_step[f"{q.stem}/{name}/events"] = np.array(
                    [(e[0], e[2], e[3], e[4]) for e in ev], float
                )
            print(
                f"{q.stem:24s} {name:14s} ATE {100 * s['ate']:6.2f} cm (lagged "
                f"{100 * s['ate_lagged']:6.2f}) final {100 * s['final_m']:6.2f} max "
                f"{100 * s['max_m']:6.2f} yaw {s['yaw_rms_deg']:5.2f} deg"
                + (
                    f" fail {s['fail']} {s['fail_reasons']} weak {s['weak']} frames "
                    f"{s['frames']} rev {s['revisits']} track {s['track_ms_mean']:.1f} ms"
                    f" step {s['step_ms_mean']:.1f} ms (p95 {s['step_ms_p95']:.1f})"
                    if src == "slam"
                    else ""
                ),
                flush=True,
            )
            if a.jsonl:
                with open(a.jsonl, "a") as f:
                    f.write(json.dumps({**s, "changes": changes}) + "\n")
    if a.per_step:
        np.savez_compressed(a.per_step, **per_step)
    # summary: mean over sequences per (sensing, variant)
    print("\nmean over sequences:")
    groups: dict[tuple[str, str], list[dict]] = {}
    for s in rows:
        groups.setdefault((s["seq"].split("_")[0], s["variant"]), []).append(s)
    for (sens, name), g in groups.items():
        tm = [x["track_ms_mean"] for x in g if x["track_ms_mean"] is not None]
        sm = [x["step_ms_mean"] for x in g if x["step_ms_mean"] is not None]
        print(
            f"{sens:10s} {name:14s} n={len(g)} ATE {100 * np.mean([x['ate'] for x in g]):6.2f} cm"
            f" (lagged {100 * np.mean([x['ate_lagged'] for x in g]):6.2f})"
            + (f" track {np.mean(tm):.1f} ms step {np.mean(sm):.1f} ms" if tm else "")
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
