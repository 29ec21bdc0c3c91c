"""Tracking benchmark: SimnSlam against Open3D's RGB-D odometry on the same sequences, same run.

Two protocols for Open3D:

* frame to frame: ``open3d.pipelines.odometry.compute_rgbd_odometry`` (hybrid Jacobian:
  photometric + geometric terms, default pyramid 20/10/5 iterations), initialised with the same
  prior as ours (constant velocity, or the wheel-odometry increment with ``--odometry``),
  chained;
* frame to model (``--open3d-model``, the protocol ours follows: each frame is registered to a
  map of the frames before it): Open3D's dense SLAM model (``open3d.t.pipelines.slam.Model``:
  a TSDF voxel-block grid, 1 cm voxels, each frame registered point-to-plane against the
  model's ray-cast depth, then fused), initialised with the same prior.

Ours: :class:`~simn_sim.slam.pipeline.SimnSlam`, ``--map points`` (the plain config: tracking
on the surface store) or ``learned`` (``simn-sim slam``'s default ``learned_tracking``
preset: tracking on the learned map); registration ms per frame = ``track_ms`` (perception +
registration), against the paper's 40.2 ms (RTX 4090). ``--camera fr1`` gives the calibration
of folders without a camera.yaml (the real TUM clips).

    MUJOCO_GL=egl .venv/bin/python scripts/bench_tracking.py /tmp/simn_slam_seqs/desk_none \
        /tmp/simn_slam_seqs/desk_d435i --tum9
    MUJOCO_GL=egl .venv/bin/python scripts/bench_tracking.py ../shared/data/tum_fr1_rpy_last150 \
        --camera fr1 --map learned --open3d-model

``--variant NAME JSON`` (repeatable) adds runs of ours with other front-end settings on the same
frames, e.g. ``--variant prior_only '{"mapper": {"decoder": {"residual": false}}}'`` or
``--variant points '{"preset": "point_tracking", "map_kind": "points"}'``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from simn_sim.config import ConfigError, json_object  # noqa: E402
from simn_sim.eval.trajectory import ate_rpe  # noqa: E402
from simn_sim.geometry.se3 import inv_T, pose_error  # noqa: E402
from simn_sim.io.tum import read_tum  # noqa: E402
from simn_sim.slam import SimnSlam, SlamConfig  # noqa: E402
from simn_sim.slam.presets import load_slam_config  # noqa: E402
from simn_sim.slam.record import read_base, read_odometry  # noqa: E402
from simn_sim.tracking.lie import constant_velocity_prior  # noqa: E402

PAPER_REG_MS = 40.2
TUM9 = Path(__file__).resolve().parents[1] / "tests" / "data" / "tum_fr1_desk_9"


def _open3d():
    try:
        import open3d as o3d
    except ImportError as e:  # noqa: F841
        raise SystemExit(
            "bench_tracking: open3d is not importable "
            f"({e}); install the bench extra (open3d-cpu) and, on Debian, libusb-1.0-0"
        ) from None
    return o3d


def _rigid(T: np.ndarray) -> np.ndarray:
    """Project onto SE(3) (a chain of float products drifts off it and then diverges)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, T[:3, 3]
    return out


def _prior_increment(odom, prev_t, t, T_prev, T_prev2) -> np.ndarray:
    """The prior's motion from the previous frame to this one (camera frame): the wheel-odometry
    increment, else constant velocity from the last two poses, else none (identity)."""
    if odom is not None:
        return inv_T(odom[round(prev_t, 6)]) @ odom[round(t, 6)]
    if T_prev2 is not None:
        return inv_T(T_prev) @ constant_velocity_prior(T_prev2, T_prev)
    return np.eye(4)


def run_open3d(
    seq, odom=None, max_depth: float = 6.0, max_correction_m: float = 0.3
) -> tuple[list, list[float], int]:
    """Chained frame-to-frame Open3D odometry -> ([(t, T_world_cam)], per-frame ms, failures)."""
    o3d = _open3d()
    K = seq.intrinsics
    intr = o3d.camera.PinholeCameraIntrinsic(K.width, K.height, K.fx, K.fy, K.cx, K.cy)
    jac = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()
    opt = o3d.pipelines.odometry.OdometryOption()
    opt.depth_max = max_depth
    traj, ms = [], []
    prev_rgbd, T_prev, T_prev2 = None, np.eye(4), None
    prev_t = None
    n_fail = 0
    for fr in seq:
        t0 = time.perf_counter()
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(fr.rgb)),
            o3d.geometry.Image(np.ascontiguousarray(fr.depth.astype(np.float32))),
            depth_scale=1.0,
            depth_trunc=max_depth,
            convert_rgb_to_intensity=True,
        )
        if prev_rgbd is None:
            T = np.eye(4)
        else:
            init = _prior_increment(odom, prev_t, fr.timestamp, T_prev, T_prev2)
            ok, T_rel, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
                rgbd, prev_rgbd, intr, np.array(init, dtype=np.float64), jac, opt
            )
            T_rel = np.array(T_rel, dtype=np.float64, copy=True)
            # the same sanity gate as ours (max_correction_m): Open3D reports success for
            # jumps of metres on the textureless sim walls; then the prior is kept
            good = ok and np.isfinite(T_rel).all()
            if good:
                R = T_rel[:3, :3]
                dt, dr = pose_error(init, T_rel)
                good = (
                    np.allclose(R @ R.T, np.eye(3), atol=1e-4)
                    and dt <= max_correction_m
                    and np.degrees(dr) <= 20.0
                )
            n_fail += int(not good)
            T = _rigid(T_prev @ (T_rel if good else init))
        ms.append((time.perf_counter() - t0) * 1e3)
        traj.append((fr.timestamp, T))
        T_prev2, T_prev, prev_rgbd, prev_t = (
            (T_prev if prev_rgbd is not None else None),
            T,
            rgbd,
            fr.timestamp,
        )
    return traj, ms, n_fail


def run_open3d_model(
    seq, odom=None, voxel: float = 0.01, max_depth: float = 4.0, depth_diff: float = 0.07
) -> tuple[list, list[float], int]:
    """Open3D dense SLAM (frame to model) -> ([(t, T_world_cam)], per-frame ms, failures).

    Each frame is tracked point-to-plane against the model's ray-cast depth from the predicted
    pose (the prior's increment applied to the last pose), then integrated. A result moving
    the prediction by more than 0.3 m / 20 deg keeps the prediction (as in ``run_open3d``)."""
    o3d = _open3d()
    o3c = o3d.core
    dev = o3c.Device("CPU:0")
    K = seq.intrinsics
    Kt = o3c.Tensor(
        np.array([[K.fx, 0, K.cx], [0, K.fy, K.cy], [0, 0, 1]], np.float64), o3c.float64
    )
    scale = 1000.0
    model = o3d.t.pipelines.slam.Model(voxel, 16, 20000, o3c.Tensor(np.eye(4)), dev)
    inp = o3d.t.pipelines.slam.Frame(K.height, K.width, Kt, dev)
    ray = o3d.t.pipelines.slam.Frame(K.height, K.width, Kt, dev)
    traj, ms = [], []
    T_prev, T_prev2, prev_t = np.eye(4), None, None
    n_fail = 0
    for i, fr in enumerate(seq):
        t0 = time.perf_counter()
        d16 = np.round(np.nan_to_num(fr.depth, nan=0.0) * scale).clip(0, 65535).astype(np.uint16)
        inp.set_data_from_image("depth", o3d.t.geometry.Image(o3c.Tensor(d16)))
        inp.set_data_from_image(
            "color", o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(fr.rgb)))
        )
        if i == 0:
            T = np.eye(4)
        else:
            init = _prior_increment(odom, prev_t, fr.timestamp, T_prev, T_prev2)
            T_pred = _rigid(T_prev @ init)
            model.update_frame_pose(i - 1, o3c.Tensor(T_pred))  # ray-cast from the prediction
            model.synthesize_model_frame(ray, scale, 0.1, max_depth, 8.0, False)
            res = model.track_frame_to_model(inp, ray, scale, max_depth, depth_diff)
            T_corr = np.asarray(res.transformation.numpy(), np.float64)
            good = bool(np.isfinite(T_corr).all()) and res.fitness > 0
            if good:
                dt, dr = pose_error(np.eye(4), T_corr)
                good = dt <= 0.3 and np.degrees(dr) <= 20.0
            n_fail += int(not good)
            T = _rigid(T_pred @ T_corr) if good else T_pred
        model.update_frame_pose(i, o3c.Tensor(T))
        model.integrate(inp, scale, max_depth, 8.0)
        ms.append((time.perf_counter() - t0) * 1e3)
        traj.append((fr.timestamp, T))
        T_prev2, T_prev, prev_t = (T_prev if i > 0 else None), T, fr.timestamp
    return traj, ms, n_fail


def run_ours(seq, folder, odom, cfg: SlamConfig) -> tuple[list, list[float], list[float]]:
    slam = SimnSlam(cfg, seq.intrinsics, read_base(folder))
    track, total = [], []
    for fr in seq:
        t0 = time.perf_counter()
        prior = None if odom is None else odom[round(fr.timestamp, 6)]
        out = slam.process(fr.timestamp, fr.rgb, fr.depth, prior)
        total.append((time.perf_counter() - t0) * 1e3)
        track.append(out.track_ms)
    return slam.trajectory(), track, total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="*", type=Path)
    ap.add_argument("--tum9", action="store_true", help="also the real TUM fr1/desk clip")
    ap.add_argument("--odometry", action="store_true", help="wheel-odometry prior for both")
    ap.add_argument(
        "--map",
        choices=("points", "learned", "implicit"),
        default="points",
        help="points: SlamConfig(map_kind=points); learned: the learned_tracking preset "
        "(simn-sim slam's default); implicit: SlamConfig() (learned map trained, point tracking)",
    )
    ap.add_argument("--camera", default=None, help="fr1|fr2|fr3 for folders without camera.yaml")
    ap.add_argument(
        "--open3d-model", action="store_true", help="also Open3D frame to model (dense SLAM)"
    )
    ap.add_argument(
        "--variant",
        nargs=2,
        action="append",
        default=[],
        metavar=("NAME", "JSON"),
        help="also ours with this SlamConfig (JSON as a slam YAML: a 'preset' key, default "
        "learned_tracking, and nested changes); repeatable; a table of ATE per variant follows",
    )
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    variants = []
    for name, text in a.variant:
        try:
            changes = json_object(text, f"--variant {name}")
        except ConfigError as e:
            ap.error(str(e))
        variants.append(
            (name, load_slam_config(None, default_preset="learned_tracking", **changes))
        )
    _open3d()
    jobs = [(f, a.camera) for f in a.folders]
    if a.tum9 and TUM9.is_dir():
        jobs.append((TUM9, "fr1"))
    if a.map == "learned":
        cfg = load_slam_config(None, default_preset="learned_tracking")
    else:
        cfg = SlamConfig(map_kind=a.map)
    rows = []
    for folder, cam in jobs:
        seq = read_tum(folder, cam)
        odom = read_odometry(folder) if a.odometry else None
        gt = [(fr_t, seq.ground_truth(k)) for k, fr_t in enumerate(seq.timestamps)]
        o_traj, o_ms, o_fail = run_open3d(seq, odom)
        s_traj, s_track, s_total = run_ours(seq, folder, odom, cfg)
        o_ate = ate_rpe(o_traj, gt)["ate_rmse_m"]
        s_ate = ate_rpe(s_traj, gt)["ate_rmse_m"]
        row = {
            "sequence": folder.name,
            "frames": len(seq),
            "map": a.map,
            "prior": "odometry" if odom is not None else "constant velocity",
            "ours_ate_cm": 100 * s_ate,
            "open3d_ate_cm": 100 * o_ate,
            "ate_ratio_ours_over_open3d": s_ate / o_ate if o_ate > 0 else float("nan"),
            "ours_track_ms_median": float(np.median(s_track)),
            "ours_frame_ms_median": float(np.median(s_total)),
            "open3d_ms_median": float(np.median(o_ms)),
            "open3d_rejected_frames": o_fail,
            "ms_ratio_ours_track_over_open3d": float(np.median(s_track) / np.median(o_ms)),
            "ours_track_ms_over_paper_40ms": float(np.median(s_track) / PAPER_REG_MS),
        }
        if a.open3d_model:
            m_traj, m_ms, m_fail = run_open3d_model(seq, odom)
            m_ate = ate_rpe(m_traj, gt)["ate_rmse_m"]
            row.update(
                open3d_model_ate_cm=100 * m_ate,
                open3d_model_ms_median=float(np.median(m_ms)),
                open3d_model_rejected_frames=m_fail,
                ate_ratio_ours_over_open3d_model=s_ate / m_ate if m_ate > 0 else float("nan"),
            )
        for name, vcfg in variants:
            v_traj, v_track, _ = run_ours(seq, folder, odom, vcfg)
            row.setdefault("variants", {})[name] = {
                "ate_cm": 100 * ate_rpe(v_traj, gt)["ate_rmse_m"],
                "track_ms_median": float(np.median(v_track)),
            }
        rows.append(row)
        print(json.dumps(row))
    print()
    print(
        "| sequence | ours (map) | prior | ATE ours (cm) | ATE Open3D frame to frame (cm) | "
        "ATE Open3D frame to model (cm) | track ms ours | frame ms ours | ms Open3D f2f / f2m | "
        "ours / paper 40 ms |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        m_ate = r.get("open3d_model_ate_cm")
        m_ms = r.get("open3d_model_ms_median")
        print(
            f"| {r['sequence']} | {r['map']} | {r['prior']} | {r['ours_ate_cm']:.2f} | "
            f"{r['open3d_ate_cm']:.2f} | {'-' if m_ate is None else f'{m_ate:.2f}'} | "
            f"{r['ours_track_ms_median']:.0f} | {r['ours_frame_ms_median']:.0f} | "
            f"{r['open3d_ms_median']:.0f} / {'-' if m_ms is None else f'{m_ms:.0f}'} | "
            f"{r['ours_track_ms_over_paper_40ms']:.2f} |"
        )
    if variants:
        print()
        print("| sequence | variant | ATE (cm) | track ms median |")
        print("|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['sequence']} | {a.map} (the run's own) | {r['ours_ate_cm']:.2f} | "
                f"{r['ours_track_ms_median']:.0f} |"
            )
            for name, v in r["variants"].items():
                print(
                    f"| {r['sequence']} | {name} | {v['ate_cm']:.2f} | {v['track_ms_median']:.0f} |"
                )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
