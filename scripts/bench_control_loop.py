"""Control-loop timing of the navigation agents in the closed loop (is ``simn`` real-time at 10 Hz?).

For each agent config, runs episodes of an episode set in one process and times every
``agent.act(obs)`` call: the whole control step (SLAM tracking + mapping + local frames +
topological map + collision model + planning + control). The env's own step (physics + RGB-D
render) is timed separately. Reported per config: mean / median / p95 / p99 / max ms per control
step, the same on the steps that open a local frame and on the rest (what makes the p95), the
share of steps over the control period (100 ms at 10 Hz), the breakdown (tracking,
mapping, planning on the steps that plan) and the ratio of the mean to the control period and to
the odometry-only ablation measured in the same run. ``--sensing`` (default ``ideal``; the
current timings, docs/tracking.md "In the loop: act() at 320x240", were measured with
``--sensing realistic``) picks the env's sensing condition; ``--odom-noise`` overrides its
odometry drift. ``--variant NAME JSON`` adds an agent config (changes to the default, as
``simn-sim batch --agent-config``). ``--episode-ids`` picks episodes by id, ``--max-steps`` cuts
each episode short, ``--stages`` adds the per-stage self times of the SLAM front-end (as
``scripts/bench_learned_tracking.py``: perception, k-NN and network of tracking, LM, map
insertion, k-NN and optimiser of training, the rest of ``SimnSlam.process``), ms per step, and
the rest of ``act()`` (collision model, topological map, planning, control). Each config's
timed run follows ``--warmup-steps`` (default 30) untimed steps of a fresh agent of that config
in the same process, so one-time costs (imports, first calls) do not land on whichever config
runs first; ``--warmup-steps 0`` times a cold start (the protocol before 2026-12-07).

    MUJOCO_GL=egl .venv/bin/python scripts/bench_control_loop.py --episodes 4 --out F.json
    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_control_loop.py \\
        --episode-file envs/episodes/office_nav_v2.json --episode-ids nav2-L2-005 \\
        --sensing realistic --stages --configs "simn (learned map, default)" "simn, point store (ablation)"
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import simn_sim  # noqa: E402,F401
from simn_sim.agents import make_agent  # noqa: E402
from simn_sim.config import ConfigError, json_object  # noqa: E402
from simn_sim.env.episodes import EpisodeSet  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary  # noqa: E402
from simn_sim.paths import envs_dir  # noqa: E402
from simn_sim.slam.config import SlamConfig  # noqa: E402


def _learned_before_cuts() -> dict:
    """``SlamConfig.for_agent`` as it was before its cost cuts (docs/tracking.md): the
    k-NN searched at every LM evaluation, 2500 random registration points, 3 rejected LM steps
    before a minimum is declared."""
    d = SlamConfig.for_agent(
        implicit_reuse_neighbors=0.0, max_track_points=2500, track_point_selection="random"
    ).to_dict()
    d["track_registration"]["max_rejects"] = 3
    return d


def _learned_exact() -> dict:
    """Tracking on the learned map as before its fast path: the network at every LM
    iteration, the agent's training schedule in the step (scripts/bench_learned_tracking.py)."""
    d = _learned_before_cuts()
    d.update(
        implicit_cache_voxel=0.0,
        train_async=False,
        open_train_iters=60,
        train_iters=15,
        train_every=5,
    )
    d["mapper"]["training"]["max_pending"] = 20_000
    return d


CONFIGS = {
    # the default agent: the paper's learned map per local frame, tracked against
    # (SlamConfig.for_agent: training on a worker thread in chunks, docs/tracking.md)
    "simn (learned map, default)": {},
    # the default with the training chunk joined after the next frame's tracking (it tracks
    # against the map before that chunk): the chunk overlaps perception and tracking too
    "simn (learned map, training latency 1)": {"slam": {"train_latency": 1}},
    # the EWC consolidation's diagonal Fisher by per-sample outer products (not torch.func)
    "simn (learned map, outer-product Fisher)": {
        "slam": {"mapper": {"training": {"fisher_method": "outer"}}}
    },
    # the point-store ablation (agent simn_points): no learning, nearest-point-plane SDF
    "simn, point store (ablation)": {"slam": {"preset": "points_agent"}},
    "simn, odometry pose (ablation)": {"pose_source": "odometry"},
    # the learned map trained in the loop but tracking on the point store
    "simn, point tracking + learned map": {
        "slam": {"preset": "points_agent", "map_kind": "implicit"}
    },
    "simn, learned tracking (exact)": {"slam": _learned_exact()},
    "simn, learned tracking (before cuts)": {"slam": _learned_before_cuts()},
}


def _stats(x: list[float]) -> dict[str, float]:
    a = np.asarray(x, float)
    if a.size == 0:
        return {"n": 0}
    return {
        "n": int(a.size),
        "mean": float(a.mean()),
        "median": float(np.median(a)),
        "p95": float(np.percentile(a, 95)),
        "p99": float(np.percentile(a, 99)),
        "max": float(a.max()),
    }


def _warm_up(env, agent_cfg: dict, ep, steps: int) -> None:
    """Untimed: ``steps`` control steps of a fresh agent on ``ep``, so the process's one-time
    costs (imports, first calls, allocator growth) land before the timed run of every config
    and not on whichever config runs first (about 0.9 s of act() on 2026-12-07)."""
    obs, info = env.reset(seed=ep.seed, options={"episode": ep.to_dict()})
    agent = make_agent("simn", env.unwrapped, agent_cfg)
    agent.reset(obs, info)
    for _ in range(steps):
        obs, _, term, trunc, _ = env.step(agent.act(obs))
        if term or trunc:
            break
    slam = getattr(getattr(agent, "world", None), "slam", None)
    if slam is not None and slam.trainer is not None:
        slam.close()


def run(
    agent_cfg: dict,
    episodes: list,
    env_cfg: dict,
    period_ms: float,
    max_steps: int = 0,
    timer=None,
    name: str = "",
    warmup_steps: int = 0,
) -> dict:
    env = gym.make("SimnOffice-v0", config=env_cfg)
    if warmup_steps > 0:
        if timer is not None:
            timer.config = f"{name} (warm-up)"  # its stage times are kept apart
        _warm_up(env, agent_cfg, episodes[0], warmup_steps)
    act, env_ms, track, mapping, plan = [], [], [], [], []
    outcomes, train_wait, n_steps = [], [], 0
    jobs = {"jobs": 0, "run_ms": 0.0, "beside_ms": 0.0, "wait_ms": 0.0, "between_ms": 0.0}
    opened: list[bool] = []  # the step opened a local frame (closing one, revisit check)
    if timer is not None:
        timer.config = name
    for ep in episodes:
        obs, info = env.reset(seed=ep.seed, options={"episode": ep.to_dict()})
        agent = make_agent("simn", env.unwrapped, agent_cfg)
        agent.reset(obs, info)
        steps = 0
        while True:
            t = time.perf_counter()
            a = agent.act(obs)
            act.append((time.perf_counter() - t) * 1e3)
            last = getattr(getattr(getattr(agent, "world", None), "slam", None), "last", None)
            opened.append(bool(last is not None and last.new_local_frame))
            d = agent.debug()
            for key, dst in (("track_ms", track), ("map_ms", mapping), ("plan_ms", plan)):
                if d.get(key) is not None:
                    dst.append(float(d[key]))
            t = time.perf_counter()
            obs, _, term, trunc, info = env.step(a)
            env_ms.append((time.perf_counter() - t) * 1e3)
            steps += 1
            if term or trunc or (max_steps > 0 and steps >= max_steps):
                outcomes.append(info["episode"]["termination"] if term or trunc else "cut")
                break
        n_steps += steps
        slam = getattr(getattr(agent, "world", None), "slam", None)
        if slam is not None and slam.trainer is not None:  # training on the worker thread
            train_wait.append(slam.trainer.wait_ms / max(slam.n_frames, 1))
            slam.close()
            for k in jobs:
                jobs[k] += getattr(slam.trainer, k)
    env.close()
    a = np.asarray(act)
    stages = None
    if timer is not None:
        stages = {k: 1e3 * timer.total[name].get(k, 0.0) / max(n_steps, 1) for k in timer.names}
        slam_ms = sum(v for k, v in stages.items() if k not in timer.threaded)
        stages["rest of act (collision model, topo map, planning, control)"] = (
            float(a.mean()) - slam_ms
        )
    op = np.asarray(opened, bool)
    slow = a >= np.percentile(a, 95) if a.size else op
    return {
        "stages_ms_per_step": stages,
        "act_ms": _stats(act),
        # the p95's make-up: steps that open a local frame (the old one's EWC consolidation
        # and replay hand-over, the new one's first training and revisit check) and the rest
        "act_ms_frame_opening": _stats(a[op]),
        "act_ms_other_steps": _stats(a[~op]),
        "frame_opening_share_of_slowest_5pct": float(op[slow].mean()) if slow.any() else None,
        "over_period_share": float(np.mean(a > period_ms)),
        "track_ms": _stats(track),
        "map_ms": _stats(mapping),
        "plan_ms": _stats(plan),
        "env_step_ms": _stats(env_ms),
        # train_async: mean ms per step the next step waited for the worker's training
        "train_wait_ms_per_step": float(np.mean(train_wait)) if train_wait else None,
        # per training job on the worker: its wall time, the main thread's work beside it
        # (from its start to the next step's join), the join's wait, and the main thread's
        # work from the join to the next job's start (the worker idle)
        "train_job_ms": (
            {k: jobs[k] / jobs["jobs"] for k in ("run_ms", "beside_ms", "wait_ms", "between_ms")}
            if jobs["jobs"]
            else None
        ),
        "terminations": outcomes,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episode-file", type=Path, default=envs_dir() / "episodes/office_nav_v1.json")
    ap.add_argument("--episodes", type=int, default=4, help="first N episodes, one per layout")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--sensing", choices=["ideal", "realistic"], default="ideal")
    ap.add_argument("--odom-noise", type=float, default=None, help="override the odometry drift")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--episode-ids", nargs="+", default=None, help="these episodes (by id)")
    ap.add_argument("--max-steps", type=int, default=0, help="cut each episode after N steps")
    ap.add_argument("--stages", action="store_true", help="per-stage self times of the front-end")
    ap.add_argument(
        "--warmup-steps",
        type=int,
        default=30,
        help="untimed steps of each config (a fresh agent) before its timed run; 0: none",
    )
    ap.add_argument(
        "--variant",
        nargs=2,
        action="append",
        default=[],
        metavar=("NAME", "JSON"),
        help="also run the agent config JSON (changes to the default, as --agent-config) as NAME",
    )
    a = ap.parse_args()
    configs = {name: CONFIGS[name] for name in a.configs}
    for name, text in a.variant:
        if name in configs:
            ap.error(f"--variant {name}: the name is taken")
        try:
            configs[name] = json_object(text, f"--variant {name}")
        except ConfigError as e:
            ap.error(str(e))
    import torch

    torch.set_num_threads(1)  # as the agent's SLAM sets it (SlamConfig.torch_threads)
    timer = None
    if a.stages:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from bench_learned_tracking import STAGES, StageTimer

        from simn_sim.slam.trainer import TrainWorker

        timer = StageTimer()
        timer.install()
        # the next step waiting for the worker's training (train_async), inside process()
        timer.wrap(TrainWorker, "join", "training wait")
        timer.names = (*STAGES, "training wait")
        # stages on the training worker thread (train_async): not inside act()
        timer.threaded = ("kNN, training", "training (optimiser)")
    eps = EpisodeSet.load(a.episode_file).episodes
    if a.episode_ids:
        by_id = {e.episode_id: e for e in eps}
        eps = [by_id[i] for i in a.episode_ids]
    by_layout: dict = {}
    for e in eps:
        by_layout.setdefault(e.layout_seed, []).append(e)
    picked = []
    while len(picked) < a.episodes and any(by_layout.values()):
        for k in list(by_layout):
            if by_layout[k] and len(picked) < a.episodes:
                picked.append(by_layout[k].pop(0))
    env_cfg = {"width": a.width, "height": a.height, "sensing": a.sensing}
    if a.odom_noise is not None:
        env_cfg.update(odom_noise_trans=a.odom_noise, odom_noise_rot=a.odom_noise)
    period = 1000.0 / 10.0
    res = {
        "machine": machine_summary(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_avg_start": os.getloadavg(),
        "env": env_cfg,
        "episodes": [e.episode_id for e in picked],
        "warmup_steps": a.warmup_steps,
        "configs": {},
    }
    for name, cfg in configs.items():
        res["configs"][name] = run(
            cfg, picked, env_cfg, period, a.max_steps, timer, name, a.warmup_steps
        )
        r = res["configs"][name]
        s = r["act_ms"]
        print(
            f"{name}: act ms mean {s['mean']:.1f} median {s['median']:.1f} p95 {s['p95']:.1f} "
            f"p99 {s['p99']:.1f} max {s['max']:.1f}; over {period:.0f} ms: "
            f"{100 * r['over_period_share']:.2f} %; env step mean {r['env_step_ms']['mean']:.1f} ms",
            flush=True,
        )
        fo, ot = r["act_ms_frame_opening"], r["act_ms_other_steps"]
        if fo["n"]:
            print(
                f"  steps opening a local frame: {fo['n']}, act ms mean {fo['mean']:.1f}; "
                f"other steps: mean {ot['mean']:.1f} p95 {ot['p95']:.1f}; share of the "
                f"slowest 5 %: {r['frame_opening_share_of_slowest_5pct']:.2f}",
                flush=True,
            )
        tj = r["train_job_ms"]
        if tj:
            print(
                f"  training job on the worker: {tj['run_ms']:.1f} ms; main thread's work "
                f"beside it {tj['beside_ms']:.1f} ms; join waited {tj['wait_ms']:.1f} ms; main "
                f"thread's work from the join to the next start {tj['between_ms']:.1f} ms",
                flush=True,
            )
        if r["stages_ms_per_step"]:
            tw = r["train_wait_ms_per_step"]
            print(
                "  stages ms/step: "
                + ", ".join(f"{k} {v:.1f}" for k, v in r["stages_ms_per_step"].items())
                + (f"; training wait {tw:.1f}" if tw is not None else ""),
                flush=True,
            )
    res["load_avg_end"] = os.getloadavg()
    cf = res["configs"]
    base = cf.get("simn, odometry pose (ablation)", {}).get("act_ms", {}).get("mean")
    for name, r in cf.items():
        m = r["act_ms"]["mean"]
        r["ratio_mean_to_period"] = m / period
        r["ratio_mean_to_odometry_ablation"] = m / base if base else None
        print(f"{name}: mean control step / {period:.0f} ms period {m / period:.2f}", end="")
        print(f", / odometry ablation {m / base:.1f}x" if base else "")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
