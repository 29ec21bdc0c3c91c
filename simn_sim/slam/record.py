"""Record TUM RGB-D sequences from the simulated office (``simn-sim record``).

Trajectories (the base is driven by velocity commands ``[v, w]``, 10 Hz):

* ``desk``: slow hand-held-like motion at the episode start: forward/back at up to 0.15 m/s
  with a slow yaw sway of up to 0.35 rad/s (net travel a few decimetres, viewpoint +-15 deg);
* ``corridor``: the exact shortest path (``env.free_space``) to the episode's goal, followed by
  the pure-pursuit follower at up to 0.5 m/s;
* ``loop``: start -> waypoint A -> waypoint B -> start -> 1.2 m along the first leg again,
  along shortest paths (A and B are free points 2.5-5 m from the start, in directions at least
  90 deg apart, chosen with ``seed``), so the sequence ends where it began, looking the same way
  (a revisit).

Besides the TUM layout (:class:`~simn_sim.io.tum.TumWriter`) the folder gets ``base.yaml``
(``T_base_cam``, so the floor is known), ``odometry.txt`` (TUM-format camera poses from the
env's wheel odometry, ``planar(odometry) @ T_base_cam`` in the start frame, with the env's
odometry noise: ``odom_noise`` = (per-metre scale std, per-radian-and-metre heading std)) and, with ``segmentation=True``, ``seg/<t>.png``
(8-bit semantic labels of the simulator: 1 floor, 2 obstacle, 4 person) listed in ``seg.txt``.

Sensing: the env runs with ``sensing: ideal`` plus the depth model ``noise`` and the odometry
drift ``odom_noise`` given explicitly, so the base executes the commands exactly (no actuation
noise) and the sequences behind the accuracy figures of docs/slam.md are recorded as before.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import yaml

from simn_sim.geometry.se3 import planar_T
from simn_sim.io.tum import TumWriter, pose_to_tum, read_groundtruth

Trajectory = Literal["desk", "corridor", "loop"]
TRAJECTORIES = ("desk", "corridor", "loop")


def _pose2d(T: np.ndarray) -> np.ndarray:
    return np.array([T[0, 3], T[1, 3], math.atan2(T[1, 0], T[0, 0])])


def _free_space(env, margin: float):
    """The env's free space with obstacles inflated by the robot radius + ``margin`` (as the
    oracle agent plans), falling back to the bare radius."""
    from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND
    from simn_sim.geometry.freespace import FreeSpace2D

    return FreeSpace2D(
        env.layout.footprints(ROBOT_Z_BAND),
        robot_radius=ROBOT_RADIUS + margin,
        bounds=env.layout.bounds,
    )


def _path(fs_list, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    for fs in fs_list:
        if fs.is_free(np.array([a, b])).all():
            p = fs.shortest_path(a, b)
            if p is not None:
                return p
    return None


def _waypoints(fs, start: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    field = fs.distance_field_to(start)
    cands = fs.sample_free(rng, 256, min_clearance=0.45)
    d = field.distance(cands)
    ok = np.isfinite(d) & (d > 2.5) & (d < 5.0)
    cands = cands[ok]
    if len(cands) < 2:
        raise RuntimeError("no loop waypoints 2.5-5 m from the start in this layout")
    a = cands[0]
    ang = np.arctan2(*(cands - start).T[::-1])
    ang_a = math.atan2(a[1] - start[1], a[0] - start[0])
    diff = np.abs((ang - ang_a + np.pi) % (2 * np.pi) - np.pi)
    far = cands[diff > np.pi / 2]
    b = far[0] if len(far) else cands[np.argmax(diff)]
    return [a, b, start.copy()]


def record_sequence(
    out: str | Path,
    trajectory: Trajectory = "desk",
    noise: Literal["none", "d435i"] = "none",
    width: int = 320,
    height: int = 240,
    frames: int | None = None,
    layout_seed: int | None = None,
    seed: int = 0,
    segmentation: bool = False,
    overwrite: bool = False,
    odom_noise: tuple[float, float] = (0.02, 0.01),
) -> dict:
    """Drive the env along ``trajectory`` and write a TUM folder at ``out``.

    frames: cap on the number of frames (default: desk 60, corridor 150, loop 600; the
    corridor and loop stop earlier when the route is done). Returns a summary dict.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    import gymnasium as gym

    import simn_sim.env  # noqa: F401 - registers the envs
    from simn_sim.planning.follower import FollowerConfig, PathFollower

    if trajectory not in TRAJECTORIES:
        raise ValueError(f"trajectory must be one of {TRAJECTORIES}, got {trajectory!r}")
    cap = frames or {"desk": 60, "corridor": 150, "loop": 600}[trajectory]
    cfg = {
        "width": width,
        "height": height,
        "sensing": "ideal",  # exact actuation; depth and odometry noise as given below
        "depth_noise": {"model": noise},
        "layout_seed": layout_seed,
        "segmentation": segmentation,
        "max_episode_steps": cap + 10,
        "odom_noise_trans": float(odom_noise[0]),
        "odom_noise_rot": float(odom_noise[1]),
    }
    env = gym.make("SimnOffice-v0", config=cfg)
    try:
        obs, info = env.reset(seed=seed)
        u = env.unwrapped
        cam = info["camera"]
        out = Path(out)
        writer = TumWriter(out, cam.intrinsics, overwrite=overwrite)
        (out / "base.yaml").write_text(
            yaml.safe_dump({"T_base_cam": np.asarray(cam.T_base_cam).tolist()}, sort_keys=False)
        )
        (out / "odometry.txt").write_text(
            "# wheel odometry: camera pose planar(x, y, yaw) @ T_base_cam (start frame)\n"
            "# timestamp tx ty tz qx qy qz qw\n"
        )
        if segmentation:
            (out / "seg").mkdir(exist_ok=True)
            (out / "seg.txt").write_text("# semantic labels (1 floor, 2 obstacle, 4 person)\n")
        start = info["T_world_base"][:2, 3].copy()
        rng = np.random.default_rng(seed)
        legs: list[np.ndarray] = []
        fss = [_free_space(u, 0.15), _free_space(u, 0.08), u.free_space]
        if trajectory == "corridor":
            legs = [np.asarray(info["episode_spec"]["goal"], float)]
        elif trajectory == "loop":
            legs = _waypoints(fss[0], start, rng)
            # finish by driving 1.2 m along the first leg again, so the end views what the
            # start viewed (a revisit the descriptors and the registration can recognise)
            first = _path(fss, start, legs[0])
            if first is not None:
                seg = np.hypot(*np.diff(first, axis=0).T)
                cum = np.concatenate([[0.0], np.cumsum(seg)])
                s_end = min(1.2, float(cum[-1]))
                i = int(np.clip(np.searchsorted(cum, s_end) - 1, 0, len(seg) - 1))
                f = (s_end - cum[i]) / max(seg[i], 1e-9)
                legs.append(first[i] + f * (first[i + 1] - first[i]))
        fcfg = FollowerConfig(v_max=0.5, lookahead=0.5, goal_tolerance=0.15)
        follower = PathFollower(fcfg)
        leg = 0
        if legs:
            path = _path(fss, start, legs[0])
            if path is None:
                raise RuntimeError("no path to the first waypoint")
            follower.set_path(path)
        dt = float(u.dt)
        n = 0
        collisions = 0
        for k in range(cap):
            t = 1.0 + k * dt
            writer.add(t, obs["rgb"], obs["depth"], info["T_world_cam"])
            x, y, yaw = (float(v) for v in obs["odometry"])
            T_odom_cam = planar_T(x, y, yaw) @ np.asarray(cam.T_base_cam, float)
            with open(out / "odometry.txt", "a") as f:
                f.write(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in pose_to_tum(T_odom_cam)) + "\n")
            if segmentation:
                name = f"{t:.6f}.png"
                cv2.imwrite(str(out / "seg" / name), info["segmentation"].astype(np.uint8))
                with open(out / "seg.txt", "a") as f:
                    f.write(f"{t:.6f} seg/{name}\n")
            n += 1
            if trajectory == "desk":
                tt = k * dt
                v = 0.15 * math.cos(2 * math.pi * tt / 6.0)
                w = 0.35 * math.sin(2 * math.pi * tt / 4.0)
            else:
                cmd = follower.step(_pose2d(info["T_world_base"]))
                if cmd.status == "reached":
                    leg += 1
                    if leg >= len(legs):
                        break
                    here = info["T_world_base"][:2, 3]
                    path = _path(fss, here, legs[leg])
                    if path is None:
                        break
                    follower.set_path(path)
                    cmd = follower.step(_pose2d(info["T_world_base"]))
                elif cmd.status in ("stale", "blocked"):
                    path = _path(fss, info["T_world_base"][:2, 3], legs[leg])
                    if path is not None:
                        follower.set_path(path)
                    cmd = follower.step(_pose2d(info["T_world_base"]))
                v, w = cmd.v, cmd.w
            obs, _, term, trunc, info = env.step(np.array([v, w], np.float32))
            collisions += int(info.get("collided", False))
            if term or trunc:
                break
        return {
            "folder": str(out),
            "trajectory": trajectory,
            "noise": noise,
            "frames": n,
            "collisions": collisions,
            "width": width,
            "height": height,
        }
    finally:
        env.close()


def read_base(folder: str | Path) -> np.ndarray | None:
    """``T_base_cam`` (4, 4) from a recorded folder's ``base.yaml``, or None."""
    p = Path(folder) / "base.yaml"
    if not p.is_file():
        return None
    T = np.asarray(yaml.safe_load(p.read_text())["T_base_cam"], dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{p}: T_base_cam must be 4x4")
    return T


def read_odometry(folder: str | Path) -> dict[float, np.ndarray] | None:
    """``{timestamp (rounded to 1 us): T_odom_cam (4, 4)}`` from ``odometry.txt``, or None."""
    p = Path(folder) / "odometry.txt"
    if not p.is_file():
        return None
    stamps, poses = read_groundtruth(p)
    return {round(float(t), 6): T for t, T in zip(stamps, poses, strict=True)}


def record_main(argv: list[str] | None = None) -> int:
    """``simn-sim record``: write a simulated TUM sequence."""
    ap = argparse.ArgumentParser(prog="simn-sim record", description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--trajectory", choices=TRAJECTORIES, default="desk")
    ap.add_argument("--noise", choices=("none", "d435i"), default="none")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--layout-seed", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--segmentation", action="store_true", help="also write seg/ labels")
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument(
        "--odom-noise",
        type=float,
        nargs=2,
        default=(0.02, 0.01),
        metavar=("TRANS", "ROT"),
        help="wheel-odometry noise written to odometry.txt (scale std per metre, heading std)",
    )
    a = ap.parse_args(argv)
    try:
        s = record_sequence(
            a.out, a.trajectory, a.noise, a.width, a.height, a.frames, a.layout_seed, a.seed,
            a.segmentation, a.overwrite, tuple(a.odom_noise),
        )  # fmt: skip
    except (FileExistsError, ValueError, RuntimeError) as e:
        print(f"simn-sim record: error: {e}")
        return 2
    print(f"wrote {s['frames']} frames to {s['folder']} ({s['collisions']} collision steps)")
    return 0
