"""Per-frame position error of a TUM trajectory against ground truth, after the same Umeyama
SE(3) alignment as the ATE (``simn_sim.eval.trajectory.ate_per_frame``): where along a sequence
the error sits.

    .venv/bin/python scripts/ate_per_frame.py OUT/trajectory_online.txt SEQ/groundtruth.txt \\
        --first 12 --every 15
"""

from __future__ import annotations

import argparse

import numpy as np

from simn_sim.eval.trajectory import ate_per_frame, read_tum_trajectory


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("estimate", help="TUM trajectory (timestamp tx ty tz qx qy qz qw)")
    ap.add_argument("groundtruth")
    ap.add_argument("--first", type=int, default=12, help="print the first N frames' errors")
    ap.add_argument("--every", type=int, default=15, help="then every K-th frame's")
    a = ap.parse_args()
    if a.first < 0 or a.every < 1:
        ap.error("--first must be >= 0 and --every >= 1")
    e = 100.0 * ate_per_frame(read_tum_trajectory(a.estimate), read_tum_trajectory(a.groundtruth))
    print(f"frames {len(e)}, ATE rmse {np.sqrt(np.mean(e**2)):.2f} cm")
    print("first frames (cm):", " ".join(f"{x:.1f}" for x in e[: a.first]))
    print(f"every {a.every}th frame (cm):", " ".join(f"{x:.1f}" for x in e[:: a.every]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
