"""``ate_per_frame`` (``scripts/ate_per_frame.py``): per-frame errors after the ATE's alignment,
on known trajectories (a rigidly moved copy of the ground truth has zero error; the errors' RMS is the
ATE that ``ate_rpe`` reports)."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.eval.trajectory import (
    ate_per_frame,
    ate_rpe,
    read_tum_trajectory,
    write_tum_trajectory,
)
from simn_sim.geometry.se3 import make_T


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _gt(n: int = 40):
    t = 1.0 + 0.1 * np.arange(n)
    poses = [make_T(_rz(0.05 * i), [0.1 * i, 0.02 * i * i / n, 1.0]) for i in range(n)]
    return t, poses


def test_a_rigidly_moved_copy_has_no_error(tmp_path):
    t, gt = _gt()
    G = make_T(_rz(0.7), [3.0, -2.0, 0.5])
    write_tum_trajectory(tmp_path / "gt.txt", t, gt)
    write_tum_trajectory(tmp_path / "est.txt", t, [G @ T for T in gt])
    e = ate_per_frame(
        read_tum_trajectory(tmp_path / "est.txt"), read_tum_trajectory(tmp_path / "gt.txt")
    )
    assert e.shape == (len(t),) and float(e.max()) < 1e-6


def test_errors_sit_where_the_estimate_is_off_and_match_the_ate(tmp_path):
    t, gt = _gt()
    rng = np.random.default_rng(0)
    est = [T.copy() for T in gt]
    for i in range(5):  # the first five frames 5-10 cm off
        est[i][:3, 3] += rng.uniform(0.05, 0.1, 3) * rng.choice([-1, 1], 3)
    write_tum_trajectory(tmp_path / "gt.txt", t, gt)
    write_tum_trajectory(tmp_path / "est.txt", t, est)
    e = ate_per_frame(
        read_tum_trajectory(tmp_path / "est.txt"), read_tum_trajectory(tmp_path / "gt.txt")
    )
    ref = ate_rpe(list(zip(t, est, strict=True)), list(zip(t, gt, strict=True)))
    assert np.sqrt(np.mean(e**2)) == pytest.approx(ref["ate_rmse_m"], rel=1e-9)
    assert e[:5].min() > 3 * np.median(e[5:])
