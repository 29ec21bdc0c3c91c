"""Tracking: register a frame's points against the current local frame's map.

:class:`Tracker` predicts the camera pose in the current frame's anchor coordinates (the
increment of the caller's prior, wheel odometry, or constant velocity without one), registers
the frame's sub-sampled points by Levenberg-Marquardt on the frame map's SDF
(:func:`~simn_sim.tracking.registration.register`) and fuses the result with the prediction
through its covariance. A failed registration, or one that moves the prediction beyond the
budget, keeps the prediction and says why (:class:`TrackResult`); nothing raises for bad
tracking, and every such fallback is counted by the caller.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Any

import numpy as np

from simn_sim.geometry.se3 import inv_T, orthonormalize, pose_error, se3_exp
from simn_sim.geometry.voxel import voxel_mean
from simn_sim.mapping.sdf_cache import SdfCache
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.tracking.lie import adjoint, constant_velocity_prior, se3_log
from simn_sim.tracking.pointsdf import PointCloudSDF
from simn_sim.tracking.registration import register


@dataclasses.dataclass
class TrackResult:
    """T_anchor_cam: (4, 4) pose in the current frame's anchor coordinates; success / reason /
    iterations: the registration's outcome; against: the local frame registered to (None: no
    map); rms: its final inlier RMS (m)."""

    T_anchor_cam: np.ndarray
    success: bool
    reason: str
    iterations: int
    against: int | None
    rms: float


def _info(sigma_rot: float, sigma_trans: float) -> np.ndarray:
    """(6, 6) diagonal information of a pose increment, (omega, v) order: rad and m sigmas."""
    return np.diag([1 / sigma_rot**2] * 3 + [1 / sigma_trans**2] * 3)


def depth_noise_weights(z: np.ndarray, sigma0: float, per_m2: float) -> np.ndarray:
    """Registration weights of points at depths ``z`` (m): the inverse variance of
    sigma(z) = ``sigma0`` + ``per_m2`` z^2 (stereo depth error grows with z^2; ``sigma0`` the
    error floor of the map and the near range) relative to a point at zero depth, in (0, 1]."""
    if sigma0 <= 0 or per_m2 < 0:
        raise ValueError(f"need sigma0 > 0 and per_m2 >= 0, got {sigma0}, {per_m2}")
    z = np.asarray(z, np.float64)
    return (sigma0 / (sigma0 + per_m2 * z**2)) ** 2


class Tracker:
    """Pose prediction and frame-to-local-frame registration (see the module docstring)."""

    def __init__(
        self,
        cfg: SlamConfig,
        frames: LocalFrames,
        rng: np.random.Generator,
        T_base_cam: np.ndarray | None = None,
    ) -> None:
        self.cfg = cfg
        self.frames = frames
        self.rng = rng
        self.reg_cfg = cfg.track_registration
        # a tracking registration is fused as weakly constrained below the strict (revisit)
        # registration's degeneracy ratio; it fails only below the tracking one
        self.weak_eig_ratio = cfg.registration.degeneracy_ratio
        self._cv_info = _info(np.radians(cfg.prior_sigma_rot_deg), cfg.prior_sigma_trans)
        self._odom_info = _info(
            np.radians(cfg.odom_prior_sigma_rot_deg), cfg.odom_prior_sigma_trans
        )
        self.hist: list[tuple[float, np.ndarray]] = []  # (t, T_anchor_cam) of the last two
        self.last_prior: np.ndarray | None = None
        # odometry window (odom_window): per committed frame, the tracked and the odometry
        # increment (4, 4) and the odometry increment's rotation and translation variances
        self._window: collections.deque = collections.deque(maxlen=max(cfg.odom_window - 1, 0))
        self._window_reset = False  # this frame fell back to the odometry: restart the window
        self.window_sigmas = float("nan")  # the last frame's window statistic (diagnostics)
        self._rms_ema: float | None = None  # running inlier RMS of the registrations
        # SDF caches of the learned maps tracked against (implicit_cache_voxel), per frame id
        self.caches: dict[int, SdfCache] = {}
        # planar_registration: tracking moves the base only on its plane. The floor's normal in
        # any (planar) camera frame, the map's anchor included, and the planar base twists
        # (yaw rate, v_x, v_y) as camera-frame right twists
        self.up_cam: np.ndarray | None = None
        self.B_cam: np.ndarray | None = None
        self._B_cam_pinv: np.ndarray | None = None  # its left inverse, for the fusion
        if cfg.planar and cfg.planar_registration:
            if T_base_cam is None:
                raise ValueError("planar_registration needs T_base_cam (the camera on the base)")
            self.up_cam = np.asarray(T_base_cam, float)[2, :3].copy()
            self.B_cam = adjoint(inv_T(np.asarray(T_base_cam, float)))[:, [2, 3, 4]]
            self._B_cam_pinv = np.linalg.pinv(self.B_cam)

    # ---- points ------------------------------------------------------------------------------
    def track_points(self, pts: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
        """Registration points: up to ``track_max_depth``, one per ``track_voxel`` voxel, at most
        ``max_track_points``: a random subset from the tracker's generator, or with
        ``track_point_selection: normals`` (and ``normals``, camera frame, NaN: unknown) spread
        evenly over the directions of the voxels' mean normals (normal-space sampling: the few
        points facing along a corridor are kept, which constrain motion along it)."""
        keep = pts[:, 2] <= self.cfg.track_max_depth
        pts = pts[keep]
        if len(pts) == 0:
            return pts
        m = self.cfg.max_track_points
        if self.cfg.track_point_selection == "normals" and normals is not None:
            nrm = np.nan_to_num(normals[keep].astype(np.float32), nan=0.0)
            tp, nv, _ = voxel_mean(pts, self.cfg.track_voxel, nrm)
            if len(tp) > m:
                tp = tp[self._normal_space(nv, m)]
            return tp.astype(np.float32)
        tp, _, _ = voxel_mean(pts, self.cfg.track_voxel)
        if len(tp) > m:
            tp = tp[self.rng.choice(len(tp), m, replace=False)]
        return tp.astype(np.float32)

    def _normal_space(self, nv: np.ndarray, m: int) -> np.ndarray:
        """Indices of ``m`` of the points with (mean) normals ``nv`` (zero rows: unknown): the
        normals binned on a 5 x 5 x 5 grid of the unit cube (unknown: a bin of their own),
        then round robin over the bins in a random order within each (the tracker's
        generator), so a bin holding fewer than its share keeps all its points."""
        n = np.linalg.norm(nv, axis=1, keepdims=True)
        u = np.where(n > 0.5, nv / np.maximum(n, 1e-9), 0.0)
        cell = np.clip(np.round(u * 2.0).astype(np.int64) + 2, 0, 4)
        b = np.where(n[:, 0] > 0.5, cell[:, 0] * 25 + cell[:, 1] * 5 + cell[:, 2], 125)
        perm = self.rng.permutation(len(b))
        bp = b[perm]
        order = np.argsort(bp, kind="stable")  # points of each bin, in the random order
        sb = bp[order]
        start = np.searchsorted(sb, sb, side="left")
        rank = np.empty(len(b), np.int64)
        rank[order] = np.arange(len(b)) - start  # rank within its bin
        pick = np.argsort(rank, kind="stable")[:m]  # round robin over the bins
        return np.sort(perm[pick])

    def point_weights(self, pts: np.ndarray) -> np.ndarray | None:
        """Inverse depth-noise variance of each point relative to a point at zero range,
        sigma(z) = depth_sigma0 + depth_sigma_per_m2 z^2; None when ``depth_sigma_per_m2`` is 0."""
        k = self.cfg.depth_sigma_per_m2
        if k <= 0:
            return None
        return depth_noise_weights(pts[:, 2], self.cfg.depth_sigma0, k)

    # ---- the SDF registered against ----------------------------------------------------------
    @property
    def kernel(self) -> float:
        """Kernel width (m) of the tracking point SDF: ``point_sdf_kernel_rms_factor`` times the
        running inlier RMS, clipped to [``point_sdf_kernel_min``, ``point_sdf_kernel``]."""
        c = self.cfg
        if c.point_sdf_kernel <= 0:
            return 0.0
        if c.point_sdf_kernel_rms_factor <= 0 or self._rms_ema is None:
            return c.point_sdf_kernel
        h = c.point_sdf_kernel_rms_factor * self._rms_ema
        return float(np.clip(h, c.point_sdf_kernel_min, c.point_sdf_kernel))

    def update_rms(self, rms: float) -> None:
        if np.isfinite(rms):
            a = 0.3
            self._rms_ema = rms if self._rms_ema is None else (1 - a) * self._rms_ema + a * rms

    def sdf_of(self, fid: int, growth: float | None = None):
        """``sdf_and_grad`` of frame ``fid`` for registration (per ``track_sdf``), or None."""
        st = self.frames.states[fid]
        if self.cfg.track_sdf == "implicit":
            if st.n_trained == 0:
                return None
            c = self.cfg
            if growth is None and c.implicit_cache_voxel > 0:
                return self.cache_of(fid).sdf_and_grad
            dmax = c.implicit_max_dist if growth is None else None  # revisits: the map's own
            return st.frame.map.tracking_sdf(c.implicit_reuse_neighbors, dmax).sdf_and_grad
        g = self.cfg.sdf_rebuild_growth if growth is None else growth
        sdf = st.surface.point_sdf(g)
        if sdf is None:
            return None
        if sdf.kernel > 0:
            sdf.kernel = self.kernel
        return sdf.sdf_and_grad

    def cache_of(self, fid: int) -> SdfCache:
        """The SDF cache of frame ``fid``'s learned map (caches of frames no longer tracked
        against, older than the previous frame, are dropped)."""
        cache = self.caches.get(fid)
        if cache is None:
            c = self.cfg
            cache = SdfCache(
                self.frames.states[fid].frame.map,
                c.implicit_cache_voxel,
                c.implicit_max_dist,
            )
            cur = self.frames.current_id
            self.caches = {f: v for f, v in self.caches.items() if f >= cur - 1}
            self.caches[fid] = cache
        return cache

    def point_sdf(self, P: np.ndarray, N: np.ndarray, max_dist: float) -> PointCloudSDF:
        c = self.cfg
        return PointCloudSDF(
            P,
            N,
            max_dist=max_dist,
            kernel=self.kernel,
            k=c.point_sdf_k,
            normal_gate=float(np.cos(np.radians(c.point_sdf_normal_gate_deg))),
        )

    def _target_frames(self) -> list[int]:
        """The frames tracking may register against, in order: the current one, then the
        previous one (while the current one has no map yet)."""
        cur = self.frames.current_id
        return [cur, cur - 1] if cur > 0 else [cur]

    def has_trained_target(self) -> bool:
        """Whether a frame of :meth:`_target_frames` has a trained learned map to track against
        (always True on the point store)."""
        if self.cfg.track_sdf != "implicit":
            return True
        return any(self.frames.states[f].n_trained > 0 for f in self._target_frames())

    def _target(self) -> tuple[int, Any] | None:
        """(frame id, sdf_and_grad): the current frame's map, or the previous frame's while the
        current one has none yet."""
        for fid in self._target_frames():
            sdf = self.sdf_of(fid)
            if sdf is not None:
                return fid, sdf
        return None

    # ---- prediction and registration ---------------------------------------------------------
    def start(self, t: float) -> None:
        """The first frame: the camera is at the new frame's anchor."""
        self.hist = [(t, np.eye(4))]

    def reanchor(self, T_new_old: np.ndarray) -> None:
        """A new local frame opened: express the history in its anchor coordinates."""
        self.hist = [(t, T_new_old @ T) for t, T in self.hist]

    def commit(self, t: float, T_anchor_cam: np.ndarray, prior: np.ndarray | None) -> None:
        if self.cfg.odom_window > 0:
            if self._window_reset or prior is None or self.last_prior is None or not self.hist:
                self._window.clear()
            else:
                sr, st = self._odom_sigmas(prior)
                inc = inv_T(self.hist[-1][1]) @ T_anchor_cam
                self._window.append((inc, inv_T(self.last_prior) @ prior, sr**2, st**2))
            self._window_reset = False
        self.hist = (self.hist + [(t, T_anchor_cam)])[-2:]
        self.last_prior = prior

    def predict(self, t: float, prior: np.ndarray | None) -> np.ndarray:
        """Predicted ``T_anchor_cam`` in the current frame."""
        T1 = self.hist[-1][1]
        if prior is not None and self.last_prior is not None:
            return T1 @ (inv_T(self.last_prior) @ prior)
        if len(self.hist) < 2:
            return T1.copy()
        (t0, T0), (t1, _) = self.hist[-2], self.hist[-1]
        ratio = (t - t1) / (t1 - t0) if t1 > t0 else 1.0
        return constant_velocity_prior(T0, T1, float(np.clip(ratio, 0.0, 5.0)))

    def odom_info(self, prior: np.ndarray) -> np.ndarray:
        """Information of the odometry increment from the last prior to ``prior``: sigma =
        ``odom_prior_sigma_*`` plus ``odom_prior_sigma_rot_per_unit`` x (turn in rad + travel
        in m) for rotations and ``odom_prior_sigma_trans_per_m`` x travel for translations (the
        wheel-odometry drift model of :func:`simn_sim.env.noise.odometry_step`); without the
        per-unit terms the constant information."""
        c = self.cfg
        if c.odom_prior_sigma_rot_per_unit == 0 and c.odom_prior_sigma_trans_per_m == 0:
            return self._odom_info
        return _info(*self._odom_sigmas(prior))

    def _odom_sigmas(self, prior: np.ndarray) -> tuple[float, float]:
        """(rotation rad, translation m) sigmas of the odometry increment to ``prior``."""
        c = self.cfg
        dist, ang = pose_error(self.last_prior, prior)
        sr = np.radians(c.odom_prior_sigma_rot_deg) + c.odom_prior_sigma_rot_per_unit * (ang + dist)
        return float(sr), float(c.odom_prior_sigma_trans + c.odom_prior_sigma_trans_per_m * dist)

    def _check_window(self, res: TrackResult, prior: np.ndarray) -> TrackResult:
        """The odometry window test (``odom_window``): the tracked motion from the window's
        start to ``res`` against the odometry's, in sigmas of the odometry increments' summed
        variances (largest of rotation and translation, as :attr:`window_sigmas`). Beyond
        ``odom_window_sigmas``: the pose from the window's start moved by the odometry, a
        failed result, and the window restarts there."""
        T_prev = self.hist[-1][1]
        E, D = np.eye(4), np.eye(4)  # tracked and odometry motion over the previous frames
        var_r = var_t = 0.0
        for inc, odo, vr, vt in self._window:
            E, D = E @ inc, D @ odo
            var_r, var_t = var_r + vr, var_t + vt
        sr, st = self._odom_sigmas(prior)
        odom_rel = D @ (inv_T(self.last_prior) @ prior)
        est_rel = E @ (inv_T(T_prev) @ res.T_anchor_cam)
        d = se3_log(inv_T(odom_rel) @ est_rel)
        m = max(
            float(np.linalg.norm(d[:3])) / np.sqrt(var_r + sr**2),
            float(np.linalg.norm(d[3:])) / np.sqrt(var_t + st**2),
        )
        self.window_sigmas = m
        if m <= self.cfg.odom_window_sigmas:
            return res
        self._window_reset = True
        T_fb = orthonormalize(T_prev @ inv_T(E) @ odom_rel)
        why = (
            f"tracked motion {m:.1f} sigma off the odometry over {len(self._window) + 1} frames"
            f" (window gate {self.cfg.odom_window_sigmas:g})"
        )
        return TrackResult(T_fb, False, why, res.iterations, res.against, res.rms)

    def track(self, pts: np.ndarray, T_pred: np.ndarray, prior: np.ndarray | None) -> TrackResult:
        """Register ``pts`` starting from ``T_pred`` (anchor coordinates)."""
        use_odom = prior is not None and self.last_prior is not None
        res = self._register(pts, T_pred, self.odom_info(prior) if use_odom else self._cv_info)
        if res.success:
            self.update_rms(res.rms)
        res.T_anchor_cam = orthonormalize(res.T_anchor_cam)
        self.window_sigmas = float("nan")
        if use_odom and self.cfg.odom_window > 0:
            res = self._check_window(res, prior)
        return res

    def register_c2f(self, pts: np.ndarray, sdf, T_init: np.ndarray, reg_cfg, up=None):
        """Register (on the plane with normal ``up``, map coordinates, when given); on a kernel
        point SDF (with ``c2f``) coarse to fine: first with the widest kernel, then from there
        with the noise-adaptive width (:attr:`kernel`)."""
        w = self.point_weights(pts)
        obj = getattr(sdf, "__self__", None)
        fine = self.kernel
        if not isinstance(obj, PointCloudSDF) or obj.kernel <= 0 or not self.cfg.c2f:
            return register(pts, sdf, T_init, reg_cfg, weights=w, up=up)
        obj.kernel = self.cfg.point_sdf_kernel
        res = register(pts, sdf, T_init, reg_cfg, weights=w, up=up)
        if not res.success or fine >= obj.kernel:
            return res
        obj.kernel = fine
        res2 = register(pts, sdf, res.pose, reg_cfg, weights=w, up=up)
        return res2 if res2.success else res

    def _register(self, pts: np.ndarray, T_pred: np.ndarray, prior_info: np.ndarray) -> TrackResult:
        """Register against the tracking target; the prediction on any failure."""
        if len(pts) < self.reg_cfg.min_valid_points:
            return TrackResult(T_pred, False, f"only {len(pts)} valid points", 0, None, np.nan)
        target = self._target()
        if target is None:
            return TrackResult(T_pred, False, "no trained map yet", 0, None, np.nan)
        fid, sdf = target
        topo = self.frames.topo
        T_cur_f = inv_T(topo.anchor(self.frames.current_id)) @ topo.anchor(fid)
        init = inv_T(T_cur_f) @ T_pred
        cache = getattr(sdf, "__self__", None)
        if isinstance(cache, SdfCache):  # bake / refresh where the points are predicted
            cache.prepare(pts.astype(np.float64) @ init[:3, :3].T + init[:3, 3])
        res = self.register_c2f(pts, sdf, init, self.reg_cfg, up=self.up_cam)
        if not res.success:
            return TrackResult(T_pred, False, res.reason, res.iterations, fid, res.final_rms)
        T_est = orthonormalize(T_cur_f @ res.pose)
        reason = "ok"
        if self.cfg.fuse_prior:
            fused = self._fuse(pts, T_pred, T_est, res, prior_info)
            if fused is None:  # the covariance could not be inverted: registration as is
                pass
            elif isinstance(fused, str):
                return TrackResult(T_pred, False, fused, res.iterations, fid, res.final_rms)
            else:
                T_est = fused
            if res.eig_ratio < self.weak_eig_ratio:
                reason = f"ok (weakly constrained, eigenvalue ratio {res.eig_ratio:.1e})"
        dt, dr = pose_error(T_pred, T_est)
        if (
            dt > self.cfg.track_max_correction_m
            or np.degrees(dr) > self.cfg.track_max_correction_deg
        ):
            why = f"correction {dt:.3f} m / {np.degrees(dr):.1f} deg beyond the budget"
            return TrackResult(T_pred, False, why, res.iterations, fid, res.final_rms)
        return TrackResult(T_est, True, reason, res.iterations, fid, res.final_rms)

    def _fuse(self, pts, T_pred, T_est, res, prior_info) -> np.ndarray | str | None:
        """Bayesian fusion in the camera-frame tangent at the prediction: the registration
        decides the well-constrained directions, the prediction the degenerate ones. Returns the
        fused pose, a reason string when the innovation gate rejects it, or None when the
        registration's covariance is singular (``LinAlgError``: the registration is kept).
        With ``planar_registration`` in the planar twists' coordinates (``B_cam``): both poses
        are on the plane, and so is the fused one."""
        delta = se3_log(inv_T(T_pred) @ T_est)
        B = self.B_cam
        try:
            c = self.cfg
            cov = 0.5 * (res.covariance + res.covariance.T)
            if c.track_cov_scale_trans > 0:
                k = np.sqrt([c.track_cov_scale] * 3 + [c.track_cov_scale_trans] * 3)
                cov = cov * np.outer(k, k)
            else:
                cov = cov * c.track_cov_scale
            if B is not None:  # (rank 3 in the planar twists): their coordinates
                Bp = self._B_cam_pinv
                cov, delta, prior_info = Bp @ cov @ Bp.T, Bp @ delta, B.T @ prior_info @ B
            info = np.linalg.inv(cov)
            if res.eig_ratio < self.weak_eig_ratio:
                # weakly constrained: directions whose information is below ``weak_ratio`` of
                # the largest carry the bias of the model's edges rather than information; drop
                # them, the prior decides there. Rotations are scaled by the median depth so
                # both blocks are in metres.
                L = float(np.median(pts[:, 2])) if len(pts) else 1.0
                D = np.diag([L] * 3 + [1.0] * 3) if B is None else np.diag([L, 1.0, 1.0])
                Di = np.linalg.inv(D)
                ev, V = np.linalg.eigh(Di @ (0.5 * (info + info.T)) @ Di)
                ev = np.where(ev >= self.cfg.weak_ratio * ev.max(), ev, 0.0)
                info = D @ ((V * ev) @ V.T) @ D
            fused = np.linalg.solve(info + prior_info, info @ delta)
        except np.linalg.LinAlgError:
            return None
        # innovation gate: a correction many prior sigmas away is a registration that slid (an
        # edge of the model, a weakly constrained view), not the motion the prediction missed
        gate = self.cfg.gate_sigmas
        if gate > 0:
            m = float(np.sqrt(max(fused @ prior_info @ fused, 0.0)))
            if m > gate:
                return f"correction {m:.1f} sigma of the motion prior (gate {gate:g})"
        return orthonormalize(T_pred @ se3_exp(fused if B is None else B @ fused))
