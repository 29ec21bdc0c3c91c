"""Trajectory error (ATE / RPE) as the TUM RGB-D benchmark computes it, through evo.

ATE: estimated and ground-truth poses are associated by timestamp (``max_diff`` seconds, nearest
stamp), the estimate is aligned to the ground truth by Umeyama's method in SE(3) (no scale: an
RGB-D camera measures metric depth), and the RMSE / mean of the translation differences is
reported. RPE: the relative motion over ``rpe_delta`` frames of the (unaligned) associated
trajectories is compared; translation RMSE in metres, rotation RMSE in degrees.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D

from simn_sim.io.tum import pose_to_tum, read_groundtruth
from simn_sim.tracking.lie import check_pose

StampedPoses = Sequence[tuple[float, np.ndarray]]


def _to_evo(traj: StampedPoses, name: str) -> PoseTrajectory3D:
    if len(traj) == 0:
        raise ValueError(f"{name} trajectory is empty")
    stamps = np.array([float(t) for t, _ in traj], dtype=np.float64)
    if not np.isfinite(stamps).all():
        raise ValueError(f"{name} trajectory has non-finite timestamps")
    if np.any(np.diff(stamps) <= 0):
        raise ValueError(f"{name} trajectory timestamps must increase strictly")
    poses = [check_pose(T, f"{name} pose {k}") for k, (_, T) in enumerate(traj)]
    return PoseTrajectory3D(poses_se3=poses, timestamps=stamps)


def _aligned_ape(
    est: StampedPoses, gt: StampedPoses, max_diff: float, align: bool
) -> tuple[PoseTrajectory3D, PoseTrajectory3D, metrics.APE, bool]:
    """The associated trajectories (the estimate unaligned), the translation APE of the
    estimate after the SE(3) alignment (when ``align`` and at least 3 poses matched) and
    whether it was aligned."""
    if max_diff <= 0:
        raise ValueError(f"max_diff must be > 0, got {max_diff}")
    t_gt, t_est = _to_evo(gt, "gt"), _to_evo(est, "est")
    try:
        t_gt, t_est = sync.associate_trajectories(t_gt, t_est, max_diff=max_diff)
    except sync.SyncException as e:
        raise ValueError(f"no matching timestamps within {max_diff} s: {e}") from None
    n = t_est.num_poses
    if n < 2:
        raise ValueError(f"only {n} pose(s) matched within {max_diff} s; need at least 2")
    aligned = bool(align and n >= 3)
    t_est_al = copy.deepcopy(t_est)
    if aligned:
        t_est_al.align(t_gt, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((t_gt, t_est_al))
    return t_gt, t_est, ape, aligned


def ate_per_frame(
    est: StampedPoses, gt: StampedPoses, max_diff: float = 0.02, align: bool = True
) -> np.ndarray:
    """(N,) metres: each matched pose's translation error after the ATE's alignment (the
    errors whose RMS is :func:`ate_rpe`'s ``ate_rmse_m``): where along a trajectory the error
    sits."""
    return np.asarray(_aligned_ape(est, gt, max_diff, align)[2].error, dtype=np.float64)


def ate_rpe(
    est: StampedPoses,
    gt: StampedPoses,
    max_diff: float = 0.02,
    align: bool = True,
    rpe_delta: int = 1,
) -> dict:
    """ATE and RPE of ``est`` against ``gt``, both lists of ``(t, T_world_cam (4, 4))``.

    Returns ``dict(ate_rmse_m, ate_mean_m, ate_max_m, rpe_trans_rmse_m, rpe_rot_rmse_deg,
    n_matched, aligned)``; ``aligned`` is True when the Umeyama SE(3) alignment was applied
    (``align`` and at least 3 matched poses). Raises ValueError when fewer than 2 poses match.
    """
    if rpe_delta < 1:
        raise ValueError(f"rpe_delta must be >= 1, got {rpe_delta}")
    t_gt, t_est, ape, aligned = _aligned_ape(est, gt, max_diff, align)
    n = t_est.num_poses
    out = {
        "ate_rmse_m": float(ape.get_statistic(metrics.StatisticsType.rmse)),
        "ate_mean_m": float(ape.get_statistic(metrics.StatisticsType.mean)),
        "ate_max_m": float(ape.get_statistic(metrics.StatisticsType.max)),
        "n_matched": int(n),
        "aligned": aligned,
    }
    delta = min(rpe_delta, n - 1)
    for key, rel in (
        ("rpe_trans_rmse_m", metrics.PoseRelation.translation_part),
        ("rpe_rot_rmse_deg", metrics.PoseRelation.rotation_angle_deg),
    ):
        rpe = metrics.RPE(rel, delta=delta, delta_unit=metrics.Unit.frames, all_pairs=False)
        rpe.process_data((t_gt, t_est))
        out[key] = float(rpe.get_statistic(metrics.StatisticsType.rmse))
    return out


def write_tum_trajectory(
    path: str | Path, stamps: Sequence[float] | np.ndarray, poses: Sequence[np.ndarray]
) -> Path:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines (TUM format); returns the path."""
    stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if len(stamps) != len(poses):
        raise ValueError(f"{len(stamps)} stamps but {len(poses)} poses")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for t, T in zip(stamps, poses, strict=True):
        if not np.isfinite(t):
            raise ValueError("non-finite timestamp")
        lines.append(f"{t:.6f} " + " ".join(f"{x:.9f}" for x in pose_to_tum(T)))
    path.write_text("\n".join(lines) + "\n")
    return path


def read_tum_trajectory(path: str | Path) -> list[tuple[float, np.ndarray]]:
    """Read a TUM trajectory file as a list of ``(t, T (4, 4))``."""
    stamps, poses = read_groundtruth(Path(path))
    return [(float(t), T) for t, T in zip(stamps, poses, strict=True)]
