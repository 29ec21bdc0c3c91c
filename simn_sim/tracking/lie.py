"""SE(3) tools the tracker needs beyond :mod:`simn_sim.geometry.se3`.

Twists are ``xi = (omega, v)`` (rotation first), the ordering of
:func:`simn_sim.geometry.se3.se3_exp` and of gtsam's ``Pose3`` tangent space.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from simn_sim.geometry.se3 import inv_T, se3_exp, skew


def so3_log(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (3,) rotation vector (axis * angle, angle in [0, pi])."""
    return Rotation.from_matrix(np.asarray(R, float)).as_rotvec()


def se3_log(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose -> (6,) twist ``(omega, v)`` with ``se3_exp(se3_log(T)) == T``."""
    T = np.asarray(T, float)
    w = so3_log(T[:3, :3])
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-8:
        V_inv = np.eye(3) - 0.5 * K + (K @ K) / 12.0
    else:
        a = 1.0 / th**2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
        V_inv = np.eye(3) - 0.5 * K + a * (K @ K)
    return np.concatenate([w, V_inv @ T[:3, 3]])


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint of a pose for ``(omega, v)`` twists: ``T exp(xi) T^-1 = exp(Ad_T xi)``."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    A[3:, :3] = skew(t) @ R
    return A


def constant_velocity_prior(
    T_prev2: np.ndarray, T_prev1: np.ndarray, dt_ratio: float = 1.0
) -> np.ndarray:
    """Constant-velocity prediction of the next pose ``T_world_cam``.

    The body-frame motion ``D = T_prev2^-1 T_prev1`` of the last step is repeated, scaled by
    ``dt_ratio = (t_next - t_prev1) / (t_prev1 - t_prev2)`` on the twist:
    ``T_next = T_prev1 exp(dt_ratio * log(D))``. With only one pose, pass it twice.
    """
    if not np.isfinite(dt_ratio) or dt_ratio < 0:
        raise ValueError(f"dt_ratio must be finite and >= 0, got {dt_ratio}")
    T_prev2, T_prev1 = np.asarray(T_prev2, float), np.asarray(T_prev1, float)
    for name, T in (("T_prev2", T_prev2), ("T_prev1", T_prev1)):
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"{name} must be a finite 4x4 pose, got shape {T.shape}")
    D = inv_T(T_prev2) @ T_prev1
    if dt_ratio != 1.0:
        D = se3_exp(dt_ratio * se3_log(D))
    return T_prev1 @ D


def check_pose(T: np.ndarray, name: str = "T", tol: float = 1e-5) -> np.ndarray:
    """Validate a 4x4 rigid transform (finite, rotation block orthonormal with det +1 within
    ``tol``, last row exactly ``[0, 0, 0, 1]`` to 1e-9); return it as float64.

    The one pose check of the package. ``T``: anything array-like (a torch tensor is detached
    and copied to the CPU). Raises ValueError naming ``name``.
    """
    if hasattr(T, "detach"):  # a torch tensor, without importing torch here
        T = T.detach().cpu().numpy()
    T = np.asarray(T)
    if T.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 pose of shape (4, 4), got shape {T.shape}")
    if not np.issubdtype(T.dtype, np.floating) and not np.issubdtype(T.dtype, np.integer):
        raise ValueError(f"{name} must be numeric, got dtype {T.dtype}")
    T = T.astype(np.float64)
    if not np.isfinite(T).all():
        raise ValueError(f"{name} contains NaN or inf")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > tol or abs(np.linalg.det(R) - 1.0) > tol:
        raise ValueError(f"{name} is not a rigid transform: its rotation block is not a rotation")
    if np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise ValueError(f"{name} is not a rigid transform: its last row must be [0, 0, 0, 1]")
    return T
