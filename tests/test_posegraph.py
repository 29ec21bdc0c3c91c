"""gtsam pose graph of local-frame anchors: loop closure on a drifted square."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.geometry.se3 import inv_T, planar_T, se3_exp
from simn_sim.tracking.posegraph import (
    PoseGraphConfig,
    covariance_from_sigmas,
    optimize_anchors,
    optimize_pose_graph,
)

ODOM_COV = covariance_from_sigmas(np.radians(1.0), 0.02)
LOOP_COV = covariance_from_sigmas(np.radians(0.2), 0.005)


def square_loop(side: float = 4.0, step: float = 0.5) -> list[np.ndarray]:
    """Ground-truth anchors along a closed square (heading along the path), z = 0.3 m."""
    out = []
    n = int(round(side / step))
    for edge in range(4):
        for k in range(n):
            s = k * step
            x, y = [(s, 0.0), (side, s), (side - s, side), (0.0, side - s)][edge]
            out.append(planar_T(x, y, edge * np.pi / 2, 0.3))
    return out


def drifted_odometry(gt: list[np.ndarray], rng: np.random.Generator):
    """Odometry arcs with a yaw bias (0.8 deg/step) and noise; anchors chained from them."""
    arcs, anchors = [], {0: gt[0].copy()}
    for i in range(len(gt) - 1):
        true = inv_T(gt[i]) @ gt[i + 1]
        err = se3_exp(
            np.concatenate(
                [
                    rng.normal(scale=np.radians(0.2), size=3) + [0, 0, np.radians(0.8)],
                    rng.normal(scale=0.005, size=3),
                ]  # fmt: skip
            )
        )
        meas = true @ err
        arcs.append((i, i + 1, meas, ODOM_COV))
        anchors[i + 1] = anchors[i] @ meas
    return anchors, arcs


def ate(est: dict[int, np.ndarray], gt: list[np.ndarray]) -> float:
    """RMS anchor position error; anchor 0 is held at its true pose (no alignment needed)."""
    return float(np.sqrt(np.mean([np.sum((est[k][:3, 3] - gt[k][:3, 3]) ** 2) for k in est])))


def test_loop_closure_reduces_ate() -> None:
    rng = np.random.default_rng(0)
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, rng)
    last = len(gt) - 1
    loop_meas = inv_T(gt[last]) @ gt[0] @ se3_exp(rng.normal(scale=[0.002] * 3 + [0.003] * 3))
    loop = [(last, 0, loop_meas, LOOP_COV)]
    before = ate(anchors, gt)
    odom_only = optimize_anchors(anchors, odom, [])
    assert ate(odom_only, gt) == pytest.approx(before, rel=1e-3)  # nothing to correct with
    res = optimize_pose_graph(anchors, odom, loop)
    after = ate(res.anchors, gt)
    assert before > 0.3
    assert after < before / 8, (before, after)
    assert res.final_error < res.initial_error
    assert np.allclose(res.anchors[0], gt[0], atol=1e-3)


@pytest.mark.parametrize("seed", [1, 2])
def test_gnc_rejects_wrong_loops(seed: int) -> None:
    rng = np.random.default_rng(seed)
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, rng)
    last = len(gt) - 1

    def arc(i: int, j: int, err: np.ndarray | None = None):
        T = inv_T(gt[i]) @ gt[j]
        return (i, j, T if err is None else T @ err, LOOP_COV)

    good = [arc(last, 0), arc(last - 1, 1)]
    # false revisits: each claims an anchor sits far from where it is
    bad = [arc(20, 4, planar_T(1.5, 0.0, 0.5)), arc(28, 10, planar_T(0.5, 0.3, 0.2))]
    res = optimize_pose_graph(anchors, odom, good + bad)  # default: GNC-TLS on loop arcs
    assert res.loop_inliers == [True, True, False, False]
    only_good = optimize_anchors(anchors, odom, good)
    assert ate(res.anchors, gt) < 1.2 * ate(only_good, gt) + 1e-3
    plain = optimize_anchors(anchors, odom, good + bad, PoseGraphConfig(loop_robust="none"))
    assert ate(plain, gt) > 3 * ate(res.anchors, gt)


def test_bad_input() -> None:
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, np.random.default_rng(2))
    with pytest.raises(ValueError, match="unknown anchor"):
        optimize_anchors(anchors, odom + [(0, 99, np.eye(4), ODOM_COV)])
    with pytest.raises(ValueError, match="positive definite"):
        optimize_anchors(anchors, [(0, 1, np.eye(4), -ODOM_COV)] + odom[1:])
    with pytest.raises(ValueError, match="6x6"):
        optimize_anchors(anchors, [(0, 1, np.eye(4), np.eye(3))] + odom[1:])
    with pytest.raises(ValueError, match="not connected"):
        optimize_anchors(anchors, odom[:-3])
    with pytest.raises(ValueError, match="itself"):
        optimize_anchors(anchors, odom + [(3, 3, np.eye(4), ODOM_COV)])
    with pytest.raises(ConfigError, match="loop_robust"):
        PoseGraphConfig(loop_robust="tukey")
    with pytest.raises(ConfigError, match="gnc_inlier_probability"):
        PoseGraphConfig(gnc_inlier_probability=1.0)
