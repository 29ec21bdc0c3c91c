"""The bump detector (:class:`simn_sim.agents.recovery.BumpDetector`) against the simulator's
contacts, under the env's realistic actuation noise and wheel-odometry drift.

The detector sees only what the agent sees: the commanded forward speed and the wheel odometry.
Two kinds of drive in the reference office's corridor, at 10 Hz:

- **free driving**: a pure-pursuit drive between random free waypoints along the corridor with
  random speed levels, stops and turns in place, ``--free-episodes`` x ``--free-steps`` steps,
  no contact (a step whose hull touched anything is dropped with its window);
- **contacts**: straight drives into the corridor's walls at incidence angles 0 (head-on) to 75
  deg, at 0.3-0.8 m/s, 0.8 m from the wall, 80 steps each;
- **glancing contacts**: drives from 0.5 m off the wall at 55-75 deg incidence that turn away
  from it (0.5 or 1.0 rad/s) as they reach it, at 0.45 or 0.7 m/s (a turn past an obstacle),
  80 steps each.

For each detector (``min_progress``, and ``rel_progress`` with ``--rel``) it reports the false
bumps per 1000 forward-commanded free steps and how many contact drives of each kind were
detected, and within how many steps of the first contact. Every
drive is recorded once and replayed through the detector variants, so they see the same steps.

    MUJOCO_GL=egl python scripts/bench_bumps.py --out runs/bumps
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np

import simn_sim  # noqa: F401  (registers the env ids)
from simn_sim.agents.recovery import BumpDetector
from simn_sim.env.episodes import EpisodeSpec
from simn_sim.geometry.se3 import inv_T, planar_T


def corridor(env) -> tuple[float, float]:
    """(y_mid, y_north) of the reference office's corridor: its centre line and the line of the
    doors in its north wall."""
    lay = env.unwrapped.layout
    ys = sorted({d.center[1] for d in lay.doors if d.axis == "x"})
    return 0.5 * (ys[0] + ys[-1]), ys[-1]


def drive(env, spec: EpisodeSpec, policy, steps: int) -> list[dict]:
    """Run ``policy(pose_true, k) -> [v, w]``; per step the command, the odometry increment
    (base frame) and whether the hull touched anything."""
    obs, info = env.reset(seed=spec.seed, options={"episode": spec.to_dict()})
    o = np.asarray(obs["odometry"], float)
    T_prev = planar_T(*o)
    rows = []
    for k in range(steps):
        T = info["T_world_base"]
        pose = np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])
        a = np.asarray(policy(pose, k), np.float32)
        obs, _, term, trunc, info = env.step(a)
        o = np.asarray(obs["odometry"], float)
        T_o = planar_T(*o)
        d = inv_T(T_prev) @ T_o
        T_prev = T_o
        rows.append(
            {
                "v": float(a[0]),
                "w": float(a[1]),
                "dx": float(d[0, 3]),
                "dy": float(d[1, 3]),
                "dyaw": float(math.atan2(d[1, 0], d[0, 0])),
                "contact": bool(info["collided"]),
            }
        )
        if term or trunc:
            break
    return rows


def free_policy(rng: np.random.Generator, y_mid: float, x_lo: float, x_hi: float):
    """Pure pursuit between random waypoints near the corridor's centre line, at random speed
    levels held 5-30 steps, with occasional stops; turns in place beyond 30 deg of bearing."""
    state = {"wp": None, "v": 0.5, "hold": 0, "stop": 0}

    def pol(pose, k):
        if state["wp"] is None or np.hypot(*(state["wp"] - pose[:2])) < 0.3:
            state["wp"] = np.array([rng.uniform(x_lo, x_hi), y_mid + rng.uniform(-0.35, 0.35)])
        if state["hold"] <= 0:
            state["v"] = float(rng.choice([0.2, 0.35, 0.5, 0.65, 0.8]))
            state["hold"] = int(rng.integers(5, 30))
            state["stop"] = int(rng.integers(2, 8)) if rng.random() < 0.2 else 0
        state["hold"] -= 1
        if state["stop"] > 0:
            state["stop"] -= 1
            return [0.0, 0.0]
        d = state["wp"] - pose[:2]
        err = (math.atan2(d[1], d[0]) - pose[2] + math.pi) % (2 * math.pi) - math.pi
        if abs(err) > math.radians(30):
            return [0.0, math.copysign(1.0, err)]
        return [state["v"], float(np.clip(1.5 * err, -1.0, 1.0))]

    return pol


def glancing_policy(y_wall: float, v: float, w_away: float):
    """Straight at ``v`` until the base centre is within 0.35 m of the wall line ``y_wall``
    (its hull radius and a little), then turning away from it (clockwise) at ``w_away`` while
    still driving, until it heads away from the wall."""

    def pol(pose, k):
        near = y_wall - pose[1] < 0.35
        heading_in = math.sin(pose[2]) > 0.0
        return [v, -w_away if near and heading_in else 0.0]

    return pol


def replay(
    rows: list[dict], min_progress: float, dt: float, rel: float = 0.0, yaw: float = 0.0
) -> list[int]:
    """The steps at which a detector with ``min_progress`` (``rel_progress`` ``rel``,
    ``yaw_tol`` ``yaw``) fires."""
    det = BumpDetector(dt, min_progress=min_progress, rel_progress=rel, yaw_tol=yaw)
    fired = []
    for k, r in enumerate(rows):
        T = planar_T(r["dx"], r["dy"], r["dyaw"])
        if det.update(r["v"], T, r["w"]):  # the command and the odometry over the step it drove
            fired.append(k)
    return fired


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--free-episodes", type=int, default=12)
    ap.add_argument("--free-steps", type=int, default=600)
    ap.add_argument("--thresholds", type=float, nargs="+", default=[0.5, 0.4, 0.3, 0.25, 0.2])
    ap.add_argument(
        "--rel", type=float, nargs="+", default=[0.0], help="rel_progress values (0: off)"
    )
    ap.add_argument("--yaw", type=float, nargs="+", default=[0.0], help="yaw_tol values (0: off)")
    args = ap.parse_args()
    env = gym.make("SimnOffice-v0", config={"width": 64, "height": 48})  # realistic sensing
    y_mid, y_n = corridor(env)
    dt = float(env.unwrapped.dt)
    x_lo, x_hi = 2.0, env.unwrapped.layout.size[0] - 2.0
    free: list[list[dict]] = []
    for s in range(args.free_episodes):
        rng = np.random.default_rng(1000 + s)
        spec = EpisodeSpec(f"free{s}", None, (x_lo + 1.0, y_mid, 0.0), (x_hi, y_mid), seed=500 + s)
        free.append(drive(env, spec, free_policy(rng, y_mid, x_lo, x_hi), args.free_steps))
    hits: list[tuple[dict, list[dict]]] = []
    # drives into the north corridor wall, away from its doors
    doors_x = [d.center[0] for d in env.unwrapped.layout.doors if d.axis == "x"]
    xs = [x for x in np.arange(3.0, x_hi, 1.7) if min(abs(x - dx) for dx in doors_x) > 1.5][:6]
    n = 0

    def far_goal(x: float) -> tuple[float, float]:  # the drive never ends in success
        return (x_lo if x > 12.0 else x_hi, y_mid)

    for inc in (0.0, 30.0, 50.0, 65.0, 75.0):
        for v in (0.3, 0.55, 0.8):
            x = xs[n % len(xs)]
            n += 1
            yaw = math.pi / 2 - math.radians(inc)
            start = (x, y_n - 0.8, yaw)
            spec = EpisodeSpec(f"hit{n}", None, start, far_goal(x), seed=700 + n)
            rows = drive(env, spec, lambda pose, k, v=v: [v, 0.0], 80)
            if any(r["contact"] for r in rows):
                hits.append(({"kind": "wall", "incidence_deg": inc, "v": v, "x": x}, rows))
    for inc in (55.0, 65.0, 75.0):
        for v in (0.45, 0.7):
            for w_away in (0.5, 1.0):
                x = xs[n % len(xs)]
                n += 1
                start = (x, y_n - 0.5, math.pi / 2 - math.radians(inc))
                spec = EpisodeSpec(f"glance{n}", None, start, far_goal(x), seed=700 + n)
                rows = drive(env, spec, glancing_policy(y_n, v, w_away), 80)
                if any(r["contact"] for r in rows):
                    meta = {"kind": "glancing", "incidence_deg": inc, "v": v, "w": w_away, "x": x}
                    hits.append((meta, rows))
    env.close()

    free_ratio = [
        r["dx"] / (r["v"] * dt) for rows in free for r in rows if r["v"] > 0.1 and not r["contact"]
    ]
    fwd = len(free_ratio)  # forward-commanded free steps
    report = {"free_forward_steps": fwd, "contact_drives": len(hits), "thresholds": {}}
    report["free_progress_ratio_quantiles"] = {
        str(q): float(np.quantile(free_ratio, q)) if free_ratio else None
        for q in (0.0, 0.001, 0.01, 0.05, 0.5)
    }
    # the turning test's statistic: the yaw-rate error beyond the actuation noise's gain band
    yaw_excess = [
        abs(r["dyaw"] / dt - r["w"]) - 0.5 * abs(r["w"])
        for rows in free
        for r in rows
        if r["v"] > 0.1 and not r["contact"]
    ]
    report["free_yaw_excess_quantiles"] = {
        str(q): float(np.quantile(yaw_excess, q)) if yaw_excess else None
        for q in (0.5, 0.95, 0.99, 0.999, 1.0)
    }
    contact_ratio = [r["dx"] / (r["v"] * dt) for _, rows in hits for r in rows if r["contact"]]
    report["contact_progress_ratio_quantiles"] = {
        str(q): float(np.quantile(contact_ratio, q)) for q in (0.5, 0.9, 0.99, 1.0)
    }
    report["contact_drives_by_kind"] = {
        k: sum(m["kind"] == k for m, _ in hits) for k in ("wall", "glancing")
    }
    for t, rel, yaw in itertools.product(args.thresholds, args.rel, args.yaw):
        false = 0
        for rows in free:
            for k in replay(rows, t, dt, rel, yaw):
                if not any(r["contact"] for r in rows[max(0, k - 4) : k + 1]):
                    false += 1
        entry: dict = {
            "false_bumps": false,
            "false_per_1000_forward_steps": 1000.0 * false / max(fwd, 1),
        }
        for kind in ("wall", "glancing"):
            delays, missed = [], []
            for meta, rows in hits:
                if meta["kind"] != kind:
                    continue
                first = next(k for k, r in enumerate(rows) if r["contact"])
                f = [k for k in replay(rows, t, dt, rel, yaw) if k >= first]
                if f:
                    delays.append(f[0] - first)
                else:
                    missed.append(meta)
            entry[kind] = {
                "detected": len(delays),
                "delay_steps_max": max(delays) if delays else None,
                "delay_steps_median": float(np.median(delays)) if delays else None,
                "missed": missed,
            }
        key = str(t) + (f", rel {rel}" if rel else "") + (f", yaw {yaw}" if yaw else "")
        report["thresholds"][key] = entry
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bumps.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
