"""ATE / RPE through evo on trajectories with known errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simn_sim.eval.trajectory import ate_rpe, read_tum_trajectory, write_tum_trajectory
from simn_sim.geometry.se3 import make_T, pose_error, se3_exp


def _gt(n: int = 200, seed: int = 0) -> list[tuple[float, np.ndarray]]:
    """A smooth 3-D trajectory at 30 Hz with rotation about all axes."""
    t = np.arange(n) / 30.0
    out = []
    for s in t:
        xi = np.array(
            [0.3 * np.sin(s), 0.2 * np.cos(0.7 * s), 0.5 * s, np.cos(s), np.sin(s), 0.1 * s]
        )
        out.append((1000.0 + s, se3_exp(xi)))
    return out


def test_rigid_offset_gives_zero_ate() -> None:
    gt = _gt()
    G = se3_exp(np.array([0.3, -0.5, 1.2, 2.0, -1.0, 0.5]))  # a different world frame
    est = [(t + 0.004, G @ T) for t, T in gt]  # stamps off by 4 ms: still associated
    r = ate_rpe(est, gt)
    assert r["aligned"] and r["n_matched"] == len(gt)
    assert r["ate_rmse_m"] < 1e-6 and r["rpe_trans_rmse_m"] < 1e-6 and r["rpe_rot_rmse_deg"] < 1e-4
    raw = ate_rpe(est, gt, align=False)
    assert not raw["aligned"] and raw["ate_rmse_m"] > 1.0
    assert raw["rpe_trans_rmse_m"] < 1e-6  # relative motion does not see the world frame


def test_noise_gives_analytic_rms() -> None:
    rng = np.random.default_rng(1)
    gt = _gt(2000)
    sigma = 0.01  # isotropic 1 cm position noise -> E[ATE^2] = 3 sigma^2
    est = [(t, make_T(T[:3, :3], T[:3, 3] + rng.normal(scale=sigma, size=3))) for t, T in gt]
    r = ate_rpe(est, gt)
    expected = np.sqrt(3) * sigma
    assert abs(r["ate_rmse_m"] - expected) < 0.05 * expected
    # consecutive differences of independent noise: sqrt(2) * sqrt(3) * sigma
    assert abs(r["rpe_trans_rmse_m"] - np.sqrt(6) * sigma) < 0.07 * np.sqrt(6) * sigma
    assert r["rpe_rot_rmse_deg"] < 1e-4


def test_rotation_noise_in_rpe() -> None:
    rng = np.random.default_rng(2)
    gt = _gt(1000)
    est = []
    for t, T in gt:
        w = rng.normal(scale=np.radians(0.5), size=3)
        est.append((t, T @ se3_exp(np.concatenate([w, np.zeros(3)]))))
    r = ate_rpe(est, gt)
    assert r["ate_rmse_m"] < 1e-6
    # angle of the composition of two independent small 3-D rotations: E[theta^2] = 6 s^2
    assert abs(r["rpe_rot_rmse_deg"] - np.sqrt(6) * 0.5) < 0.1 * np.sqrt(6) * 0.5


def test_association_and_errors() -> None:
    gt = _gt(100)
    est = [(t + 10.0, T) for t, T in gt]  # 10 s later: nothing within 20 ms
    with pytest.raises(ValueError, match="match"):
        ate_rpe(est, gt)
    half = gt[::2]
    assert ate_rpe(half, gt)["n_matched"] == 50
    with pytest.raises(ValueError, match="empty"):
        ate_rpe([], gt)
    with pytest.raises(ValueError, match="increase"):
        ate_rpe(gt[::-1], gt)


def test_write_read_round_trip(tmp_path: Path) -> None:
    gt = _gt(30)
    p = write_tum_trajectory(tmp_path / "traj.txt", [t for t, _ in gt], [T for _, T in gt])
    back = read_tum_trajectory(p)
    assert len(back) == 30
    for (t, T), (t2, T2) in zip(gt, back, strict=True):
        assert abs(t - t2) < 1e-6
        et, er = pose_error(T, T2)
        assert et < 1e-8 and er < 1e-7
    assert ate_rpe(back, gt)["ate_rmse_m"] < 1e-6
