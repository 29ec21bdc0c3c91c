"""Geometric traversable-floor / obstacle classifier (no simulator needed).

Points (world or robot-base frame, z up) get a label:

* ``FLOOR`` (1): within ``floor_tol`` of the floor plane and with a normal within
  ``max_floor_normal_deg`` of up -- traversable;
* ``OBSTACLE`` (2): height above the floor in ``(obstacle_min_height, robot_height]``, or a steep
  surface (normal further than ``max_floor_normal_deg`` from up) anywhere from ``-floor_tol`` up to
  ``robot_height`` (the foot of a wall, a steep ramp, a box side at floor level);
* ``OVERHEAD`` (3): above ``robot_height`` -- seen, but not an obstacle for the base (the base
  drives under it); map it to 0 with :func:`base_labels` where only floor/obstacle matter;
* ``UNKNOWN`` (0): non-finite points, points without a normal where one is needed, points more
  than ``floor_tol`` below the floor (holes, noise), and flat points in the band between
  ``floor_tol`` and ``obstacle_min_height`` when that band is non-empty.

The floor is the plane ``n . p = d`` (``n`` unit, pointing up), either given (a known floor height
from the camera-to-base transform: ``floor_height``) or fitted by RANSAC on the lowest
``lowest_fraction`` of the points, constrained to within ``max_floor_tilt_deg`` of up and refined
by least squares on its inliers. Normals come from the organised depth image
(:func:`normals_from_organized`, central differences) or local PCA over ``normal_k`` neighbours
(:func:`estimate_normals`). A gentle ramp is therefore floor where it is within ``floor_tol`` of
the floor and an obstacle above that: the classifier does not reason about climbable slopes.

Stereo depth noise grows with the square of the range, so with the points' ranges (``ranges``)
the floor band widens with range: ``floor_tol + floor_tol_per_m2 * range^2`` replaces
``floor_tol`` (and ``obstacle_min_height`` where it is smaller), the steep-normal rule only holds
where the band is still within ``1.25 floor_tol`` (normals of noisy far floor are noise), and points
beyond ``max_obstacle_range`` are never obstacles (they are UNKNOWN unless floor).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from simn_sim.config import Config, require
from simn_sim.geometry.bounds import finite_rows
from simn_sim.geometry.camera import Intrinsics, backproject
from simn_sim.geometry.se3 import transform_points

UNKNOWN, FLOOR, OBSTACLE, OVERHEAD = 0, 1, 2, 3


@dataclasses.dataclass(frozen=True)
class FloorClassifierConfig(Config):
    floor_tol: float = 0.05  # m, |height| below this can be floor
    max_floor_normal_deg: float = 15.0  # floor normal within this of up
    obstacle_min_height: float = 0.05  # m, h_min
    robot_height: float = 1.2  # m, things above are OVERHEAD, not obstacles
    floor_height: float | None = None  # known floor z (plane z = floor_height); None: RANSAC
    lowest_fraction: float = 0.3  # RANSAC samples from this fraction of lowest points
    ransac_iters: int = 256
    ransac_tol: float = 0.02  # m, inlier distance for the plane fit
    max_floor_tilt_deg: float = 10.0  # fitted plane normal within this of up
    min_floor_inliers: int = 50
    normal_k: int = 12  # neighbours for PCA normals
    max_points_fit: int = 20000  # subsample for RANSAC
    # range-dependent noise (used when classify_points gets the points' ranges)
    floor_tol_per_m2: float = 0.0  # floor band grows by this x range^2 (m per m^2)
    max_obstacle_range: float = float("inf")  # farther points are never obstacles

    def validate(self) -> None:
        n = type(self).__name__
        require(self.floor_tol > 0, n, "floor_tol", "must be > 0")
        require(0 < self.max_floor_normal_deg < 90, n, "max_floor_normal_deg", "in (0, 90)")
        require(self.obstacle_min_height >= self.floor_tol, n, "obstacle_min_height",
                "must be >= floor_tol")  # fmt: skip
        require(self.robot_height > self.obstacle_min_height, n, "robot_height",
                "must be > obstacle_min_height")  # fmt: skip
        require(0 < self.lowest_fraction <= 1, n, "lowest_fraction", "must be in (0, 1]")
        require(self.ransac_iters >= 1, n, "ransac_iters", "must be >= 1")
        require(self.ransac_tol > 0, n, "ransac_tol", "must be > 0")
        require(0 < self.max_floor_tilt_deg < 90, n, "max_floor_tilt_deg", "in (0, 90)")
        require(self.min_floor_inliers >= 3, n, "min_floor_inliers", "must be >= 3")
        require(self.normal_k >= 3, n, "normal_k", "must be >= 3")
        require(self.max_points_fit >= 3, n, "max_points_fit", "must be >= 3")
        require(self.floor_tol_per_m2 >= 0, n, "floor_tol_per_m2", "must be >= 0")
        require(self.max_obstacle_range > 0, n, "max_obstacle_range", "must be > 0")


@dataclasses.dataclass(frozen=True)
class SemanticResult:
    """labels (N,) int8; height (N,) float32 above the floor plane; plane ``n . p = d``."""

    labels: np.ndarray
    height: np.ndarray
    plane_normal: np.ndarray
    plane_offset: float


class FloorNotFoundError(ValueError):
    """No floor plane could be fitted (too few low, level points)."""


def _check_points(points: np.ndarray) -> np.ndarray:
    P = np.asarray(points)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {P.shape}")
    if not np.issubdtype(P.dtype, np.floating):
        raise ValueError(f"points must be floating point, got {P.dtype}")
    return P


def fit_floor_plane(
    points: np.ndarray,
    cfg: FloorClassifierConfig | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, float, int]:
    """RANSAC plane on the lowest points: unit normal (3,) pointing up (+z), offset d, inliers."""
    cfg = cfg or FloorClassifierConfig()
    rng = rng or np.random.default_rng(0)
    P = _check_points(points).astype(np.float64)
    P = P[finite_rows(P)]
    if len(P) < cfg.min_floor_inliers:
        raise FloorNotFoundError(f"only {len(P)} finite points; need {cfg.min_floor_inliers}")
    if len(P) > cfg.max_points_fit:
        P = P[rng.choice(len(P), cfg.max_points_fit, replace=False)]
    low = P[P[:, 2] <= np.quantile(P[:, 2], cfg.lowest_fraction)]
    if len(low) < 3:
        raise FloorNotFoundError("too few low points for a floor fit")
    idx = rng.integers(0, len(low), size=(cfg.ransac_iters, 3))
    a, b, c = low[idx[:, 0]], low[idx[:, 1]], low[idx[:, 2]]
    nrm = np.cross(b - a, c - a)
    nn = np.linalg.norm(nrm, axis=1)
    ok = nn > 1e-9
    nrm = nrm[ok] / nn[ok, None]
    nrm *= np.where(nrm[:, 2] < 0, -1.0, 1.0)[:, None]
    ok_tilt = nrm[:, 2] >= np.cos(np.radians(cfg.max_floor_tilt_deg))
    nrm, a = nrm[ok_tilt], a[ok][ok_tilt]
    if len(nrm) == 0:
        raise FloorNotFoundError("no level plane among the RANSAC hypotheses")
    d = np.sum(nrm * a, axis=1)
    dist = np.abs(low @ nrm.T - d)  # (M, H)
    counts = (dist < cfg.ransac_tol).sum(axis=0)
    best = int(np.argmax(counts))
    inl = low[dist[:, best] < cfg.ransac_tol]
    if len(inl) < cfg.min_floor_inliers:
        raise FloorNotFoundError(
            f"best floor plane has {len(inl)} inliers < {cfg.min_floor_inliers}"
        )
    cen = inl.mean(axis=0)
    _, _, vt = np.linalg.svd(inl - cen, full_matrices=False)
    n = vt[2] * (1.0 if vt[2, 2] >= 0 else -1.0)
    if n[2] < np.cos(np.radians(cfg.max_floor_tilt_deg)):
        n = nrm[best]
    return n, float(n @ cen), int(len(inl))


def estimate_normals(points: np.ndarray, k: int = 12, towards_origin: bool = False) -> np.ndarray:
    """(N, 3) float64 unit normals by local PCA over ``k`` nearest neighbours: the one home of
    PCA normals.

    The sign is arbitrary, or with ``towards_origin`` flipped to face the origin (the camera,
    for camera-frame points). Non-finite points, and all points when fewer than 3 are finite,
    get NaN normals.
    """
    P = _check_points(points).astype(np.float64)
    out = np.full(P.shape, np.nan)
    fin = finite_rows(P)
    Q = P[fin]
    if len(Q) < 3:
        return out
    k = min(k, len(Q))
    _, nb = cKDTree(Q).query(Q, k=k)
    X = Q[nb] - Q[nb].mean(axis=1, keepdims=True)  # (N, k, 3)
    C = np.einsum("nki,nkj->nij", X, X)
    _, V = np.linalg.eigh(C)
    out[fin] = V[:, :, 0]
    if towards_origin:
        out *= np.where((out * P).sum(1) > 0, -1.0, 1.0)[:, None]
    return out


def normals_from_organized(points_hw3: np.ndarray, max_jump: float = 0.05) -> np.ndarray:
    """(H, W, 3) organised points (camera frame, z = depth, 0/NaN invalid) -> (H, W, 3) normals.

    Central differences; NaN where a neighbour is invalid or the depth jumps by more than
    ``max_jump`` times the depth (an occlusion edge). Oriented towards the camera.
    """
    P = np.asarray(points_hw3, dtype=np.float64)
    if P.ndim != 3 or P.shape[2] != 3:
        raise ValueError(f"points_hw3 must be (H, W, 3), got {P.shape}")
    z = P[..., 2]
    valid = finite_rows(P) & (z > 0)
    out = np.full(P.shape, np.nan)
    c = P[1:-1, 1:-1]
    dx = P[1:-1, 2:] - P[1:-1, :-2]
    dy = P[2:, 1:-1] - P[:-2, 1:-1]
    n = np.cross(dx, dy)
    nn = np.linalg.norm(n, axis=2, keepdims=True)
    ok = valid[1:-1, 1:-1] & valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
    zc = np.where(ok, z[1:-1, 1:-1], 1.0)
    jump = np.maximum(np.abs(dx[..., 2]), np.abs(dy[..., 2])) > 2 * max_jump * zc
    ok &= ~jump & (nn[..., 0] > 0)
    n = n / np.where(nn > 0, nn, 1.0)
    n *= np.where(np.sum(n * c, axis=2, keepdims=True) > 0, -1.0, 1.0)
    out[1:-1, 1:-1] = np.where(ok[..., None], n, np.nan)
    return out


def classify_points(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    cfg: FloorClassifierConfig | None = None,
    rng: np.random.Generator | None = None,
    plane: tuple[np.ndarray, float] | None = None,
    ranges: np.ndarray | None = None,
) -> SemanticResult:
    """Label (N, 3) points in a z-up frame (world or base); see the module docstring.

    normals: (N, 3) (any sign) or None for PCA normals. plane: ``(n, d)`` to skip the fit;
    otherwise ``cfg.floor_height`` or RANSAC. ranges: (N,) sensor range of each point (the
    camera-frame depth) for the range-dependent rules, or None. Raises
    :class:`FloorNotFoundError` if no floor.
    """
    cfg = cfg or FloorClassifierConfig()
    P = _check_points(points).astype(np.float64)
    if normals is None:
        N = estimate_normals(P, cfg.normal_k)
    else:
        N = np.asarray(normals, dtype=np.float64)
        if N.shape != P.shape:
            raise ValueError(f"normals shape {N.shape} != points shape {P.shape}")
    if plane is not None:
        n, d = np.asarray(plane[0], dtype=np.float64), float(plane[1])
        n = n / np.linalg.norm(n)
        if n[2] < 0:
            n, d = -n, -d
    elif cfg.floor_height is not None:
        n, d = np.array([0.0, 0.0, 1.0]), float(cfg.floor_height)
    else:
        n, d, _ = fit_floor_plane(P, cfg, rng)
    fin = finite_rows(P)
    h = np.where(fin, P @ n - d, np.nan)
    has_n = finite_rows(N)
    cos_up = np.abs(np.where(has_n[:, None], N, 0.0) @ n)
    level = has_n & (cos_up >= np.cos(np.radians(cfg.max_floor_normal_deg)))
    steep = has_n & ~level
    labels = np.zeros(len(P), np.int8)
    tol: float | np.ndarray = cfg.floor_tol
    h_min: float | np.ndarray = cfg.obstacle_min_height
    in_range: bool | np.ndarray = True
    if ranges is not None:
        r = np.asarray(ranges, dtype=np.float64).reshape(-1)
        if r.shape != (len(P),):
            raise ValueError(f"ranges shape {r.shape} != ({len(P)},)")
        tol = cfg.floor_tol + cfg.floor_tol_per_m2 * r**2
        h_min = np.maximum(cfg.obstacle_min_height, tol)
        in_range = r <= cfg.max_obstacle_range
        steep = steep & (tol <= 1.25 * cfg.floor_tol)
    with np.errstate(invalid="ignore"):
        near = fin & (np.abs(h) < tol)
        body = fin & in_range & (h > h_min) & (h <= cfg.robot_height)
        low_steep = fin & in_range & steep & (h >= -tol) & (h <= cfg.robot_height)
        over = fin & (h > cfg.robot_height)
    labels[near & level] = FLOOR
    labels[body | low_steep] = OBSTACLE
    labels[over] = OVERHEAD
    return SemanticResult(labels, h.astype(np.float32), n, d)


def classify_depth(
    depth: np.ndarray,
    intr: Intrinsics,
    T_world_cam: np.ndarray,
    cfg: FloorClassifierConfig | None = None,
    rng: np.random.Generator | None = None,
    plane: tuple[np.ndarray, float] | None = None,
) -> tuple[np.ndarray, SemanticResult]:
    """Label an organised depth image: (H, W) int8 labels (0 where depth is invalid) and the
    per-valid-pixel :class:`SemanticResult` (normals from the image, frame = ``T_world_cam``'s)."""
    Pc = backproject(np.asarray(depth, dtype=np.float32), intr)
    Nc = normals_from_organized(Pc)
    valid = finite_rows(Pc) & (Pc[..., 2] > 0)
    T = np.asarray(T_world_cam, dtype=np.float64)
    Pw = transform_points(T, Pc[valid].astype(np.float64))
    Nw = Nc[valid] @ T[:3, :3].T
    res = classify_points(Pw, Nw, cfg, rng, plane)
    img = np.zeros(depth.shape, np.int8)
    img[valid] = res.labels
    return img, res


def base_labels(labels: np.ndarray) -> np.ndarray:
    """Labels for the base: OVERHEAD -> UNKNOWN (0); FLOOR and OBSTACLE kept."""
    out = np.asarray(labels).copy()
    out[out == OVERHEAD] = UNKNOWN
    return out


def precision_recall(
    pred_labels: np.ndarray, true_labels: np.ndarray, cls: int
) -> tuple[float, float]:
    """Precision and recall of class ``cls`` (NaN when undefined: no predictions / no truth)."""
    p = np.asarray(pred_labels).reshape(-1)
    t = np.asarray(true_labels).reshape(-1)
    if p.shape != t.shape:
        raise ValueError(f"pred {p.shape} and true {t.shape} labels differ in size")
    tp = int(np.count_nonzero((p == cls) & (t == cls)))
    n_pred = int(np.count_nonzero(p == cls))
    n_true = int(np.count_nonzero(t == cls))
    prec = tp / n_pred if n_pred else float("nan")
    rec = tp / n_true if n_true else float("nan")
    return prec, rec
