"""Frame-to-map registration on an implicit surface (paper: "Building Spatial-Implicit Local Frames").

A frame's points ``p_cam`` (N, 3), OpenCV camera frame, lie on the surface, so at the right pose
``T_map_cam`` their SDF is zero. We minimise ``sum_i rho(r_i)`` with ``r_i = sdf(T p_i)`` by
Levenberg-Marquardt with iteratively re-weighted Geman-McClure weights.

Perturbation convention (left, in map coordinates, about the centroid ``c`` of the transformed
points for conditioning): ``T <- T_c exp(dxi) T_c^-1 T`` with ``dxi = (omega, v)``. For a transformed
point ``q = T p`` and ``p' = q - c``, ``q(dxi) ~ q + omega x p' + v``, so
``dr/d(dxi) = [(p' x g)^T, g^T]`` with ``g = d sdf / d q`` -- the paper's Jacobian row with ``p``
taken relative to the centroid (centring changes nothing but the conditioning of the 6x6 system
and makes the degeneracy test meaningful). Step: ``dxi = -(J^T W J + lambda I)^-1 J^T W r``.

With ``up`` (a ground robot on a flat floor) the steps are restricted to the plane: rotations
about ``up`` and translations across it, ``dxi = B x`` with ``x`` in R^3 and ``B`` the (6, 3)
basis of :func:`planar_basis`; the degeneracy test and the covariance are then those of ``x``
(the covariance ``B cov_x B^T``, rank 3).

The reported covariance is in gtsam's convention: right perturbation in the camera (body) frame,
``T_map_cam exp(delta)``, ``delta = (omega, v)``, rotation first.

The SDF is any callable ``sdf_and_grad(points_map) -> (sdf (N,), grad (N, 3)[, valid (N,)])``
taking numpy float32 (or torch float32 with ``points_as="torch"``) and returning numpy or torch;
without a ``valid`` output, non-finite values mark invalid points.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.bounds import finite_rows
from simn_sim.geometry.se3 import inv_T, se3_exp
from simn_sim.tracking.lie import adjoint, check_pose

SdfAndGrad = Callable[[Any], tuple]


@dataclasses.dataclass(frozen=True)
class RegistrationConfig(Config):
    """LM registration settings (lengths in metres)."""

    max_iters: int = 30
    lambda_reg: float = 1e-3  # initial and minimum LM damping (paper: 1e-3)
    lambda_up: float = 10.0  # damping factor after a rejected step
    max_rejects: int = 3  # rejected steps (damping x lambda_up each) before declaring a minimum
    gm_scale: float = 0.02  # Geman-McClure scale floor c (m); tuned, see docs/tracking.md
    gm_mad_factor: float = 5.0  # adaptive scale c = max(gm_scale, factor * 1.4826 * MAD)
    tol_rot: float = 1e-4  # convergence: step rotation (rad)
    tol_trans: float = 1e-4  # convergence: step translation (m)
    grad_norm_min: float = 0.5  # valid SDF gradient norm range (true SDF: 1)
    grad_norm_max: float = 1.5
    min_valid_points: int = 100
    min_valid_fraction: float = 0.3
    max_final_rms: float = 0.03  # RMS over inliers (|r| < 3 c) must end below this (m)
    inlier_threshold: float = 0.02  # fixed |r| bound (m) for the reported inlier_fraction
    min_inlier_fraction: float = 0.5
    max_rms_growth: float = 1.5  # final inlier RMS / initial must stay below this
    degeneracy_ratio: float = 1e-3  # min/max eigenvalue of J^T W J must exceed this
    fail_covariance: float = 1e6  # diagonal of the covariance reported on failure

    def validate(self) -> None:
        n = type(self).__name__
        require(self.max_iters >= 1, n, "max_iters", "must be >= 1")
        require(self.lambda_reg > 0, n, "lambda_reg", "must be > 0")
        require(self.lambda_up > 1, n, "lambda_up", "must be > 1")
        require(self.max_rejects >= 1, n, "max_rejects", "must be >= 1")
        require(self.gm_scale > 0, n, "gm_scale", "must be > 0")
        require(self.gm_mad_factor >= 0, n, "gm_mad_factor", "must be >= 0")
        require(self.tol_rot > 0 and self.tol_trans > 0, n, "tol_rot", "tolerances must be > 0")
        require(
            0 < self.grad_norm_min < 1 < self.grad_norm_max,
            n,
            "grad_norm_min",
            "need 0 < grad_norm_min < 1 < grad_norm_max",
        )
        require(self.min_valid_points >= 6, n, "min_valid_points", "must be >= 6")
        require(0 <= self.min_valid_fraction <= 1, n, "min_valid_fraction", "must be in [0, 1]")
        require(0 <= self.min_inlier_fraction <= 1, n, "min_inlier_fraction", "must be in [0, 1]")
        require(self.max_final_rms > 0, n, "max_final_rms", "must be > 0")
        require(self.inlier_threshold > 0, n, "inlier_threshold", "must be > 0")
        require(self.max_rms_growth >= 1, n, "max_rms_growth", "must be >= 1")
        require(0 < self.degeneracy_ratio < 1, n, "degeneracy_ratio", "must be in (0, 1)")
        require(self.fail_covariance > 0, n, "fail_covariance", "must be > 0")


@dataclasses.dataclass(frozen=True)
class RegistrationResult:
    """Outcome of :func:`register`.

    pose: T_map_cam (4, 4) float64 -- the estimate, or the prior when ``success`` is False.
    covariance: (6, 6), right perturbation in the camera frame, (omega, v) order.
    """

    pose: np.ndarray
    covariance: np.ndarray
    iterations: int
    n_valid: int
    n_inliers: int
    final_rms: float  # RMS SDF residual (m) over inliers at the returned estimate
    initial_rms: float
    success: bool
    reason: str  # "ok" or why it failed
    converged: bool  # the last step was below the tolerances
    eig_ratio: float  # min/max eigenvalue of J^T W J (centred); small = degenerate
    seconds: float
    inlier_fraction: float = 0.0  # of ALL input points: valid and |r| < cfg.inlier_threshold


def _to_numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def check_points(points: Any, name: str = "points_cam") -> np.ndarray:
    """Validate (N, 3) float32/float64 finite non-empty points; return float64 numpy."""
    if hasattr(points, "detach"):
        points = points.detach().cpu().numpy()
    if not isinstance(points, np.ndarray):
        raise ValueError(f"{name} must be a numpy array or torch tensor, got {type(points)}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    if points.dtype not in (np.float32, np.float64):
        raise ValueError(f"{name} must be float32 or float64, got {points.dtype}")
    if points.shape[0] == 0:
        raise ValueError(f"{name} is empty")
    if not np.isfinite(points).all():
        raise ValueError(f"{name} contains NaN or inf")
    return points.astype(np.float64)


class _Evaluator:
    """Evaluates residuals, Jacobians and validity of the points under a pose."""

    def __init__(
        self,
        P: np.ndarray,
        fn: SdfAndGrad,
        cfg: RegistrationConfig,
        as_torch: bool,
        weights: np.ndarray | None = None,
    ):
        self.P, self.fn, self.cfg, self.as_torch = P, fn, cfg, as_torch
        self.pw = np.ones(len(P)) if weights is None else weights

    def __call__(self, T: np.ndarray) -> dict[str, np.ndarray]:
        q = self.P @ T[:3, :3].T + T[:3, 3]
        q32 = q.astype(np.float32)
        if self.as_torch:
            import torch

            q32 = torch.from_numpy(q32)
        out = self.fn(q32)
        if not isinstance(out, tuple | list) or len(out) not in (2, 3):
            raise ValueError("sdf_and_grad must return (sdf, grad) or (sdf, grad, valid)")
        sdf = _to_numpy(out[0]).astype(np.float64).reshape(-1)
        grad = _to_numpy(out[1]).astype(np.float64).reshape(-1, 3)
        n = len(q)
        if sdf.shape[0] != n or grad.shape[0] != n:
            raise ValueError(f"sdf_and_grad returned {sdf.shape[0]} values for {n} points")
        valid = np.isfinite(sdf) & finite_rows(grad)
        if len(out) == 3:
            valid &= _to_numpy(out[2]).astype(bool).reshape(-1)
        gn = np.linalg.norm(np.where(valid[:, None], grad, 0.0), axis=1)
        valid &= (gn >= self.cfg.grad_norm_min) & (gn <= self.cfg.grad_norm_max)
        return {"q": q, "r": np.where(valid, sdf, 0.0), "g": grad, "valid": valid, "pw": self.pw}


def _gm_weights(r: np.ndarray, c: float) -> np.ndarray:
    """IRLS weights of Geman-McClure rho(r) = r^2 c^2 / (2 (c^2 + r^2)): (c^2/(c^2+r^2))^2."""
    return (c * c / (c * c + r * r)) ** 2


def _gm_cost(ev: dict, c: float) -> float:
    """Robust cost, each point times its prior weight; an invalid point counts as a saturated
    outlier (c^2 / 2)."""
    r = ev["r"]
    rho = 0.5 * r * r * c * c / (c * c + r * r)
    return float((ev["pw"] * np.where(ev["valid"], rho, 0.5 * c * c)).sum())


def _scale(r: np.ndarray, valid: np.ndarray, cfg: RegistrationConfig) -> float:
    rv = np.abs(r[valid])
    if rv.size == 0:
        return cfg.gm_scale
    mad = float(np.median(rv))
    return max(cfg.gm_scale, cfg.gm_mad_factor * 1.4826 * mad)


def _normal_equations(ev: dict, c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Centred J^T W J, J^T W r, the centroid, and sum w r^2 over valid points."""
    v = ev["valid"]
    q, r, g = ev["q"][v], ev["r"][v], ev["g"][v]
    cen = q.mean(axis=0)
    J = np.concatenate([np.cross(q - cen, g), g], axis=1)
    w = _gm_weights(r, c) * ev["pw"][v]
    Jw = J * w[:, None]
    return Jw.T @ J, Jw.T @ r, cen, float((w * r * r).sum())


def _inlier_rms(ev: dict, c: float) -> tuple[float, int]:
    r = ev["r"][ev["valid"]]
    inl = np.abs(r) < 3.0 * c
    if not inl.any():
        return float("inf"), 0
    return float(np.sqrt(np.mean(r[inl] ** 2))), int(inl.sum())


def planar_basis(up: Any) -> np.ndarray:
    """(6, 3) basis of the planar twists ``(omega, v)`` for the unit normal ``up`` of the plane:
    the rotation about ``up``, then two translations across it. ValueError for a bad ``up``."""
    n = np.asarray(up, dtype=np.float64)
    if n.shape != (3,) or not np.isfinite(n).all() or abs(np.linalg.norm(n) - 1.0) > 1e-6:
        raise ValueError(f"up must be a finite unit 3-vector, got {up!r}")
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    B = np.zeros((6, 3))
    B[:3, 0] = n
    B[3:, 1] = e1
    B[3:, 2] = np.cross(n, e1)
    return B


def register(
    points_cam: Any,
    sdf_and_grad: SdfAndGrad,
    T_init: np.ndarray,
    cfg: RegistrationConfig | None = None,
    *,
    points_as: Literal["numpy", "torch"] = "numpy",
    weights: Any = None,
    up: Any = None,
) -> RegistrationResult:
    """Register (N, 3) camera-frame points to the zero level set of ``sdf_and_grad``.

    T_init: (4, 4) initial ``T_map_cam`` (e.g. :func:`~simn_sim.tracking.lie.constant_velocity_prior`).
    ``weights``: optional (N,) prior weights >= 0 (e.g. the inverse variance of each point's
    depth noise relative to the best point), multiplied into the Geman-McClure IRLS weights.
    ``up``: optional unit normal of the floor plane in map coordinates; the pose then moves only
    on the plane (rotation about ``up``, translation across it; see the module docstring).
    Never raises for poor convergence: on failure it returns ``T_init`` with ``success=False``
    and a ``reason``. Raises ``ValueError`` only for bad input (shape, dtype, NaN, empty).
    """
    cfg = cfg or RegistrationConfig()
    t0 = time.perf_counter()
    P = check_points(points_cam)
    T0 = check_pose(T_init, "T_init")
    W = None
    if weights is not None:
        W = np.asarray(_to_numpy(weights), np.float64)
        if W.shape != (len(P),):
            raise ValueError(f"weights must have shape ({len(P)},), got {W.shape}")
        if not np.isfinite(W).all():
            raise ValueError("weights contain NaN or inf")
        if (W < 0).any():
            raise ValueError(f"weights must be >= 0, got a minimum of {W.min():g}")
        if not (W > 0).any():
            raise ValueError("weights are all zero")
    B = None if up is None else planar_basis(up)
    dof = 6 if B is None else 3
    ev_fn = _Evaluator(P, sdf_and_grad, cfg, points_as == "torch", W)
    fail_cov = np.eye(6) * cfg.fail_covariance

    def fail(reason: str, it: int, ev: dict | None, rms0: float, ratio: float = float("nan")):
        nv = int(ev["valid"].sum()) if ev is not None else 0
        return RegistrationResult(
            T0,
            fail_cov,
            it,
            nv,
            0,
            float("nan"),
            rms0,
            False,
            reason,
            False,
            ratio,
            time.perf_counter() - t0,
        )

    n = len(P)
    min_valid = max(cfg.min_valid_points, int(np.ceil(cfg.min_valid_fraction * n)))
    ev = ev_fn(T0)
    c = _scale(ev["r"], ev["valid"], cfg)
    rms0, _ = _inlier_rms(ev, c)
    if int(ev["valid"].sum()) < min_valid:
        return fail(
            f"too few valid points at the prior ({int(ev['valid'].sum())} < {min_valid})",
            0,
            ev,
            rms0,
        )
    T = T0.copy()
    lam = cfg.lambda_reg
    converged = False
    it = 0
    while it < cfg.max_iters and not converged:
        it += 1
        c = _scale(ev["r"], ev["valid"], cfg)
        H, b, cen, _ = _normal_equations(ev, c)
        cost = _gm_cost(ev, c)
        accepted = False
        for _ in range(cfg.max_rejects):
            try:
                if B is None:
                    dxi = -np.linalg.solve(H + lam * np.eye(6), b)
                else:
                    dxi = -B @ np.linalg.solve(B.T @ H @ B + lam * np.eye(3), B.T @ b)
            except np.linalg.LinAlgError:
                lam *= cfg.lambda_up
                continue
            # a step below the tolerances is not worth an SDF evaluation: converged
            # (the rotation is about the points' centroid, so |v| is the centroid's motion)
            if np.linalg.norm(dxi[:3]) < cfg.tol_rot and np.linalg.norm(dxi[3:]) < cfg.tol_trans:
                converged = True
                break
            Tc = np.eye(4)
            Tc[:3, 3] = cen
            T_new = Tc @ se3_exp(dxi) @ inv_T(Tc) @ T
            ev_new = ev_fn(T_new)
            if _gm_cost(ev_new, c) <= cost:
                T, ev = T_new, ev_new
                lam = max(cfg.lambda_reg, lam / cfg.lambda_up)
                accepted = True
                break
            lam *= cfg.lambda_up
        if not accepted and not converged:
            converged = True  # no step decreases the cost: at a (local) minimum
            break

    nv = int(ev["valid"].sum())
    if nv < min_valid:
        return fail(f"too few valid points ({nv} < {min_valid})", it, ev, rms0)
    c = _scale(ev["r"], ev["valid"], cfg)
    H, _, cen, wrr = _normal_equations(ev, c)
    rms, n_inl = _inlier_rms(ev, c)
    if not np.isfinite(H).all():
        return fail("non-finite normal equations", it, ev, rms0)
    Hx = H if B is None else B.T @ H @ B
    eig = np.linalg.eigvalsh(Hx)
    ratio = float(eig[0] / eig[-1]) if eig[-1] > 0 else 0.0
    if ratio < cfg.degeneracy_ratio:
        return fail(f"degenerate geometry (eigenvalue ratio {ratio:.2e})", it, ev, rms0, ratio)
    if n_inl < cfg.min_inlier_fraction * nv:
        return fail(f"too few inliers ({n_inl} of {nv})", it, ev, rms0, ratio)
    if not np.isfinite(rms) or rms > cfg.max_final_rms:
        return fail(f"residual too large (RMS {rms:.4f} m)", it, ev, rms0, ratio)
    if rms > cfg.max_rms_growth * rms0 and rms > cfg.gm_scale:
        return fail(f"residual blew up (RMS {rms0:.4f} -> {rms:.4f} m)", it, ev, rms0, ratio)

    sigma2 = wrr / max(nv - dof, 1)
    cov_c = sigma2 * (np.linalg.inv(H) if B is None else B @ np.linalg.inv(Hx) @ B.T)
    Tc = np.eye(4)
    Tc[:3, 3] = cen
    A_inv = inv_T(inv_T(Tc) @ T)
    Ad = adjoint(A_inv)
    cov = Ad @ cov_c @ Ad.T
    cov = 0.5 * (cov + cov.T)
    frac = float(np.count_nonzero(ev["valid"] & (np.abs(ev["r"]) < cfg.inlier_threshold)) / n)
    return RegistrationResult(
        T,
        cov,
        it,
        nv,
        n_inl,
        rms,
        rms0,
        True,
        "ok",
        converged,
        ratio,
        time.perf_counter() - t0,
        frac,
    )
