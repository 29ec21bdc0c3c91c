#!/usr/bin/env python
"""Benchmark of the spatial-implicit mapper against the paper's runtime table (RTX 4090).

Measures, on the chosen device:
  * ray sampling, ms per million samples (paper: 1.2 ms, GPU);
  * one training update at 320x240 input: one optimiser iteration at the default batch, the
    per-frame integration (perception + point insertion + ray sampling), and one full adaptive
    training call (paper: 200.1 ms for a 640x480 frame, GPU);
  * SDF queries per second for 100k points (SDF only, and SDF + gradient);
  * peak memory after integrating N frames (default 500) with training every 5th frame.

    .venv/bin/python scripts/bench_mapping.py [--device cuda] [--frames 500] [--out bench.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import time

import numpy as np
import torch

from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import ImplicitMap, MapperConfig, SamplingConfig, rgbd_to_points, sample_rays
from simn_sim.mapping.synthetic import AnalyticScene, Box, Sphere, look_at


def office_scene() -> AnalyticScene:
    """An 8 x 6 x 3 m room with boxes (desks, shelves) and a sphere."""
    boxes = (
        Box((2.5, 1.8, 0.375), (0.8, 0.4, 0.375)),
        Box((-2.5, 1.8, 0.375), (0.8, 0.4, 0.375)),
        Box((2.5, -1.8, 0.9), (0.3, 0.8, 0.9)),
        Box((-2.8, -2.0, 0.5), (0.5, 0.5, 0.5)),
        Box((0.0, 2.5, 1.0), (1.0, 0.25, 1.0)),
    )
    return AnalyticScene(
        Box((0.0, 0.0, 1.5), (4.0, 3.0, 1.5)), boxes, (Sphere((0.5, -1.0, 0.4), 0.4),)
    )


def trajectory(n: int) -> list[np.ndarray]:
    """A camera at 1.2 m driving an ellipse, looking ahead and slightly inwards."""
    out = []
    for i in range(n):
        a = 2 * np.pi * i / 250.0
        eye = np.array([1.6 * np.cos(a), 1.0 * np.sin(a), 1.2])
        fwd = np.array([-np.sin(a), np.cos(a), 0.0]) + 0.4 * np.array([np.cos(a), np.sin(a), 0.0])
        out.append(look_at(eye, eye + 2.0 * fwd + [0, 0, -0.5]))
    return out


def sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def timeit(fn, dev, repeat: int) -> list[float]:
    fn()  # warm-up
    out = []
    for _ in range(repeat):
        sync(dev)
        t0 = time.perf_counter()
        fn()
        sync(dev)
        out.append(time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=500, help="frames for the memory run")
    ap.add_argument(
        "--memory-train-iters",
        type=int,
        default=0,
        help="iteration cap per training call in the memory run (0: config default)",
    )
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch default)")
    ap.add_argument("--out", default=None, help="write the figures as JSON here")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    res: dict = {
        "device": str(dev),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "cpu": platform.processor() or platform.machine(),
    }
    if dev.type == "cuda":
        res["gpu"] = torch.cuda.get_device_name(dev)
    g = torch.Generator(device=dev).manual_seed(0)

    # --- ray sampling: 1M output samples (default 3 front + 2 behind + 2 surface per point)
    scfg = SamplingConfig()
    per = scfg.n_front + scfg.n_behind + scfg.n_surface
    n_pts = 1_000_000 // per
    pts = torch.rand((n_pts, 3), generator=g, device=dev) * 4 + torch.tensor(
        [0, 0, 1.0], device=dev
    )
    origin = torch.zeros(3, device=dev)
    t = timeit(lambda: sample_rays(pts, origin, scfg, g), dev, 10)
    res["sampling_ms_per_million_samples"] = 1e3 * float(np.median(t)) * 1e6 / (n_pts * per)
    res["sampling_ms_per_million_surface_points"] = 1e3 * float(np.median(t)) * 1e6 / n_pts

    # --- training update at 320 x 240
    scene = office_scene()
    intr = Intrinsics.from_fovy(320, 240)
    poses = trajectory(args.frames)
    depth0 = scene.render_depth(intr, poses[0])
    cfg = MapperConfig(device=str(dev))
    m = ImplicitMap(cfg)
    pc = rgbd_to_points(depth0, intr, cfg=cfg.perception)
    res["frame_points_320x240"] = len(pc)
    k = cfg.training.train_every
    t_int, calls = [], []
    for c in range(4):  # training calls on frames 5c .. 5c+4; the first one warms up
        for T in poses[c * k : (c + 1) * k]:
            depth = scene.render_depth(intr, T)
            sync(dev)
            t0 = time.perf_counter()
            m.integrate_rgbd(depth, intr, T, train=False)
            sync(dev)
            t_int.append(time.perf_counter() - t0)
        calls.append(m.train())
    res["integrate_frame_ms"] = 1e3 * float(np.median(t_int[k:]))
    res["train_call_ms"] = 1e3 * float(np.median([c.seconds for c in calls[1:]]))
    res["train_call_iterations"] = [c.iterations for c in calls[1:]]
    res["train_call_samples"] = calls[-1].n_samples
    # one optimiser iteration: (call of 4n iterations - call of n) / 3n, same sample count
    m.cfg = m.cfg.replace(training={**m.cfg.training.to_dict(), "loss_threshold": 0.0})
    n = m.cfg.training.min_iters
    m.integrate_rgbd(depth0, intr, poses[0], train=False)
    a = m.train(max_iters=n)
    m.integrate_rgbd(depth0, intr, poses[0], train=False)
    b = m.train(max_iters=4 * n)
    res["train_iteration_ms"] = 1e3 * (b.seconds - a.seconds) / (b.iterations - a.iterations)
    res["train_setup_ms"] = 1e3 * a.seconds - n * res["train_iteration_ms"]
    res["train_batch_size"] = m.cfg.training.batch_size
    res["amortised_training_ms_per_frame"] = res["train_call_ms"] / m.cfg.training.train_every

    # --- SDF queries, 100k points near surfaces
    fp = m.feature_points().positions
    rng = np.random.default_rng(0)
    q = torch.from_numpy(
        (fp[rng.integers(0, len(fp), 100_000)] + rng.normal(0, 0.05, (100_000, 3))).astype(
            np.float32
        )
    ).to(dev)
    t_q = timeit(lambda: m.sdf(q), dev, 3)
    t_g = timeit(lambda: m.sdf_and_grad(q), dev, 3)
    res["sdf_queries_per_s"] = 100_000 / float(np.median(t_q))
    res["sdf_and_grad_queries_per_s"] = 100_000 / float(np.median(t_g))
    res["query_valid_fraction"] = float(m.query(q).valid.float().mean())

    # --- memory after N frames (training every 5th frame)
    tr = MapperConfig().training.to_dict()
    if args.memory_train_iters > 0:
        tr["max_iters"] = args.memory_train_iters
        tr["min_iters"] = min(tr["min_iters"], args.memory_train_iters)
    mm = ImplicitMap(MapperConfig(device=str(dev)).replace(training=tr))
    t0 = time.perf_counter()
    for T in poses:
        mm.integrate_rgbd(scene.render_depth(intr, T), intr, T)
    res["memory_run_frames"] = len(poses)
    res["memory_run_s"] = time.perf_counter() - t0
    res["memory_run_train_iters_cap"] = tr["max_iters"]
    res["memory_run_train_calls"] = len(poses) // tr["train_every"]
    res["neural_points"] = len(mm.points)
    res["map_tensor_mb"] = mm.nbytes() / 2**20
    res["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if dev.type == "cuda":
        res["peak_cuda_mb"] = torch.cuda.max_memory_allocated(dev) / 2**20

    width = max(len(k) for k in res)
    for k, v in res.items():
        print(f"{k:<{width}}  {v:.3f}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(res, f, indent=2)


if __name__ == "__main__":
    main()
