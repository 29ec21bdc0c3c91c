"""Per-frame position error of a TUM trajectory against ground truth, after the same Umeyama
SE(3) alignment as the ATE (``simn_sim.eval.trajectory.ate_rpe``): where along a sequence the
error sits.

    .venv/bin/python scripts/ate_per_frame.py OUT/trajectory_online.txt SEQ/groundtruth.txt \\
        --first 12 --every 15
"""

from __future__ import annotations

import argparse
import copy

import numpy as np
from evo.core import metrics, sync

from simn_sim.eval.trajectory import _to_evo, read_tum_trajectory


def per_frame_errors(est_path: str, gt_path: str, max_diff: float = 0.02) -> np.ndarray:
    """(N,) metres: each matched frame's position error after the SE(3) alignment."""
    gt = _to_evo(read_tum_trajectory(gt_path), "gt")
    est = _to_evo(read_tum_trajectory(est_path), "est")
    gt, est = sync.associate_trajectories(gt, est, max_diff=max_diff)
    if est.num_poses < 3:
        raise ValueError(f"only {est.num_poses} poses matched within {max_diff} s; need 3")
    est = copy.deepcopy(est)
    est.align(gt, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((gt, est))
    return np.asarray(ape.error, float)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("estimate", help="TUM trajectory (timestamp tx ty tz qx qy qz qw)")
    ap.add_argument("groundtruth")
    ap.add_argument("--first", type=int, default=12, help="print the first N frames' errors")
    ap.add_argument("--every", type=int, default=15, help="then every K-th frame's")
    a = ap.parse_args()
    if a.first < 0 or a.every < 1:
        ap.error("--first must be >= 0 and --every >= 1")
    e = 100.0 * per_frame_errors(a.estimate, a.groundtruth)
    print(f"frames {len(e)}, ATE rmse {np.sqrt(np.mean(e**2)):.2f} cm")
    print("first frames (cm):", " ".join(f"{x:.1f}" for x in e[: a.first]))
    print(f"every {a.every}th frame (cm):", " ".join(f"{x:.1f}" for x in e[:: a.every]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
