"""SIMN front-end: RGB-D frames -> tracked camera poses, spatial-implicit local frames,
topological map with revisits, and classified floor / obstacle points for the planner.

Per frame (:meth:`SimnSlam.process`):

1. perception: strided back-projection (OpenCV camera frame), organised-image normals;
   registration points on a ``track_voxel`` (6 cm) grid, at most ``max_track_points``;
2. prediction: the increment of the caller's prior (wheel odometry) applied to the previous
   estimate, or constant velocity without one;
3. tracking: Levenberg-Marquardt registration (:func:`~simn_sim.tracking.registration.register`)
   of the frame against the current local frame's map (its learned SDF); while a freshly opened
   frame's map is untrained, against the previous frame's map. A failed registration (or one
   that moves the prediction beyond ``max_correction_*``) falls back to the prediction and says
   so in :class:`SlamFrame`; nothing raises for bad tracking;
4. local frames: :class:`~simn_sim.tracking.localframes.FrameTrigger` (travel or rotation); on
   closing, the map is consolidated (EWC snapshot) and its topological node refreshed; the new
   frame is anchored at the current pose with an odometry arc, and a revisit check
   (:func:`~simn_sim.tracking.topomap.close_loop`: descriptor candidates -> registration ->
   inlier test -> gtsam) may move all anchors (``anchors_version`` increments);
5. semantics: with ``T_base_cam`` the floor is the base plane ``z = 0`` of the estimated base
   pose (no RANSAC); labels per point (0 unknown, 1 floor, 2 obstacle, 3 overhead);
6. mapping: the frame's points (anchor coordinates, with colours and labels) go into the local
   frame's :class:`~simn_sim.mapping.mapper.ImplicitMap`; training on the frame's first
   observation and then every ``train_every``-th frame;
7. obstacle / floor stores: per local frame voxel sets in anchor coordinates; stored obstacle
   points of the recent frames that the current depth image sees *through* are removed
   (free-space carving), so a person who walked away does not stay an obstacle.

Frames: ``T_world_cam`` maps OpenCV camera points to the SLAM world. The world is the prior's
frame when the first call has a prior; else, with ``T_base_cam``, the first base pose is the
world origin (z up); else the first camera pose is the identity.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import cv2
import numpy as np
import torch

from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import inv_T, orthonormalize, pose_error, se3_exp, transform_points
from simn_sim.mapping.mapper import ImplicitMap
from simn_sim.mapping.perception import voxel_downsample
from simn_sim.semantics import FLOOR, OBSTACLE, classify_points, normals_from_organized
from simn_sim.slam.config import SlamConfig
from simn_sim.tracking.lie import check_pose, constant_velocity_prior, se3_log
from simn_sim.tracking.localframes import FrameTrigger, LocalFrame, unpack_feature_points
from simn_sim.tracking.pointsdf import PointCloudSDF
from simn_sim.tracking.posegraph import covariance_from_sigmas
from simn_sim.tracking.registration import register
from simn_sim.tracking.topomap import DescriptorConfig, TopoMap, close_loop_steps, describe


@dataclasses.dataclass
class SlamFrame:
    """Result of :meth:`SimnSlam.process` for one frame.

    T_world_cam: (4, 4) float64 estimate (world <- OpenCV camera). prior: the prediction used.
    success / reason / iterations: the registration's outcome ("ok", or why the prediction was
    kept). points_world: (N, 3) float32 classified points of this frame (world), labels (N,)
    int8. obstacle_points_world: (M, 3) float32 the OBSTACLE subset.
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray
    prior: np.ndarray
    success: bool
    reason: str
    iterations: int
    frame_id: int
    new_local_frame: bool
    revisit_accepted: bool
    revisit_frame: int | None
    track_ms: float
    map_ms: float
    n_track_points: int
    points_world: np.ndarray
    labels: np.ndarray
    obstacle_points_world: np.ndarray
    anchors_version: int
    pixels: np.ndarray | None = None  # (N, 2) int (row, column) of each point in the image
    tracked_against: int | None = None  # local frame whose map was used (None: no map)
    inlier_rms: float = float("nan")


class _VoxelStore:
    """Points on a voxel grid, one per voxel, anchor coordinates, with optional (N, k) extra
    attributes (normals). ``keep="latest"`` replaces a voxel's point by a newer one (obstacles:
    the world may change); ``keep="first"`` keeps the first; ``keep="mean"`` averages all
    observations of the voxel (points and extras; a noise-averaged tracking model)."""

    def __init__(self, voxel: float, keep: str = "latest", extra_dim: int = 0) -> None:
        self.voxel = float(voxel)
        self.keep = keep
        self.keys = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3), np.float32)
        self.extra = np.zeros((0, extra_dim), np.float32)
        self.count = np.zeros(0, np.float32)

    def _key(self, p: np.ndarray) -> np.ndarray:
        g = np.floor(p / self.voxel).astype(np.int64) + (1 << 20)
        return (g[:, 0] << 42) | (g[:, 1] << 21) | g[:, 2]

    def add(self, p: np.ndarray, extra: np.ndarray | None = None) -> None:
        if len(p) == 0:
            return
        p = np.asarray(p, np.float32)
        e = np.zeros((len(p), self.extra.shape[1]), np.float32) if extra is None else extra
        e = np.asarray(e, np.float32)
        kn = self._key(p)
        if self.keep == "mean":
            keys = np.concatenate([self.keys, kn])
            w = np.concatenate([self.count, np.ones(len(p), np.float32)])
            P = np.concatenate([self.points * self.count[:, None], p])
            E = np.concatenate([self.extra * self.count[:, None], e])
            self.keys, inv = np.unique(keys, return_inverse=True)
            inv = inv.reshape(-1)
            m = len(self.keys)
            self.count = np.bincount(inv, w, minlength=m).astype(np.float32)

            def mean(a: np.ndarray) -> np.ndarray:
                cols = [np.bincount(inv, a[:, j], minlength=m) for j in range(a.shape[1])]
                return (np.stack(cols, 1) / self.count[:, None]).astype(np.float32)

            self.points = mean(P)
            self.extra = mean(E) if E.shape[1] else np.zeros((m, 0), np.float32)
            return
        new = (kn, p, e)
        old = (self.keys, self.points, self.extra)
        a, b = (new, old) if self.keep == "latest" else (old, new)  # np.unique keeps the first
        keys = np.concatenate([a[0], b[0]])
        self.keys, idx = np.unique(keys, return_index=True)
        self.points = np.concatenate([a[1], b[1]])[idx]
        self.extra = np.concatenate([a[2], b[2]])[idx]
        self.count = np.ones(len(self.keys), np.float32)

    def remove(self, mask: np.ndarray) -> None:
        keep = ~mask
        self.keys, self.points, self.extra = self.keys[keep], self.points[keep], self.extra[keep]
        self.count = self.count[keep]

    def __len__(self) -> int:
        return len(self.keys)


class PointFrameMap:
    """The learning-free per-frame map (``map_kind="points"``): a surface voxel store with
    normals in anchor coordinates; ``sdf_and_grad`` is its point-to-plane SDF. Implements the
    :class:`~simn_sim.tracking.localframes.FrameMap` protocol (no learned features)."""

    def __init__(
        self,
        surface: _VoxelStore,
        max_dist: float = 0.05,
        kernel: float = 0.0,
        k: int = 8,
        count_weight: bool = False,
        normal_gate: float = -1.0,
    ) -> None:
        self.surface = surface
        self.max_dist = float(max_dist)
        self.kernel, self.k, self.count_weight = float(kernel), int(k), bool(count_weight)
        self.normal_gate = float(normal_gate)
        self._sdf: PointCloudSDF | None = None
        self._n = -1

    def point_sdf(self, rebuild_growth: float = 0.1) -> PointCloudSDF | None:
        """The point-to-plane SDF, rebuilt when the store grew by ``rebuild_growth``."""
        n = len(self.surface)
        if n < 50:
            return None
        if self._sdf is None or n > self._n * (1 + rebuild_growth) or n < self._n:
            try:
                self._sdf = PointCloudSDF(
                    self.surface.points,
                    self.surface.extra,
                    max_dist=self.max_dist,
                    kernel=self.kernel,
                    k=self.k,
                    confidence=self.surface.count if self.count_weight else None,
                    normal_gate=self.normal_gate,
                )
            except ValueError:
                return None
            self._n = n
        return self._sdf

    def sdf_and_grad(self, points: np.ndarray):
        sdf = self.point_sdf(0.0)
        if sdf is None:
            x = np.asarray(points)
            return np.full(len(x), np.nan), np.full((len(x), 3), np.nan), np.zeros(len(x), bool)
        return sdf.sdf_and_grad(points)

    def feature_points(self):
        P = self.surface.points
        return P, np.zeros((len(P), 0), np.float32), np.zeros(len(P), np.int64)


@dataclasses.dataclass
class _FrameState:
    """Pipeline-side state of one local frame."""

    frame: LocalFrame
    obstacles: _VoxelStore
    floor: _VoxelStore
    surface: PointFrameMap  # tracking model (2 cm voxels + normals), anchor coordinates
    n_trained: int = 0
    n_obs: int = 0
    loop_sdf: tuple[int, PointCloudSDF] | None = None


class SimnSlam:
    """The SIMN front-end; see the module docstring.

    intrinsics: the camera's (full-resolution) pinhole intrinsics. T_base_cam: (4, 4) camera
    (OpenCV optical frame) in the robot base frame (z up, base plane z = 0), or None (hand-held
    / TUM: no floor prior, semantics off).
    """

    def __init__(
        self,
        cfg: SlamConfig | None = None,
        intrinsics: Intrinsics | None = None,
        T_base_cam: np.ndarray | None = None,
    ) -> None:
        if intrinsics is None:
            raise ValueError("SimnSlam needs the camera intrinsics")
        self.cfg = cfg or SlamConfig()
        self.intr = intrinsics
        self.T_base_cam = None if T_base_cam is None else check_pose(T_base_cam, "T_base_cam")
        s = self.cfg.pixel_stride or max(1, int(round(intrinsics.width / 160)))
        self.stride = s
        v, u = np.mgrid[0 : intrinsics.height : s, 0 : intrinsics.width : s]
        self._ray_x = ((u - intrinsics.cx) / intrinsics.fx).astype(np.float32)
        self._ray_y = ((v - intrinsics.cy) / intrinsics.fy).astype(np.float32)
        self.rng = np.random.default_rng(self.cfg.seed)
        # the learned map's geometric prior takes its own (smoother) normals
        self._map_prior = (
            self.cfg.map_kind == "implicit" and self.cfg.mapper.decoder.geometric_prior
        )
        self._track_reg = self.cfg.registration.replace(
            degeneracy_ratio=self.cfg.track_degeneracy_ratio,
            min_valid_fraction=self.cfg.track_min_valid_fraction,
        )
        if self.cfg.track_sdf == "implicit":
            self._track_reg = self._track_reg.replace(grad_norm_min=self.cfg.implicit_grad_norm_min)
        c = self.cfg
        sr, st = np.radians(c.prior_sigma_rot_deg), c.prior_sigma_trans
        self._cv_info = np.diag([1 / sr**2] * 3 + [1 / st**2] * 3)
        sr, st = np.radians(c.odom_prior_sigma_rot_deg), c.odom_prior_sigma_trans
        self._odom_info = np.diag([1 / sr**2] * 3 + [1 / st**2] * 3)
        self.topo = TopoMap(DescriptorConfig(max_points=self.cfg.describe_max_points))
        self.trigger = FrameTrigger(self.cfg.trigger)
        self._states: dict[int, _FrameState] = {}
        self._base_map: ImplicitMap | None = None
        self.current_frame_id: int = -1
        self.anchors_version = 0
        self.n_frames = 0
        self.n_revisits = 0
        self.n_track_failures = 0
        self._hist: list[tuple[float, np.ndarray]] = []  # (t, T_anchor_cam) of the last two
        self._last_prior: np.ndarray | None = None
        self._rms_ema: float | None = None  # running inlier RMS of the tracking registrations
        self._records: list[tuple[float, int, np.ndarray, np.ndarray]] = []
        self._obst_cache: tuple[tuple, np.ndarray] | None = None
        self._floor_cache: tuple[tuple, np.ndarray] | None = None
        self.last: SlamFrame | None = None
        self.loop_log: list[dict[str, Any]] = []
        # deferred revisit checks (revisit_checks_per_frame > 0): (frame, points, candidates)
        self._pending_revisit: tuple[int, np.ndarray, list[int]] | None = None
        # revisit_registrations_per_frame > 0: the deferred check in progress, a
        # ``close_loop_steps`` generator advanced that many registrations per frame
        self._revisit_job: tuple[int, Any] | None = None

    # ------------------------------------------------------------------ perception
    def _perceive(self, rgb: np.ndarray | None, depth: np.ndarray) -> dict[str, np.ndarray]:
        depth = np.asarray(depth)
        h, w = self.intr.height, self.intr.width
        if depth.shape != (h, w):
            raise ValueError(f"depth is {depth.shape}, intrinsics are {w}x{h}")
        s = self.stride
        z = depth[::s, ::s].astype(np.float32)
        ok = np.isfinite(z) & (z >= self.cfg.min_depth) & (z <= self.cfg.max_depth)
        zz = np.where(ok, z, 0.0).astype(np.float32)
        P = np.stack([self._ray_x * zz, self._ray_y * zz, zz], axis=2)
        N = self._normals(P, zz, ok, self.cfg.normal_smooth_px)
        pts = P[ok]
        nrm = N[ok].astype(np.float32)
        map_nrm = nrm
        k_map = self.cfg.implicit_normal_smooth_px
        if self._map_prior and k_map != self.cfg.normal_smooth_px:
            map_nrm = self._normals(P, zz, ok, k_map)[ok].astype(np.float32)
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.shape != (h, w, 3):
                raise ValueError(f"rgb is {rgb.shape}, expected ({h}, {w}, 3)")
            col = rgb[::s, ::s][ok]
            col = col.astype(np.float32) / 255.0 if rgb.dtype == np.uint8 else col
            col = np.clip(col.astype(np.float32), 0, 1)
        else:
            col = np.full((len(pts), 3), 0.5, np.float32)
        rows, cols = np.nonzero(ok)
        pix = np.stack([rows * s, cols * s], axis=1)
        return {
            "points": pts,
            "normals": nrm,
            "map_normals": map_nrm,
            "colors": col,
            "depth": zz,
            "valid": ok,
            "pix": pix,
        }

    def _normals(self, P: np.ndarray, zz: np.ndarray, ok: np.ndarray, k_px: int) -> np.ndarray:
        """(H, W, 3) normals of the organised points; with ``k_px`` > 0 from a normalised-
        convolution box blur of the depth over (2 k_px + 1)^2 pixels (noisy stereo depth gives
        useless central-difference normals); the points themselves keep the raw depth."""
        if k_px <= 0:
            return normals_from_organized(np.where(ok[..., None], P, np.nan))
        k = 2 * k_px + 1
        wsum = cv2.blur(ok.astype(np.float32), (k, k))
        zs = cv2.blur(zz, (k, k)) / np.maximum(wsum, 1e-6)
        Ps = np.stack([self._ray_x * zs, self._ray_y * zs, zs], axis=2)
        return normals_from_organized(np.where(ok[..., None], Ps, np.nan))

    def _point_weights(self, pts: np.ndarray) -> np.ndarray | None:
        """Registration prior weights: the inverse depth-noise variance of each point relative
        to a point at zero range, sigma(z) = depth_sigma0 + depth_sigma_per_m2 z^2 (the stereo
        error grows with z^2); None when ``depth_sigma_per_m2`` is 0 (equal weights)."""
        k = self.cfg.depth_sigma_per_m2
        if k <= 0:
            return None
        s0 = self.cfg.depth_sigma0
        return (s0 / (s0 + k * pts[:, 2].astype(np.float64) ** 2)) ** 2

    def _track_points(self, pts: np.ndarray) -> np.ndarray:
        pts = pts[pts[:, 2] <= self.cfg.track_max_depth]
        if len(pts) == 0:
            return pts
        tp, _, _ = voxel_downsample(pts, self.cfg.track_voxel)
        if len(tp) > self.cfg.max_track_points:
            tp = tp[self.rng.choice(len(tp), self.cfg.max_track_points, replace=False)]
        return tp.astype(np.float32)

    # ------------------------------------------------------------------ frames
    def _point_map(self, surface: _VoxelStore) -> PointFrameMap:
        c = self.cfg
        return PointFrameMap(
            surface,
            c.point_sdf_max_dist,
            c.point_sdf_kernel,
            c.point_sdf_k,
            c.point_sdf_count_weight,
            np.cos(np.radians(c.point_sdf_normal_gate_deg)),
        )

    def _new_map(self, surface: _VoxelStore):
        if self.cfg.map_kind == "points":
            return self._point_map(surface)
        if self._base_map is None:
            self._base_map = ImplicitMap(self.cfg.mapper)
            return self._base_map
        prev = self._states[self.current_frame_id].frame.map
        m = prev.new_map(share_decoder=self.cfg.share_decoder)
        if self.cfg.share_decoder and prev.ewc.active:
            m.ewc.load_state_dict(prev.ewc.state_dict())  # keep protecting the shared decoder
        return m

    def _open_frame(self, T_world_cam: np.ndarray, t: float) -> int:
        fid = len(self._states)
        surface = _VoxelStore(self.cfg.surface_voxel, keep=self.cfg.surface_keep, extra_dim=3)
        frame = LocalFrame(fid, T_world_cam.copy(), self._new_map(surface), t_start=t, t_end=t)
        self._states[fid] = _FrameState(
            frame,
            _VoxelStore(self.cfg.obstacle_voxel),
            _VoxelStore(self.cfg.floor_voxel),
            frame.map if isinstance(frame.map, PointFrameMap) else self._point_map(surface),
        )
        self.topo.add_frame(frame)
        prev = self.current_frame_id
        if prev >= 0:
            T_pc = inv_T(self.topo.anchor(prev)) @ T_world_cam
            ang = float(np.linalg.norm(se3_log(T_pc)[:3]))
            dist = float(np.linalg.norm(T_pc[:3, 3]))
            c = self.cfg
            cov = covariance_from_sigmas(
                c.odom_sigma_rot + c.odom_sigma_rot_per_rad * ang,
                c.odom_sigma_trans + c.odom_sigma_trans_per_m * dist,
            )
            self.topo.add_arc(prev, fid, T_pc, cov)
        self.current_frame_id = fid
        return fid

    def _close_frame(self, fid: int) -> None:
        st = self._states[fid]
        try:
            if isinstance(st.frame.map, ImplicitMap) and st.n_trained and st.frame.map.n_pending:
                st.frame.map.train(self.cfg.train_iters)
            if isinstance(st.frame.map, ImplicitMap):
                st.frame.map.consolidate()
        except Exception:  # noqa: BLE001 - a mapping hiccup must not stop tracking
            pass
        if len(unpack_feature_points(st.frame.map.feature_points())[0]):
            self.topo.refresh(fid)

    # ------------------------------------------------------------------ tracking
    def _sdf_of(self, fid: int, growth: float | None = None):
        """``sdf_and_grad`` of frame ``fid`` for registration (per ``track_sdf``), or None."""
        st = self._states[fid]
        if self.cfg.track_sdf == "implicit":
            if st.n_trained == 0:
                return None
            c = self.cfg
            dmax = c.implicit_max_dist if growth is None else None  # revisits: the map's own
            return st.frame.map.tracking_sdf(c.implicit_reuse_neighbors, dmax).sdf_and_grad
        g = self.cfg.sdf_rebuild_growth if growth is None else growth
        sdf = st.surface.point_sdf(g)
        if sdf is None:
            return None
        if sdf.kernel > 0:
            sdf.kernel = self.track_kernel
        return sdf.sdf_and_grad

    @property
    def track_kernel(self) -> float:
        """Kernel width (m) of the tracking point SDF: ``point_sdf_kernel_rms_factor`` times the
        running inlier RMS of the registrations, clipped to [``point_sdf_kernel_min``,
        ``point_sdf_kernel``] (the maximum before the first registration)."""
        c = self.cfg
        if c.point_sdf_kernel <= 0:
            return 0.0
        if c.point_sdf_kernel_rms_factor <= 0 or self._rms_ema is None:
            return c.point_sdf_kernel
        h = c.point_sdf_kernel_rms_factor * self._rms_ema
        return float(np.clip(h, c.point_sdf_kernel_min, c.point_sdf_kernel))

    def _update_rms(self, rms: float) -> None:
        if np.isfinite(rms):
            a = 0.3
            self._rms_ema = rms if self._rms_ema is None else (1 - a) * self._rms_ema + a * rms

    def _track_target(self) -> tuple[int, Any] | None:
        """(frame id, sdf_and_grad) to register against: the current frame's map, or the
        previous frame's while the current one has none yet."""
        cands = [self.current_frame_id]
        if self.current_frame_id > 0:
            cands.append(self.current_frame_id - 1)
        for fid in cands:
            sdf = self._sdf_of(fid)
            if sdf is not None:
                return fid, sdf
        return None

    def _predict(self, t: float, prior: np.ndarray | None) -> np.ndarray:
        """Predicted ``T_anchor_cam`` in the current frame."""
        T1 = self._hist[-1][1]
        if prior is not None and self._last_prior is not None:
            return T1 @ (inv_T(self._last_prior) @ prior)
        if len(self._hist) < 2:
            return T1.copy()
        (t0, T0), (t1, _) = self._hist[-2], self._hist[-1]
        ratio = (t - t1) / (t1 - t0) if t1 > t0 else 1.0
        return constant_velocity_prior(T0, T1, float(np.clip(ratio, 0.0, 5.0)))

    # ------------------------------------------------------------------ main entry
    def process(
        self,
        t: float,
        rgb: np.ndarray | None,
        depth: np.ndarray,
        T_world_cam_prior: np.ndarray | None = None,
    ) -> SlamFrame:
        """Track, map and update the topological map with one RGB-D frame.

        t: timestamp (s), increasing. rgb: (H, W, 3) uint8 or None. depth: (H, W) float metres
        (0 / NaN invalid). T_world_cam_prior: optional (4, 4) pose from another source (wheel
        odometry); only its change since the previous call is used (so its drift does not
        enter), except on the first call, where it defines the world frame.
        """
        n_threads = torch.get_num_threads()
        if self.cfg.torch_threads and self.cfg.torch_threads != n_threads:
            torch.set_num_threads(self.cfg.torch_threads)
        try:
            return self._process(t, rgb, depth, T_world_cam_prior)
        finally:
            if torch.get_num_threads() != n_threads:
                torch.set_num_threads(n_threads)

    def _process(
        self,
        t: float,
        rgb: np.ndarray | None,
        depth: np.ndarray,
        T_world_cam_prior: np.ndarray | None,
    ) -> SlamFrame:
        t0 = time.perf_counter()
        t = float(t)
        if self._hist and t <= self._hist[-1][0]:
            raise ValueError(f"timestamp {t} is not after {self._hist[-1][0]}")
        prior = None if T_world_cam_prior is None else check_pose(T_world_cam_prior, "prior")
        obs = self._perceive(rgb, depth)
        track_pts = self._track_points(obs["points"])
        first = self.n_frames == 0
        new_frame = False
        revisit, revisit_fid = False, None
        success, reason, iters, against, rms = True, "first frame", 0, None, float("nan")
        if first:
            if prior is not None:
                T_world_cam = prior.copy()
            elif self.T_base_cam is not None:
                T_world_cam = self.T_base_cam.copy()
            else:
                T_world_cam = np.eye(4)
            self._open_frame(T_world_cam, t)
            self.trigger.reset(T_world_cam)
            T_anchor_cam = np.eye(4)
            T_pred_world = T_world_cam.copy()
        else:
            A = self.topo.anchor(self.current_frame_id)
            T_pred = orthonormalize(self._predict(t, prior))
            T_pred_world = A @ T_pred
            use_odom = prior is not None and self._last_prior is not None
            T_anchor_cam, success, reason, iters, against, rms = self._register(
                track_pts, T_pred, self._odom_info if use_odom else self._cv_info
            )
            if success:
                self._update_rms(rms)
            T_anchor_cam = orthonormalize(T_anchor_cam)
            T_world_cam = orthonormalize(A @ T_anchor_cam)
        if not success:
            self.n_track_failures += 1
        track_ms = (time.perf_counter() - t0) * 1e3

        t1 = time.perf_counter()
        if not first and self.trigger.update(T_world_cam):
            old = self.current_frame_id
            self._states[old].frame.t_end = self._hist[-1][0]
            self._close_frame(old)
            fid = self._open_frame(T_world_cam, t)
            new_frame = True
            self._hist = [(tt, inv_T(self.topo.anchor(fid)) @ self.topo.anchor(old) @ T)
                          for tt, T in self._hist]  # fmt: skip
            T_anchor_cam = np.eye(4)
            self._pending_revisit = self._revisit_job = None
            if self.cfg.revisits and len(track_pts) >= 100:
                if self.cfg.revisit_registrations_per_frame > 0:
                    cands = self._revisit_candidates(fid, track_pts, T_world_cam)
                    if cands:
                        steps = self._revisit_steps(fid, track_pts, T_world_cam, cands)
                        self._revisit_job = (fid, steps)
                elif self.cfg.revisit_checks_per_frame > 0:
                    cands = self._revisit_candidates(fid, track_pts, T_world_cam)
                    if cands:
                        self._pending_revisit = (fid, track_pts, cands)
                else:
                    revisit_fid = self._revisit(fid, track_pts, T_world_cam)
                    if revisit_fid is not None:
                        revisit = True
                        T_world_cam = self.topo.anchor(fid) @ T_anchor_cam
        elif not first and self._revisit_job is not None:
            # deferred, spread over frames registration by registration (the opening
            # observation of the current frame, at the frame's anchor, against the candidates)
            pfid, steps = self._revisit_job
            done, revisit_fid = self._advance_revisit(
                pfid, steps, self.cfg.revisit_registrations_per_frame
            )
            if done:
                self._revisit_job = None
            if revisit_fid is not None:
                revisit = True
                T_world_cam = self.topo.anchor(self.current_frame_id) @ T_anchor_cam
        elif not first and self._pending_revisit is not None:
            # deferred: the opening observation of the current frame against the next
            # candidates (its camera pose then was the frame's anchor)
            pfid, ppts, queue = self._pending_revisit
            k = self.cfg.revisit_checks_per_frame
            self._pending_revisit = (pfid, ppts, queue[k:]) if len(queue) > k else None
            revisit_fid = self._revisit(pfid, ppts, self.topo.anchor(pfid), queue[:k])
            if revisit_fid is not None:
                revisit = True
                self._pending_revisit = None
                T_world_cam = self.topo.anchor(self.current_frame_id) @ T_anchor_cam
        fid = self.current_frame_id
        st = self._states[fid]

        labels = np.zeros(len(obs["points"]), np.int8)
        if self.cfg.semantics and self.T_base_cam is not None and len(obs["points"]):
            labels = self._classify(obs, T_world_cam)
        self._integrate(st, obs, labels, T_anchor_cam)
        if self.cfg.carve:
            self._carve(obs, T_world_cam)
        st.frame.t_end = t
        st.frame.n_observations += 1

        Pw = transform_points(T_world_cam, obs["points"].astype(np.float64)).astype(np.float32)
        self._hist = (self._hist + [(t, T_anchor_cam)])[-2:]
        self._last_prior = prior
        self._records.append((t, fid, T_anchor_cam.copy(), T_world_cam.copy()))
        self.n_frames += 1
        map_ms = (time.perf_counter() - t1) * 1e3
        out = SlamFrame(
            index=self.n_frames - 1,
            timestamp=t,
            T_world_cam=T_world_cam,
            prior=T_pred_world,
            success=success,
            reason=reason,
            iterations=iters,
            frame_id=fid,
            new_local_frame=new_frame or first,
            revisit_accepted=revisit,
            revisit_frame=revisit_fid,
            track_ms=track_ms,
            map_ms=map_ms,
            n_track_points=len(track_pts),
            points_world=Pw,
            labels=labels,
            obstacle_points_world=Pw[labels == OBSTACLE],
            anchors_version=self.anchors_version,
            pixels=obs["pix"],
            tracked_against=against,
            inlier_rms=rms,
        )
        self.last = out
        return out

    def _register(
        self, pts: np.ndarray, T_pred: np.ndarray, prior_info: np.ndarray
    ) -> tuple[np.ndarray, bool, str, int, int | None, float]:
        """Register against the tracking target; the prediction on any failure."""
        if len(pts) < self.cfg.registration.min_valid_points:
            return T_pred, False, f"only {len(pts)} valid points", 0, None, float("nan")
        target = self._track_target()
        if target is None:
            return T_pred, False, "no trained map yet", 0, None, float("nan")
        fid, sdf = target
        cur = self.current_frame_id
        T_cur_f = inv_T(self.topo.anchor(cur)) @ self.topo.anchor(fid)
        init = inv_T(T_cur_f) @ T_pred
        try:
            res = self._register_c2f(pts, sdf, init, self._track_reg)
        except Exception as e:  # noqa: BLE001 - tracking must never raise
            return T_pred, False, f"registration error: {type(e).__name__}: {e}", 0, fid, np.nan
        if not res.success:
            return T_pred, False, res.reason, res.iterations, fid, res.final_rms
        T_est = orthonormalize(T_cur_f @ res.pose)
        reason = "ok"
        if self.cfg.fuse_prior:
            # Bayesian fusion in the camera-frame tangent at the prediction: the registration
            # decides the well-constrained directions, the prediction the degenerate ones.
            delta = se3_log(inv_T(T_pred) @ T_est)
            try:
                info = np.linalg.inv(0.5 * (res.covariance + res.covariance.T))
                if res.eig_ratio < self.cfg.registration.degeneracy_ratio:
                    # weakly constrained: directions whose information is below ``weak_ratio``
                    # of the largest carry the bias of the model's edges rather than
                    # information; drop them, the prior decides there. Rotations are scaled by
                    # the median depth so both blocks are in metres.
                    L = float(np.median(pts[:, 2])) if len(pts) else 1.0
                    D = np.diag([L] * 3 + [1.0] * 3)
                    Di = np.linalg.inv(D)
                    ev, V = np.linalg.eigh(Di @ (0.5 * (info + info.T)) @ Di)
                    ev = np.where(ev >= self.cfg.weak_ratio * ev.max(), ev, 0.0)
                    info = D @ ((V * ev) @ V.T) @ D
                fused = np.linalg.solve(info + prior_info, info @ delta)
                T_est = orthonormalize(T_pred @ se3_exp(fused))
                # innovation gate: a correction many prior sigmas away is a registration that
                # slid (an edge of the model, a weakly constrained view), not the motion the
                # prediction missed; keep the prediction
                gate = self.cfg.gate_sigmas
                if gate > 0:
                    m = float(np.sqrt(max(fused @ prior_info @ fused, 0.0)))
                    if m > gate:
                        why = f"correction {m:.1f} sigma of the motion prior (gate {gate:g})"
                        return T_pred, False, why, res.iterations, fid, res.final_rms
            except np.linalg.LinAlgError:
                pass
            if res.eig_ratio < self.cfg.registration.degeneracy_ratio:
                reason = f"ok (weakly constrained, eigenvalue ratio {res.eig_ratio:.1e})"
        dt, dr = pose_error(T_pred, T_est)
        if dt > self.cfg.max_correction_m or np.degrees(dr) > self.cfg.max_correction_deg:
            why = f"correction {dt:.3f} m / {np.degrees(dr):.1f} deg beyond the budget"
            return T_pred, False, why, res.iterations, fid, res.final_rms
        return T_est, True, reason, res.iterations, fid, res.final_rms

    def _register_c2f(self, pts: np.ndarray, sdf, T_init: np.ndarray, reg_cfg):
        """Register; on a kernel point SDF coarse to fine: first with the widest kernel
        (``point_sdf_kernel``: smooth, wide basin), then from there with the noise-adaptive
        width (:attr:`track_kernel`: on exact depth close to the nearest-point SDF, which
        keeps the geometry's detail)."""
        w = self._point_weights(pts)
        obj = getattr(sdf, "__self__", None)
        fine = self.track_kernel
        if not isinstance(obj, PointCloudSDF) or obj.kernel <= 0 or not self.cfg.c2f:
            return register(pts, sdf, T_init, reg_cfg, weights=w)
        obj.kernel = self.cfg.point_sdf_kernel
        res = register(pts, sdf, T_init, reg_cfg, weights=w)
        if not res.success or fine >= obj.kernel:
            return res
        obj.kernel = fine
        res2 = register(pts, sdf, res.pose, reg_cfg, weights=w)
        return res2 if res2.success else res

    def _point_sdf(self, P: np.ndarray, N: np.ndarray, max_dist: float) -> PointCloudSDF:
        c = self.cfg
        return PointCloudSDF(
            P,
            N,
            max_dist=max_dist,
            kernel=self.track_kernel,
            k=c.point_sdf_k,
            normal_gate=float(np.cos(np.radians(c.point_sdf_normal_gate_deg))),
        )

    def _loop_register(self, fid: int, pts: np.ndarray, T_init: np.ndarray):
        """Registration callback of the revisit check: against frame ``fid``'s SDF."""
        if self.cfg.track_sdf == "implicit":
            sdf = self._sdf_of(fid, growth=0.0)
        else:  # a wider validity radius than tracking: the drift may be decimetres
            st = self._states[fid]
            if st.loop_sdf is None or st.loop_sdf[0] != len(st.surface.surface):
                P, N = st.surface.surface.points, st.surface.surface.extra
                st.loop_sdf = (len(P), self._point_sdf(P, N, self.cfg.loop_sdf_max_dist))
            st.loop_sdf[1].kernel = self.track_kernel if self.cfg.loop_kernel else 0.0
            sdf = st.loop_sdf[1].sdf_and_grad
        if sdf is None:
            raise ValueError(f"frame {fid} has no map to register against")
        return self._register_c2f(pts, sdf, T_init, self.cfg.registration)

    def _revisit_candidates(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray) -> list[int]:
        """Earlier frames to check for a revisit, most similar first (as in ``close_loop``)."""
        if len(self._states) <= self.cfg.loop.exclude_recent + 1:
            return []
        c = self.cfg.loop
        Pw = transform_points(T_world_cam, pts.astype(np.float64))
        desc = describe(Pw, None, self.topo.desc_cfg)
        found = self.topo.candidates(desc, c.exclude_recent, c.top, c.min_similarity, exclude=[fid])
        out = []
        for f, _ in found:
            if self.cfg.revisit_min_overlap > 0:
                # the check moves the guess by at most max_correction_m: an observation that
                # does not reach the candidate's region grown by that much cannot pass it
                r = self.topo.region(f)
                g = c.max_correction_m
                inside = np.all((Pw[:, :2] >= r[:2] - g) & (Pw[:, :2] <= r[2:] + g), axis=1)
                if not np.all(np.isfinite(r)) or inside.mean() < self.cfg.revisit_min_overlap:
                    continue
            out.append(int(f))
        return out

    def _revisit(
        self,
        fid: int,
        pts: np.ndarray,
        T_world_cam: np.ndarray,
        candidate_ids: list[int] | None = None,
    ) -> int | None:
        """The whole revisit check of frame ``fid``'s observation ``pts`` now."""
        if candidate_ids is None and len(self._states) <= self.cfg.loop.exclude_recent + 1:
            return None
        steps = self._revisit_steps(fid, pts, T_world_cam, candidate_ids)
        return self._advance_revisit(fid, steps, None)[1]

    def _revisit_steps(
        self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray, candidate_ids: list[int] | None
    ):
        # candidates() skips the most recent frames; untrained maps have no descriptor
        return close_loop_steps(
            self.topo,
            fid,
            pts,
            T_world_cam,
            self._loop_register,
            self.cfg.loop,
            candidate_ids=candidate_ids,
            pose_graph_cfg=self.cfg.pose_graph,
        )

    def _advance_revisit(self, fid: int, steps: Any, budget: int | None) -> tuple[bool, int | None]:
        """Run a revisit check's ``close_loop_steps`` generator for at most ``budget``
        registrations (None: to the end). Returns (finished, accepted frame or None)."""
        n = 0
        try:
            while budget is None or n < budget:
                next(steps)
                n += 1
            return False, None
        except StopIteration as done:
            res = done.value
        except Exception as e:  # noqa: BLE001 - a failed revisit check must not stop tracking
            self.loop_log.append({"frame": fid, "error": f"{type(e).__name__}: {e}"})
            return True, None
        self.loop_log.append(
            {
                "frame": fid,
                "accepted": res.accepted,
                "attempts": [
                    {
                        "candidate": a.frame_id,
                        "similarity": a.similarity,
                        "accepted": a.accepted,
                        "reason": a.reason,
                    }
                    for a in res.attempts
                ],
            }  # fmt: skip
        )
        if res.accepted is None:
            return True, None
        self.n_revisits += 1
        self.anchors_version += 1
        return True, int(res.accepted)

    # ------------------------------------------------------------------ semantics / stores
    def _classify(self, obs: dict[str, np.ndarray], T_world_cam: np.ndarray) -> np.ndarray:
        T_world_base = T_world_cam @ inv_T(self.T_base_cam)
        n = T_world_base[:3, 2].copy()
        d = float(n @ T_world_base[:3, 3])
        R = T_world_cam[:3, :3]
        Pw = transform_points(T_world_cam, obs["points"].astype(np.float64))
        Nw = obs["normals"].astype(np.float64) @ R.T
        try:
            res = classify_points(
                Pw, Nw, self.cfg.classifier, plane=(n, d), ranges=obs["points"][:, 2]
            )
        except Exception:  # noqa: BLE001
            return np.zeros(len(Pw), np.int8)
        return res.labels.astype(np.int8)

    def _integrate(
        self,
        st: _FrameState,
        obs: dict[str, np.ndarray],
        labels: np.ndarray,
        T_anchor_cam: np.ndarray,
    ) -> None:
        pts = obs["points"]
        st.n_obs += 1
        if len(pts) == 0:
            return
        Pa = transform_points(T_anchor_cam, pts.astype(np.float64)).astype(np.float32)
        if labels is not None and len(labels):
            st.obstacles.add(Pa[labels == OBSTACLE])
            st.floor.add(Pa[labels == FLOOR])
        ok = np.isfinite(obs["normals"]).all(axis=1)
        if ok.any():
            q, nq, _ = _voxel_pick(pts[ok], obs["normals"][ok], self.cfg.surface_voxel)
            st.surface.surface.add(
                transform_points(T_anchor_cam, q.astype(np.float64)),
                (nq.astype(np.float64) @ T_anchor_cam[:3, :3].T).astype(np.float32),
            )
        if not isinstance(st.frame.map, ImplicitMap):
            if st.n_obs in (1, 2, 4, 8) or st.n_obs % 10 == 0:
                self.topo.refresh(st.frame.frame_id)
            return
        m: ImplicitMap = st.frame.map
        if st.n_trained == 0:
            train_iters = self.cfg.open_train_iters
        elif st.n_obs % self.cfg.train_every == 0:
            train_iters = self.cfg.train_iters
        else:
            train_iters = 0
        try:
            m.integrate_frame(
                pts,
                T_anchor_cam,
                obs["colors"],
                labels.astype(np.int16),
                False,
                normals=obs["map_normals"],
            )
            if train_iters:
                m.train(train_iters)
                st.n_trained += 1
        except Exception:  # noqa: BLE001 - mapping failures degrade tracking, never stop it
            return
        if train_iters and (st.n_trained in (1, 2, 4) or st.n_trained % 8 == 0):
            try:
                self.topo.refresh(st.frame.frame_id)
            except Exception:  # noqa: BLE001
                pass

    def _carve(self, obs: dict[str, np.ndarray], T_world_cam: np.ndarray) -> None:
        """Remove stored obstacle points of recent frames that this frame sees through."""
        zimg, s, intr = obs["depth"], self.stride, self.intr
        hh, ww = zimg.shape
        ids = sorted(self._states)[-self.cfg.carve_frames :]
        T_cam_world = inv_T(T_world_cam)
        changed = False
        for fid in ids:
            st = self._states[fid]
            if len(st.obstacles) == 0:
                continue
            T = T_cam_world @ self.topo.anchor(fid)
            pc = transform_points(T, st.obstacles.points.astype(np.float64))
            z = pc[:, 2]
            front = z > self.cfg.min_depth
            u = np.round((intr.fx * pc[:, 0] / np.where(front, z, 1) + intr.cx) / s).astype(int)
            v = np.round((intr.fy * pc[:, 1] / np.where(front, z, 1) + intr.cy) / s).astype(int)
            inside = front & (u >= 0) & (u < ww) & (v >= 0) & (v < hh)
            zo = np.zeros(len(z))
            zo[inside] = zimg[v[inside], u[inside]]
            through = inside & (zo > 0) & (zo > z + self.cfg.carve_margin)
            if through.any():
                st.obstacles.remove(through)
                changed = True
        if changed:
            self._obst_cache = None

    # ------------------------------------------------------------------ outputs
    def _stamp(self) -> tuple:
        return (self.anchors_version, self.n_frames, self.current_frame_id)

    def obstacle_points_world(self) -> np.ndarray:
        """(N, 3) float32 OBSTACLE points of all local frames, world coordinates through the
        current anchors (one point per ``obstacle_voxel`` voxel per frame). Cached per frame."""
        key = self._stamp()
        if self._obst_cache is None or self._obst_cache[0] != key:
            parts = [
                transform_points(self.topo.anchor(f), s.obstacles.points.astype(np.float64))
                for f, s in self._states.items()
                if len(s.obstacles)
            ]
            pts = (
                np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 3), np.float32)
            )
            self._obst_cache = (key, pts)
        return self._obst_cache[1]

    def floor_points_world(self) -> np.ndarray:
        """(N, 3) float32 FLOOR points of all local frames (world), cached per frame."""
        key = self._stamp()
        if self._floor_cache is None or self._floor_cache[0] != key:
            parts = [
                transform_points(self.topo.anchor(f), s.floor.points.astype(np.float64))
                for f, s in self._states.items()
                if len(s.floor)
            ]
            pts = (
                np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 3), np.float32)
            )
            self._floor_cache = (key, pts)
        return self._floor_cache[1]

    @property
    def pose(self) -> np.ndarray:
        """Latest ``T_world_cam`` through the current anchor."""
        if not self._records:
            raise RuntimeError("no frame processed yet")
        _, fid, T, _ = self._records[-1]
        return self.topo.anchor(fid) @ T

    def trajectory(self, corrected: bool = True) -> list[tuple[float, np.ndarray]]:
        """``[(t, T_world_cam)]`` of all frames: ``corrected`` re-expresses each frame's pose
        through the current (optimised) anchor of its local frame; otherwise the online estimates
        as returned by :meth:`process`."""
        if corrected:
            return [(t, self.topo.anchor(f) @ T) for t, f, T, _ in self._records]
        return [(t, Tw.copy()) for t, _, _, Tw in self._records]

    def stats(self) -> dict[str, Any]:
        return {
            "frames": self.n_frames,
            "local_frames": len(self._states),
            "revisits_accepted": self.n_revisits,
            "track_failures": self.n_track_failures,
            "anchors_version": self.anchors_version,
        }

    def debug(self) -> dict[str, Any]:
        """Data for a rerun recording, with the keys :class:`simn_sim.viz.RerunRecorder`
        reads from ``agent_debug``: ``local_frames`` ``{"current": (points (N, 3) world,
        labels (N,))}`` (this frame's classified points), ``topo_nodes`` (K, 3) anchor
        positions, ``topo_arcs`` list of (2, 3) segments, ``topo_arc_kinds``, ``track_ms``,
        ``map_ms``, ``T_world_cam_est`` and (with ``T_base_cam``) ``T_world_base_est``."""
        ids = self.topo.frame_ids
        nodes = np.array([self.topo.anchor(f)[:3, 3] for f in ids]).reshape(-1, 3)
        pos = {f: nodes[k] for k, f in enumerate(ids)}
        arcs, kinds = [], []
        for i, j, e in self.topo.graph.edges(data=True):
            arcs.append(np.stack([pos[i], pos[j]]))
            kinds.append("loop" if "loop" in e["kinds"] else "odom")
        last = self.last
        out: dict[str, Any] = {"topo_nodes": nodes, "topo_arcs": arcs, "topo_arc_kinds": kinds}
        if last is not None:
            out["local_frames"] = {"current": (last.points_world, last.labels)}
            out["track_ms"], out["map_ms"] = last.track_ms, last.map_ms
            out["T_world_cam_est"] = last.T_world_cam
            if self.T_base_cam is not None:
                out["T_world_base_est"] = last.T_world_cam @ inv_T(self.T_base_cam)
        return out


def _voxel_pick(
    p: np.ndarray, n: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First point (and its normal) per voxel: (M, 3), (M, 3), indices."""
    g = np.floor(p / voxel).astype(np.int64)
    g -= g.min(axis=0)
    span = g.max(axis=0) + 1
    keys = (g[:, 0] * span[1] + g[:, 1]) * span[2] + g[:, 2]
    _, idx = np.unique(keys, return_index=True)
    return p[idx], n[idx], idx
