"""SE(3) helpers on 4x4 float64 matrices named ``T_a_b`` (maps points in frame b to frame a)."""

from __future__ import annotations

import numpy as np


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inv_T(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T`` to (N, 3) points; keeps the input dtype."""
    R = T[:3, :3].astype(points.dtype, copy=False)
    t = T[:3, 3].astype(points.dtype, copy=False)
    return points @ R.T + t


def rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def planar_T(x: float, y: float, yaw: float, z: float = 0.0) -> np.ndarray:
    return make_T(rot_z(yaw), np.array([x, y, z]))


def yaw_of(T: np.ndarray) -> float:
    return float(np.arctan2(T[1, 0], T[0, 0]))


def on_plane(
    T_plane: np.ndarray, T_world_cam: np.ndarray, T_base_cam: np.ndarray, dyaw: float = 0.0
) -> np.ndarray:
    """``T_world_cam`` with its base projected onto the plane of ``T_plane`` (the base's z,
    roll and pitch relative to ``T_plane`` set to 0, its x, y and yaw kept) and turned by
    ``dyaw`` rad about the plane's vertical."""
    rel = inv_T(T_plane) @ T_world_cam @ inv_T(T_base_cam)
    return T_plane @ planar_T(rel[0, 3], rel[1, 3], yaw_of(rel) + dyaw) @ T_base_cam


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    K = skew(w)
    if th < 1e-10:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * (K @ K)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Exponential map of a twist ``xi = (omega, v)`` (rotation first) to a 4x4 pose."""
    w, v = np.asarray(xi[:3], float), np.asarray(xi[3:], float)
    th = float(np.linalg.norm(w))
    K = skew(w)
    R = so3_exp(w)
    if th < 1e-10:
        V = np.eye(3) + 0.5 * K
    else:
        V = np.eye(3) + (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * (K @ K)
    return make_T(R, V @ v)


def rotation_angle(R: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix."""
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (rad) difference between two poses."""
    D = inv_T(T_a) @ T_b
    return float(np.linalg.norm(D[:3, 3])), rotation_angle(D[:3, :3])


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """Project the rotation block of ``T`` back onto SO(3) (removes accumulated round-off)."""
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return make_T(R, T[:3, 3])
