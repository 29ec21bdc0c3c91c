"""Pose-graph optimisation of local-frame anchors with gtsam.

Anchors are ``T_world_anchor`` (4, 4). An arc ``(i, j, T_i_j, cov)`` measures the pose of anchor
``j`` in anchor ``i``'s frame, ``T_i_j = T_world_i^-1 T_world_j`` -- gtsam's
``BetweenFactorPose3(i, j)``. ``cov`` (6, 6) is in gtsam's Pose3 tangent convention: right
perturbation ``T_i_j exp(delta)``, ``delta = (omega, v)``, rotation first (the convention of
:class:`~simn_sim.tracking.registration.RegistrationResult.covariance`). A prior holds the first
anchor (smallest id unless ``fixed`` is given). Levenberg-Marquardt does the optimisation.

Loop arcs are where wrong data association comes from, so they can be made robust. The default,
``"gnc_tls"``, is gtsam's graduated non-convexity with a truncated-least-squares loss, the prior
and odometry being known inliers: it rejects a wrong loop arc even when the drift makes the
right ones look large at the start. Plain M-estimators (``"huber"``, ``"cauchy"``) are offered,
but measured on a drifted square with one false loop they either kept the false loop or also
down-weighted the true one, depending on the scale.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Literal

import gtsam
import numpy as np

from simn_sim.config import Config, require
from simn_sim.tracking.lie import check_pose

Arc = tuple[int, int, np.ndarray, np.ndarray]


@dataclasses.dataclass(frozen=True)
class PoseGraphConfig(Config):
    """Pose-graph settings; the robust scale ``loop_robust_k`` is in whitened units (sigmas)."""

    prior_sigma_rot: float = 1e-4  # rad, prior on the fixed anchor
    prior_sigma_trans: float = 1e-4  # m
    loop_robust: Literal["none", "huber", "cauchy", "gnc_tls", "gnc_gm"] = "gnc_tls"
    loop_robust_k: float = 3.0  # M-estimator scale (sigmas) for "huber" / "cauchy"
    gnc_inlier_probability: float = 0.99  # chi-square quantile (6 dof) of the GNC inlier bound
    max_iters: int = 100
    relative_tol: float = 1e-8
    absolute_tol: float = 1e-10

    def validate(self) -> None:
        n = type(self).__name__
        require(self.prior_sigma_rot > 0, n, "prior_sigma_rot", "must be > 0")
        require(self.prior_sigma_trans > 0, n, "prior_sigma_trans", "must be > 0")
        require(self.loop_robust_k > 0, n, "loop_robust_k", "must be > 0")
        require(
            0 < self.gnc_inlier_probability < 1, n, "gnc_inlier_probability", "must be in (0, 1)"
        )
        require(self.max_iters >= 1, n, "max_iters", "must be >= 1")
        require(self.relative_tol > 0, n, "relative_tol", "must be > 0")
        require(self.absolute_tol > 0, n, "absolute_tol", "must be > 0")


@dataclasses.dataclass(frozen=True)
class PoseGraphResult:
    """Optimised anchors and the graph error (gtsam's 0.5 * sum of squared whitened errors)."""

    anchors: dict[int, np.ndarray]
    initial_error: float
    final_error: float
    iterations: int
    loop_inliers: list[bool]  # per loop arc: kept (True) or rejected by the robust loss


def check_covariance(cov: np.ndarray, name: str = "cov") -> np.ndarray:
    """A symmetric positive-definite (6, 6) float64 covariance, or ValueError."""
    C = np.asarray(cov, dtype=np.float64)
    if C.shape != (6, 6) or not np.isfinite(C).all():
        raise ValueError(f"{name} must be a finite 6x6 matrix, got shape {C.shape}")
    if np.abs(C - C.T).max() > 1e-9 * max(1.0, np.abs(C).max()):
        raise ValueError(f"{name} is not symmetric")
    try:
        np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} is not positive definite") from None
    return 0.5 * (C + C.T)


def _noise(cov: np.ndarray, robust: str, k: float):
    base = gtsam.noiseModel.Gaussian.Covariance(cov)
    est = gtsam.noiseModel.mEstimator
    if robust == "huber":
        return gtsam.noiseModel.Robust.Create(est.Huber.Create(k), base)
    if robust == "cauchy":
        return gtsam.noiseModel.Robust.Create(est.Cauchy.Create(k), base)
    return base  # "none" and GNC (which needs plain Gaussian factors)


def _check_arcs(arcs: Sequence[Arc], anchors: Mapping[int, np.ndarray], kind: str) -> list:
    out = []
    for n, arc in enumerate(arcs):
        if len(arc) != 4:
            raise ValueError(f"{kind} arc {n} must be (i, j, T_i_j, cov6)")
        i, j, T, C = arc
        i, j = int(i), int(j)
        if i not in anchors or j not in anchors:
            raise ValueError(f"{kind} arc {n} ({i} -> {j}) references an unknown anchor")
        if i == j:
            raise ValueError(f"{kind} arc {n} connects anchor {i} to itself")
        out.append(
            (
                i,
                j,
                check_pose(T, f"{kind} arc {n} T_i_j"),
                check_covariance(C, f"{kind} arc {n} cov"),
            )
        )
    return out


def _connected(ids: list[int], arcs: list) -> set[int]:
    parent = {i: i for i in ids}

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for i, j, _, _ in arcs:
        parent[find(i)] = find(j)
    return {i for i in ids if find(i) == find(ids[0])}


def optimize_pose_graph(
    anchors: Mapping[int, np.ndarray],
    odom_arcs: Sequence[Arc],
    loop_arcs: Sequence[Arc] = (),
    cfg: PoseGraphConfig | None = None,
    fixed: int | None = None,
    unary: Sequence[tuple[int, np.ndarray, np.ndarray]] = (),
) -> PoseGraphResult:
    """Optimise ``anchors`` (id -> T_world_anchor, the initial guess) given the arcs.

    Every anchor must be connected to ``fixed`` (default: the smallest id) through arcs.
    ``unary``: absolute priors ``(id, T_world_anchor, information)``, the (6, 6) information
    in gtsam's tangent order (rotation, translation; the anchor's own axes), e.g. a heading
    measured from the walls that constrains one rotation direction only.
    """
    cfg = cfg or PoseGraphConfig()
    if not anchors:
        raise ValueError("no anchors")
    A = {int(k): check_pose(T, f"anchor {k}") for k, T in anchors.items()}
    odo = _check_arcs(odom_arcs, A, "odom")
    loop = _check_arcs(loop_arcs, A, "loop")
    fixed = min(A) if fixed is None else int(fixed)
    if fixed not in A:
        raise ValueError(f"fixed anchor {fixed} is not an anchor")
    ids = [fixed] + sorted(k for k in A if k != fixed)
    reach = _connected(ids, odo + loop)
    if len(reach) != len(ids):
        raise ValueError(f"anchors {sorted(set(ids) - reach)} are not connected to anchor {fixed}")

    graph = gtsam.NonlinearFactorGraph()
    init = gtsam.Values()
    for k in ids:
        init.insert(k, gtsam.Pose3(A[k]))
    prior = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([cfg.prior_sigma_rot] * 3 + [cfg.prior_sigma_trans] * 3)
    )
    graph.add(gtsam.PriorFactorPose3(fixed, gtsam.Pose3(A[fixed]), prior))
    for k, T, info in unary:
        if int(k) not in A:
            raise ValueError(f"unary prior on {k}, which is not an anchor")
        info = np.asarray(info, dtype=np.float64)
        if info.shape != (6, 6) or not np.isfinite(info).all():
            raise ValueError(
                f"unary prior {k}: information must be a finite (6, 6), got {info.shape}"
            )
        if not np.allclose(info, info.T) or np.linalg.eigvalsh(info).min() <= 0:
            raise ValueError(f"unary prior {k}: information must be symmetric positive definite")
        T = check_pose(T, f"unary prior {k}")
        graph.add(
            gtsam.PriorFactorPose3(
                int(k), gtsam.Pose3(T), gtsam.noiseModel.Gaussian.Information(info)
            )
        )
    for i, j, T, C in odo:
        graph.add(gtsam.BetweenFactorPose3(i, j, gtsam.Pose3(T), _noise(C, "none", 1.0)))
    n_known = graph.size()
    for i, j, T, C in loop:
        graph.add(
            gtsam.BetweenFactorPose3(
                i, j, gtsam.Pose3(T), _noise(C, cfg.loop_robust, cfg.loop_robust_k)
            )
        )
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.max_iters)
    params.setRelativeErrorTol(cfg.relative_tol)
    params.setAbsoluteErrorTol(cfg.absolute_tol)
    inliers = [True] * len(loop)
    if loop and cfg.loop_robust.startswith("gnc"):
        gp = gtsam.GncLMParams(params)
        gp.setLossType(
            gtsam.GncLossType.TLS if cfg.loop_robust == "gnc_tls" else gtsam.GncLossType.GM
        )
        gp.setKnownInliers(list(range(n_known)))
        gnc = gtsam.GncLMOptimizer(graph, init, gp)
        gnc.setInlierCostThresholdsAtProbability(cfg.gnc_inlier_probability)
        res = gnc.optimize()
        w = np.asarray(gnc.getWeights())[n_known:]
        inliers = [bool(x > 0.5) for x in w]
        # final error of the graph the robust loss settled on (rejected loops left out)
        kept = gtsam.NonlinearFactorGraph()
        for f in range(n_known):
            kept.add(graph.at(f))
        for m, ok in enumerate(inliers):
            if ok:
                kept.add(graph.at(n_known + m))
        opt = gtsam.LevenbergMarquardtOptimizer(kept, res, params)
        res = opt.optimize()
    else:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, init, params)
        res = opt.optimize()
    out = {k: np.asarray(res.atPose3(k).matrix(), dtype=np.float64) for k in ids}
    return PoseGraphResult(
        out, float(graph.error(init)), float(graph.error(res)), int(opt.iterations()), inliers
    )


def optimize_anchors(
    anchors: Mapping[int, np.ndarray],
    odom_arcs: Sequence[Arc],
    loop_arcs: Sequence[Arc] = (),
    cfg: PoseGraphConfig | None = None,
) -> dict[int, np.ndarray]:
    """Optimised ``{id: T_world_anchor}``; see :func:`optimize_pose_graph`."""
    return optimize_pose_graph(anchors, odom_arcs, loop_arcs, cfg).anchors


def covariance_from_sigmas(sigma_rot: float, sigma_trans: float) -> np.ndarray:
    """Diagonal (6, 6) covariance, (omega, v) order."""
    return np.diag([sigma_rot**2] * 3 + [sigma_trans**2] * 3)
