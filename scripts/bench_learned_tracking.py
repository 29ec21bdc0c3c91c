"""Tracking on the learned map: per-stage cost of the fast path against the exact path and the
point store, frame by frame in one process (the frames of the configs interleaved, so a change
of the machine's load hits all of them alike).

Configs (all at the agent's 320x240 settings, ``SlamConfig.for_points_agent``):

* ``points``: the agent's default (surface point store, no learning);
* ``learned, exact``: the implementation before the fast path: the network at every LM
  iteration (``implicit_cache_voxel: 0``), k-NN on the single 15 cm bucket grid, the agent's
  training schedule (60 iterations when a frame opens, 15 every 5th frame) run in the step;
* ``learned, fast``: ``SlamConfig.for_agent`` (KD-tree k-NN, training in chunks of 3
  iterations per frame), here with the training run in the step (``train_async: false``) so
  that its cost is measured; in the loop it runs on a worker thread
  (``scripts/bench_control_loop.py`` measures that);
* ``learned, fast + SDF cache``: the same, LM on the SDF cache (``implicit_cache_voxel``
  0.02).

Stages are self times (a stage's time without the stages it calls), in ms per frame:
perception, kNN (tracking / training), network (decoder forward + dF/dp), SDF cache (baking is
counted as kNN + network; interpolation here), LM (linear algebra, weights), training
(optimiser steps, without its kNN), map insertion (neural points, planes, ray sampling), and the
rest of ``SimnSlam.process`` (topology, stores, labels, carving). Also per config: wall ms per
frame (mean / median / p95), ATE against the ground truth, ratios to ``points`` and to
``learned, exact``.

    MUJOCO_GL=egl .venv/bin/python scripts/bench_learned_tracking.py --frames 60 --out F.json
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

import simn_sim.mapping.mapper as mapper_mod  # noqa: E402
import simn_sim.mapping.neural_points as np_mod  # noqa: E402
import simn_sim.mapping.sdf_cache as cache_mod  # noqa: E402
import simn_sim.mapping.tracking_sdf as tsdf_mod  # noqa: E402
import simn_sim.perception.frame as perc_mod  # noqa: E402
import simn_sim.slam.track as track_mod  # noqa: E402
import simn_sim.tracking.pointsdf as psdf_mod  # noqa: E402
from simn_sim.eval.trajectory import ate_rpe  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary
from simn_sim.io.tum import read_tum  # noqa: E402
from simn_sim.slam import SimnSlam, SlamConfig  # noqa: E402
from simn_sim.slam.record import read_base, read_odometry, record_sequence  # noqa: E402

STAGES = (
    "perception",
    "kNN, tracking",
    "network, tracking",
    "SDF cache interpolation",
    "LM",
    "tracking, other",
    "point SDF",
    "map insertion + ray sampling",
    "kNN, training",
    "training (optimiser)",
    "rest of process",
)


def configs() -> dict[str, tuple[SlamConfig, dict]]:
    """name -> (config, k-NN switches of NeuralPointMap while it runs)."""
    fast = SlamConfig.for_agent(train_async=False)
    tr = fast.mapper.training.replace(max_pending=20_000)
    # as before the fast path and the registration cuts of for_agent (docs/tracking.md)
    exact = fast.replace(
        implicit_reuse_neighbors=0.0,
        max_track_points=2500,
        track_point_selection="random",
        track_registration=fast.track_registration.replace(max_rejects=3),
        implicit_cache_voxel=0.0,
        open_train_iters=60,
        train_iters=15,
        train_every=5,
        mapper=fast.mapper.replace(training=tr),
    )
    return {
        "points": (SlamConfig.for_points_agent(), {}),
        "learned, exact": (exact, {"use_trees": False, "fine_grid": False}),
        "learned, fast": (fast, {}),
        "learned, fast + SDF cache": (fast.replace(implicit_cache_voxel=0.02), {}),
    }


class StageTimer:
    """Self time per (config, stage): wrapped functions push a frame on a per-thread stack."""

    def __init__(self) -> None:
        self.total: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        self.config = ""
        self._tls = threading.local()

    def stack(self) -> list:
        if not hasattr(self._tls, "s"):
            self._tls.s = []
        return self._tls.s

    def wrap(self, owner, name: str, stage) -> None:
        f = getattr(owner, name)
        timer = self

        def w(*a, **k):
            st = timer.stack()
            key = stage(st) if callable(stage) else stage
            st.append([key, 0.0])
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                dt = time.perf_counter() - t
                _, child = st.pop()
                timer.total[timer.config][key] += dt - child
                if st:
                    st[-1][1] += dt

        w.__wrapped__ = f
        setattr(owner, name, w)

    def install(self) -> None:
        def in_training(st) -> bool:
            return any(k == "training (optimiser)" for k, _ in st)

        self.wrap(perc_mod.Perception, "__call__", "perception")
        self.wrap(
            np_mod.NeuralPointMap,
            "knn",
            lambda st: "kNN, training" if in_training(st) else "kNN, tracking",
        )
        self.wrap(mapper_mod.ImplicitMap, "query", "network, tracking")
        self.wrap(tsdf_mod.TrackingSdf, "sdf_and_grad", "network, tracking")
        self.wrap(cache_mod.SdfCache, "sdf_and_grad", "SDF cache interpolation")
        self.wrap(cache_mod.SdfCache, "prepare", "SDF cache interpolation")
        self.wrap(track_mod, "register", "LM")
        self.wrap(track_mod.Tracker, "track", "tracking, other")
        self.wrap(psdf_mod.PointCloudSDF, "sdf_and_grad", "point SDF")
        self.wrap(mapper_mod.ImplicitMap, "integrate_frame", "map insertion + ray sampling")
        self.wrap(mapper_mod, "train_chunk", "training (optimiser)")
        self.wrap(SimnSlam, "process", "rest of process")


def _stats(x) -> dict:
    a = np.asarray(x, float)
    return {
        "mean": float(a.mean()),
        "median": float(np.median(a)),
        "p95": float(np.percentile(a, 95)),
        "max": float(a.max()),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seq", type=Path, default=None, help="TUM folder (default: record one)")
    ap.add_argument("--trajectory", default="corridor", choices=["desk", "corridor", "loop"])
    ap.add_argument("--noise", default="d435i", choices=["none", "d435i"])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--root", type=Path, default=Path("/tmp/simn_bench_learned"))
    ap.add_argument("--configs", nargs="+", default=None)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    seq_dir = a.seq
    if seq_dir is None:
        seq_dir = a.root / f"{a.trajectory}_{a.noise}_320"
        if not (seq_dir / "rgb.txt").is_file():
            record_sequence(seq_dir, a.trajectory, a.noise, 320, 240, frames=a.frames)
    seq = read_tum(seq_dir)
    odo = read_odometry(seq_dir)
    base = read_base(seq_dir)
    cfgs = configs()
    names = a.configs or list(cfgs)
    timer = StageTimer()
    timer.install()
    slams = {n: SimnSlam(cfgs[n][0], seq.intrinsics, base) for n in names}
    wall: dict[str, list[float]] = {n: [] for n in names}
    gt = []
    load0 = os.getloadavg()
    n_frames = min(a.frames, len(seq))
    for k in range(n_frames):
        fr = seq[k]
        prior = None if odo is None else odo.get(round(float(fr.timestamp), 6))
        gt.append((fr.timestamp, fr.T_world_cam))
        order = names if k % 2 == 0 else names[::-1]
        for n in order:
            switches = cfgs[n][1]
            old = {s: getattr(np_mod.NeuralPointMap, s) for s in switches}
            for s, v in switches.items():
                setattr(np_mod.NeuralPointMap, s, v)
            timer.config = n
            t = time.perf_counter()
            try:
                slams[n].process(fr.timestamp, fr.rgb, fr.depth, prior)
            finally:
                for s, v in old.items():
                    setattr(np_mod.NeuralPointMap, s, v)
            wall[n].append((time.perf_counter() - t) * 1e3)
    res = {
        "sequence": str(seq_dir),
        "frames": n_frames,
        "machine": machine_summary(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "load_avg_start": load0,
        "load_avg_end": os.getloadavg(),
        "configs": {},
    }
    for n in names:
        s = slams[n]
        ate = ate_rpe(s.trajectory(), gt)["ate_rmse_m"]
        stages = {k: 1e3 * timer.total[n].get(k, 0.0) / n_frames for k in STAGES}
        res["configs"][n] = {
            "wall_ms": _stats(wall[n]),
            "stages_ms_per_frame": stages,
            "ate_cm": 100 * ate,
            "track_failures": s.n_track_failures,
            "tracking_map": s.tracking_map,
        }
        caches = list(s.tracker.caches.values())
        if caches:
            res["configs"][n]["cache_vertices_baked"] = int(sum(c.baked for c in caches))
    cf = res["configs"]
    for n in names:
        for ref in ("points", "learned, exact"):
            if ref in cf and ref != n:
                cf[n][f"mean_ratio_to_{ref}"] = (
                    cf[n]["wall_ms"]["mean"] / cf[ref]["wall_ms"]["mean"]
                )
    # table
    print(f"{seq_dir}, {n_frames} frames, load {load0[0]:.1f} -> {res['load_avg_end'][0]:.1f}")
    print("| stage (ms per frame) | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for k in STAGES:
        print(
            f"| {k} | " + " | ".join(f"{cf[n]['stages_ms_per_frame'][k]:.1f}" for n in names) + " |"
        )
    for key in ("mean", "median", "p95"):
        print(
            f"| **wall {key}** | "
            + " | ".join(f"{cf[n]['wall_ms'][key]:.1f}" for n in names)
            + " |"
        )
    print("| ATE (cm) | " + " | ".join(f"{cf[n]['ate_cm']:.2f}" for n in names) + " |")
    for ref in ("points", "learned, exact"):
        if ref in cf:
            row = [cf[n].get(f"mean_ratio_to_{ref}") for n in names]
            print(
                f"| mean / {ref} | "
                + " | ".join("-" if r is None else f"{r:.2f}" for r in row)
                + " |"
            )
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
