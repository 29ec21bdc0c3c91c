"""Env throughput: SimnOffice-v0 steps/s against bare MuJoCo on the same scene, in the same run.

Measures, at each resolution:
  - env: ``env.step`` with rendering (RGB-D, geodesic, metrics) under ideal sensing, with the
    depth model ``--noise`` (the figures in docs/env.md are ``--noise none``);
  - bare_1pass: the same physics steps + one-pass RGB-D render with the env's own camera class
    (the floor for any env built on this scene); the env's overhead ratio is env / bare_1pass;
  - bare_renderer: physics + ``mujoco.Renderer`` colour pass + depth pass (what a plain MuJoCo
    script does);
  - physics alone (frame_skip physics steps per control step).
Usage: python scripts/bench_env.py [--steps 200] [--noise none|d435i]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

import gymnasium as gym
import mujoco
import numpy as np

import simn_sim  # noqa: F401
from simn_sim.env.scene import ROBOT_GROUP
from simn_sim.env.sensors import OffscreenCamera


def _rate(fn, n: int) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return n / (time.perf_counter() - t)


def bench(width: int, height: int, steps: int, noise: str) -> dict:
    env = gym.make(
        "SimnOffice-v0",
        config={
            "width": width,
            "height": height,
            "sensing": "ideal",
            "depth_noise": {"model": noise},
            "max_episode_steps": 10**6,
        },
    )
    u = env.unwrapped
    env.reset(seed=0)
    actions = [np.array([0.3, 0.4 * math.sin(i / 7)], np.float32) for i in range(steps + 1)]
    it = iter(actions)
    env_rate = _rate(lambda: env.step(next(it)), min(steps, len(actions) - 1))

    m, d = u.model, mujoco.MjData(u.model)
    d.qpos[:] = u.data.qpos
    cam = OffscreenCamera(m, u._scene.camera_id, width, height, (ROBOT_GROUP,))
    fs = u.frame_skip

    def physics():
        yaw = d.qpos[2]
        d.ctrl[:3] = [0.3 * math.cos(yaw), 0.3 * math.sin(yaw), 0.2]
        for _ in range(fs):
            mujoco.mj_step(m, d)

    def bare_1pass():
        physics()
        cam.render_rgbd(d)

    r = mujoco.Renderer(m, height, width)
    opt = mujoco.MjvOption()
    opt.geomgroup[ROBOT_GROUP] = 0

    def bare_renderer():
        physics()
        r.update_scene(d, camera=u._scene.camera_id, scene_option=opt)
        r.render()
        r.enable_depth_rendering()
        r.render()
        r.disable_depth_rendering()

    # interleaved rounds, so that load changes on a shared machine hit both sides alike;
    # ratios are medians over rounds
    rounds = 5
    n = max(10, steps // rounds)
    env_r, bare_r, rend_r = [env_rate], [], []
    for _ in range(rounds):
        env_r.append(_rate(lambda: env.step(actions[0]), n))
        bare_r.append(_rate(bare_1pass, n))
        rend_r.append(_rate(bare_renderer, n))
    env_r = env_r[1:]
    out = {
        "resolution": f"{width}x{height}",
        "env_steps_per_s": float(np.median(env_r)),
        "bare_1pass_steps_per_s": float(np.median(bare_r)),
        "bare_renderer_steps_per_s": float(np.median(rend_r)),
        "physics_only_steps_per_s": _rate(physics, steps * 5),
        "env_overhead_vs_1pass": float(np.median(np.array(bare_r) / np.array(env_r))),
        "env_speedup_vs_renderer": float(np.median(np.array(env_r) / np.array(rend_r))),
    }
    r.close()
    cam.close()
    env.close()
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--noise", default="none", choices=["none", "d435i"])
    a = ap.parse_args()
    import os

    print(
        f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus, MUJOCO_GL={os.environ.get('MUJOCO_GL')}, mujoco {mujoco.__version__}"
    )
    rows = [bench(w, h, a.steps, a.noise) for w, h in ((640, 480), (320, 240))]
    for row in rows:
        print(json.dumps({k: (round(v, 2) if isinstance(v, float) else v) for k, v in row.items()}))
