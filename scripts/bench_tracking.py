"""Tracking benchmark: SimnSlam against Open3D's RGB-D odometry on the same sequences, same run.

Open3D: ``open3d.pipelines.odometry.compute_rgbd_odometry`` frame to frame (hybrid Jacobian:
photometric + geometric terms, default pyramid 20/10/5 iterations), initialised with the same
prior as ours (constant velocity, or the wheel-odometry increment with ``--odometry``), chained.
Ours: :class:`~simn_sim.slam.pipeline.SimnSlam` (``map_kind`` from ``--map``), registration ms
per frame = ``track_ms`` (perception + registration), against the paper's 40.2 ms (RTX 4090).

    MUJOCO_GL=egl .venv/bin/python scripts/bench_tracking.py /tmp/simn_slam_seqs/desk_none \
        /tmp/simn_slam_seqs/desk_d435i --tum9
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from simn_sim.eval.trajectory import ate_rpe  # noqa: E402
from simn_sim.geometry.se3 import inv_T, pose_error  # noqa: E402
from simn_sim.io.tum import read_tum  # noqa: E402
from simn_sim.slam import SimnSlam, SlamConfig  # noqa: E402
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
            if odom is not None:
                init = inv_T(odom[round(prev_t, 6)]) @ odom[round(fr.timestamp, 6)]
            elif T_prev2 is not None:
                init = inv_T(T_prev) @ constant_velocity_prior(T_prev2, T_prev)
            else:
                init = np.eye(4)
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
    ap.add_argument("--map", choices=("points", "implicit"), default="points")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    _open3d()
    jobs = [(f, None) for f in a.folders]
    if a.tum9 and TUM9.is_dir():
        jobs.append((TUM9, "fr1"))
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
        rows.append(row)
        print(json.dumps(row))
    print()
    print(
        "| sequence | prior | ATE ours (cm) | ATE Open3D (cm) | ratio | track ms ours | "
        "frame ms ours | ms Open3D | ours / paper 40 ms |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['sequence']} | {r['prior']} | {r['ours_ate_cm']:.2f} | {r['open3d_ate_cm']:.2f} | "
            f"{r['ate_ratio_ours_over_open3d']:.2f} | {r['ours_track_ms_median']:.0f} | "
            f"{r['ours_frame_ms_median']:.0f} | {r['open3d_ms_median']:.0f} | "
            f"{r['ours_track_ms_over_paper_40ms']:.2f} |"
        )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
