"""SIMN front-end: RGB-D frames -> tracked camera poses, spatial-implicit local frames,
topological map with revisits, and classified floor / obstacle points for the planner.

Per frame (:meth:`SimnSlam.process`):

1. perceive (:mod:`simn_sim.perception.frame`): one :class:`~simn_sim.perception.Frame`;
   registration points on a ``track_voxel`` (6 cm) grid, at most ``max_track_points``;
2. prediction: the increment of the caller's prior (wheel odometry) applied to the previous
   estimate, or constant velocity without one;
3. track (:mod:`simn_sim.slam.track`): Levenberg-Marquardt registration (:func:`~simn_sim.tracking.registration.register`)
   of the frame against the current local frame's map (its learned SDF); while a freshly opened
   frame's map is untrained, against the previous frame's map. A failed registration (or one
   that moves the prediction beyond ``max_correction_*``) falls back to the prediction and says
   so in :class:`SlamFrame`; nothing raises for bad tracking;
4. topology (:mod:`simn_sim.slam.frames`, :mod:`simn_sim.slam.revisit`):
   :class:`~simn_sim.tracking.localframes.FrameTrigger` (travel or rotation); on
   closing, the map is consolidated (EWC snapshot) and its topological node refreshed; the new
   frame is anchored at the current pose with an odometry arc, and, once the frame's first
   observation is integrated (step 6), a revisit check (:mod:`simn_sim.slam.revisit`: candidates
   ranked by the learned key points' features or by descriptors -> registration -> inlier test
   -> gtsam) may move all anchors (``anchors_version`` increments);
5. integrate (:mod:`simn_sim.slam.integrate`): semantics with ``T_base_cam`` the floor is the base plane ``z = 0`` of the estimated base
   pose (no RANSAC); labels per point (0 unknown, 1 floor, 2 obstacle, 3 overhead);
6. the frame's points (anchor coordinates, with colours and labels) go into the local
   frame's :class:`~simn_sim.mapping.mapper.ImplicitMap`; training on the frame's first
   observation and then every ``train_every``-th frame;
7. obstacle / floor stores (:class:`~simn_sim.slam.frames.LocalFrames`): per local frame voxel sets in anchor coordinates; stored obstacle
   points of the recent frames that the current depth image sees *through* are removed
   (free-space carving), so a person who walked away does not stay an obstacle.

Frames: ``T_world_cam`` maps OpenCV camera points to the SLAM world. The world is the prior's
frame when the first call has a prior; else, with ``T_base_cam``, the first base pose is the
world origin (z up); else the first camera pose is the identity.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import inv_T, on_plane, orthonormalize, transform_points
from simn_sim.perception.frame import Perception
from simn_sim.perception.manhattan import WallHeading
from simn_sim.semantics import OBSTACLE
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.slam.integrate import classify, integrate
from simn_sim.slam.revisit import Revisits
from simn_sim.slam.track import Tracker, TrackResult
from simn_sim.slam.trainer import TrainWorker
from simn_sim.tracking.lie import check_pose
from simn_sim.tracking.localframes import FrameTrigger


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
        self.cfg = cfg = cfg or SlamConfig()
        self.intr = intrinsics
        self.T_base_cam = None if T_base_cam is None else check_pose(T_base_cam, "T_base_cam")
        if cfg.planar and self.T_base_cam is None:
            raise ValueError("SlamConfig.planar needs T_base_cam (the camera on the base)")
        self._T_plane: np.ndarray | None = None  # planar: the first frame's base pose
        self._planar_runs = 0  # the pose-graph runs seen by _graph_moved
        # the learned map's geometric prior takes its own (smoother) normals
        map_prior = cfg.map_kind == "implicit" and cfg.mapper.decoder.geometric_prior
        pc = cfg.perception.replace(
            map_normal_smooth_px=(
                cfg.perception.map_normal_smooth_px
                if map_prior
                else cfg.perception.normal_smooth_px
            )
        )
        self.perception = Perception(intrinsics, pc)
        self.stride = self.perception.stride
        self.rng = np.random.default_rng(cfg.seed)
        self.frames = LocalFrames(cfg)
        self.tracker = Tracker(cfg, self.frames, self.rng, self.T_base_cam)
        self.revisits = Revisits(cfg, self.frames, self.tracker)
        self.trigger = FrameTrigger(cfg.trigger)
        # planar + heading.enabled: the walls' direction holds the heading (WallHeading)
        self.heading = WallHeading(cfg.heading, intrinsics) if cfg.heading.enabled else None
        # the training chunk of a frame, joined by the next frame before it tracks
        # (train_latency 0) or after (1); on a worker thread with train_async, else inline at
        # the join (no worker at all for latency 0 without train_async: trained in the step)
        self.trainer = (
            TrainWorker(cfg.torch_threads, inline=not cfg.train_async)
            if cfg.train_async or cfg.train_latency
            else None
        )
        self.n_frames = 0
        self.n_track_failures = 0
        self.n_map_skipped = 0  # frames the learned map rejected as empty
        self.n_dynamic_points = 0  # points left out of registration and its maps (dynamic)
        self._records: list[tuple[float, int, np.ndarray, np.ndarray]] = []
        self.last: SlamFrame | None = None
        self._held_threads: int | None = None  # the caller's, while a chunk runs (process)

    # ---- the local frames and the topological map, read-only views -------------------------
    @property
    def topo(self):
        return self.frames.topo

    @property
    def current_frame_id(self) -> int:
        return self.frames.current_id

    @property
    def anchors_version(self) -> int:
        return self.frames.anchors_version

    @property
    def loop_log(self) -> list[dict[str, Any]]:
        return self.revisits.log

    @property
    def n_revisits(self) -> int:
        return self.revisits.n_accepted

    # ---- main entry --------------------------------------------------------------------------
    def process(
        self,
        t: float,
        rgb: np.ndarray | None,
        depth: np.ndarray,
        T_world_cam_prior: np.ndarray | None = None,
        dynamic: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> SlamFrame:
        """Track, map and update the topological map with one RGB-D frame.

        t: timestamp (s), increasing. rgb: (H, W, 3) uint8 or None. depth: (H, W) float metres
        (0 / NaN invalid). T_world_cam_prior: optional (4, 4) pose from another source (wheel
        odometry); only its change since the previous call is used (so its drift does not
        enter), except on the first call, where it defines the world frame. dynamic: optional
        ``(N, 3) world points -> (N,) bool``, True where a point lies in space known to hold
        something that moves (the agent's transient cells); those points of the frame, placed
        at the predicted pose, are left out of registration (tracking and the revisit checks)
        and of the maps registration reads (the surface store and the learned map), and still
        reach the obstacle stores and carving.
        """
        # the caller's torch threads: set to ``torch_threads`` here and given back when no
        # training chunk runs on the worker thread; while one runs they stay held until the
        # next join. Given back mid-chunk, in-process runs with 2 threads were not
        # reproducible (one seed gave episodes of 151-157 steps): the setting reaches a
        # library whose thread count is process-wide (presumably MKL, which torch also sets),
        # so the chunk's products split over a thread count that depended on timing
        n_threads = torch.get_num_threads() if self._held_threads is None else self._held_threads
        if self.cfg.torch_threads and self.cfg.torch_threads != torch.get_num_threads():
            torch.set_num_threads(self.cfg.torch_threads)
        try:
            return self._process(t, rgb, depth, T_world_cam_prior, dynamic)
        finally:
            if self.trainer is not None and self.trainer.busy:
                self._held_threads = n_threads
            else:
                self._give_back_threads(n_threads)

    def _give_back_threads(self, n_threads: int | None = None) -> None:
        n = self._held_threads if n_threads is None else n_threads
        self._held_threads = None
        if n is not None and torch.get_num_threads() != n:
            torch.set_num_threads(n)

    def _process(
        self,
        t: float,
        rgb: np.ndarray | None,
        depth: np.ndarray,
        T_world_cam_prior: np.ndarray | None,
        dynamic: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> SlamFrame:
        t0 = time.perf_counter()
        t = float(t)
        tr, frames = self.tracker, self.frames
        if tr.hist and t <= tr.hist[-1][0]:
            raise ValueError(f"timestamp {t} is not after {tr.hist[-1][0]}")
        prior = None if T_world_cam_prior is None else check_pose(T_world_cam_prior, "prior")
        # perceive
        frame = self.perception(rgb, depth)
        first = self.n_frames == 0
        keep = None  # the frame's points outside dynamic space (None: all of them)
        if dynamic is not None and not first and len(frame):
            T_guess = frames.topo.anchor(frames.current_id) @ orthonormalize(tr.predict(t, prior))
            moving = np.asarray(dynamic(transform_points(T_guess, frame.points.astype(np.float64))))
            if moving.shape != (len(frame),) or moving.dtype != bool:
                raise ValueError(
                    f"dynamic must give a ({len(frame)},) bool mask, got {moving.dtype} "
                    f"{moving.shape}"
                )
            if moving.any():
                keep = ~moving
                self.n_dynamic_points += int(moving.sum())
        static = frame if keep is None else frame.select(keep)
        track_pts = tr.track_points(static.points, static.normals)
        if self.cfg.train_latency == 0 or (not first and not tr.has_trained_target()):
            # the previous frame's training (train_async) before the map is read; with
            # train_latency 1 only when nothing trained could be tracked against without it
            self.sync()
        # track
        if first:
            T_world_cam = self._initial_pose(prior)
            if self.cfg.planar:
                self._T_plane = T_world_cam @ inv_T(self.T_base_cam)
                frames.topo.anchor_constraint = self._planar  # pose-graph runs keep the plane
            frames.open(T_world_cam, t)
            self.trigger.reset(T_world_cam)
            tr.start(t)
            res = TrackResult(np.eye(4), True, "first frame", 0, None, float("nan"))
            T_pred_world = T_world_cam.copy()
        else:
            A = frames.topo.anchor(frames.current_id)
            T_pred = orthonormalize(tr.predict(t, prior))
            T_pred_world = A @ T_pred
            res = tr.track(track_pts, T_pred, prior)
            T_world_cam = self._planar(orthonormalize(A @ res.T_anchor_cam))
        self.n_track_failures += int(not res.success)
        T_anchor_cam = (
            res.T_anchor_cam if first or self._T_plane is None else inv_T(A) @ T_world_cam
        )
        track_ms = (time.perf_counter() - t0) * 1e3
        self.sync()  # train_latency 1: the previous frame's training, joined after tracking
        # topology: local frames and revisits
        t1 = time.perf_counter()
        new_frame, revisit_fid = first, None
        if not first and self.trigger.update(T_world_cam):
            old = frames.current_id
            frames.current.frame.t_end = tr.hist[-1][0]
            frames.close(old)
            # the wall heading of the closed frame's views turns the new anchor (and with it
            # the tracker's history: C is a change of world coordinates, not a motion)
            C = self._heading_correction(old, T_world_cam)
            T_world_cam = C @ T_world_cam
            fid = frames.open(T_world_cam, t)
            new_frame = True
            tr.reanchor(inv_T(frames.topo.anchor(fid)) @ C @ frames.topo.anchor(old))
            T_anchor_cam = np.eye(4)
        elif not first:
            revisit_fid = self.revisits.step()
        if self._graph_moved() or revisit_fid is not None:
            # anchors moved: the pose through the current anchor
            T_world_cam = frames.topo.anchor(frames.current_id) @ T_anchor_cam
        # integrate
        st = frames.current
        labels = np.zeros(len(frame), np.int8)
        if self.cfg.semantics and self.T_base_cam is not None and len(frame):
            labels = classify(frame, T_world_cam, self.T_base_cam, self.cfg.classifier)
        frame = frame.with_labels(labels)
        if not integrate(frames, st, frame, T_anchor_cam, self.cfg, self.trainer, keep):
            self.n_map_skipped += 1
        if new_frame and not first:
            # the revisit check of a new frame runs once its first observation is in its map:
            # the learned ranking matches the key points (and features) trained on it; the
            # labels above do not depend on where the anchors are
            revisit_fid = self.revisits.on_open(frames.current_id, track_pts, T_world_cam)
            if self._graph_moved() or revisit_fid is not None:
                T_world_cam = frames.topo.anchor(frames.current_id) @ T_anchor_cam
                # the view is seen from the moved anchor: its stored points were observed there
                frames.restamp_observed(frames.current_id)
        if self.cfg.stores.carve:
            frames.carve(frame, T_world_cam)
        if self.heading is not None:
            R = self._R_plane_anchor(frames.current_id)
            self.heading.observe(depth, T_anchor_cam[:3, :3], R)
        st.frame.t_end = t
        st.frame.n_observations += 1

        Pw = transform_points(T_world_cam, frame.points.astype(np.float64)).astype(np.float32)
        tr.commit(t, T_anchor_cam, prior)
        self._records.append((t, frames.current_id, T_anchor_cam.copy(), T_world_cam.copy()))
        self.n_frames += 1
        out = SlamFrame(
            index=self.n_frames - 1,
            timestamp=t,
            T_world_cam=T_world_cam,
            prior=T_pred_world,
            success=res.success,
            reason=res.reason,
            iterations=res.iterations,
            frame_id=frames.current_id,
            new_local_frame=new_frame,
            revisit_accepted=revisit_fid is not None,
            revisit_frame=revisit_fid,
            track_ms=track_ms,
            map_ms=(time.perf_counter() - t1) * 1e3,
            n_track_points=len(track_pts),
            points_world=Pw,
            labels=labels,
            obstacle_points_world=Pw[labels == OBSTACLE],
            anchors_version=frames.anchors_version,
            pixels=frame.pixels,
            tracked_against=res.against,
            inlier_rms=res.rms,
        )
        self.last = out
        if self.trainer is not None:  # the frame's training, on the worker from here on
            self.trainer.start()
        return out

    def sync(self) -> None:
        """Wait for the training launched by the last frame (``train_async``; no-op otherwise)
        and apply its bookkeeping. Call before reading the learned maps between frames."""
        if self.trainer is not None:
            self.trainer.join()
        self._give_back_threads()

    def close(self) -> None:
        """:meth:`sync` and stop the training thread (``train_async``); the caller's torch
        threads are given back."""
        try:
            if self.trainer is not None:
                self.trainer.close()
        finally:
            self._give_back_threads()

    def _planar(self, T_world_cam: np.ndarray) -> np.ndarray:
        """``T_world_cam`` with its base projected onto the first frame's base plane
        (``planar``: z, roll and pitch of the base relative to the first frame's base set to 0,
        x, y and yaw kept); unchanged without ``planar``."""
        T_plane = self._T_plane
        return T_world_cam if T_plane is None else on_plane(T_plane, T_world_cam, self.T_base_cam)

    def _R_plane_anchor(self, fid: int) -> np.ndarray:
        """Rotation of frame ``fid``'s anchor in the first base's plane coordinates (z up)."""
        return (inv_T(self._T_plane) @ self.frames.topo.anchor(fid))[:3, :3]

    def _heading_correction(self, closed: int, T_world_cam: np.ndarray) -> np.ndarray:
        """(4, 4) change of world coordinates that turns ``T_world_cam``'s base about its own
        vertical by the wall-heading correction of frame ``closed``'s views (identity without
        one; ``heading``)."""
        if self.heading is None:
            return np.eye(4)
        e = self.heading.residual(self._R_plane_anchor(closed))
        if e is None:
            return np.eye(4)
        hc = self.cfg.heading
        if hc.prior_sigma_deg > 0:
            # the closed frame's anchor, its heading residual taken out, for the pose graph:
            # information only about the floor plane's vertical (in the anchor's own axes)
            A = self.frames.topo.anchor(closed)
            a = A[:3, :3].T @ self._T_plane[:3, 2]
            info = np.eye(6) * 1e-6
            info[:3, :3] += np.outer(a, a) / np.radians(hc.prior_sigma_deg) ** 2
            A_fixed = on_plane(self._T_plane, A, self.T_base_cam, np.radians(-e))
            self.frames.topo.anchor_priors[closed] = (A_fixed, info)
        T_new = on_plane(self._T_plane, T_world_cam, self.T_base_cam, np.radians(-hc.gain * e))
        return orthonormalize(T_new @ inv_T(T_world_cam))

    def _graph_moved(self) -> bool:
        """``planar``: whether a pose-graph run moved the (projected) anchors since the last
        call, also one whose robust loss then rejected the new arc; the anchors' version moves
        on so cached world points follow."""
        n = self.frames.topo.n_optimized
        if self._T_plane is None or n == self._planar_runs:
            return False
        self._planar_runs = n
        self.frames.anchors_version += 1
        return True

    def _initial_pose(self, prior: np.ndarray | None) -> np.ndarray:
        if prior is not None:
            return prior.copy()
        if self.T_base_cam is not None:
            return self.T_base_cam.copy()
        return np.eye(4)

    # ---- outputs -----------------------------------------------------------------------------
    def obstacle_points_world(self) -> np.ndarray:
        """(N, 3) float32 OBSTACLE points of all local frames (world, current anchors)."""
        return self.frames.obstacle_points_world()

    def floor_points_world(self) -> np.ndarray:
        """(N, 3) float32 FLOOR points of all local frames (world, current anchors)."""
        return self.frames.floor_points_world()

    @property
    def pose(self) -> np.ndarray:
        """Latest ``T_world_cam`` through the current anchor."""
        if not self._records:
            raise RuntimeError("no frame processed yet")
        _, fid, T, _ = self._records[-1]
        return self.frames.topo.anchor(fid) @ T

    def trajectory(self, corrected: bool = True) -> list[tuple[float, np.ndarray]]:
        """``[(t, T_world_cam)]`` of all frames: ``corrected`` re-expresses each frame's pose
        through the current (optimised) anchor of its local frame; otherwise the online estimates
        as returned by :meth:`process`."""
        topo = self.frames.topo
        if corrected:
            return [(t, topo.anchor(f) @ T) for t, f, T, _ in self._records]
        return [(t, Tw.copy()) for t, _, _, Tw in self._records]

    @property
    def tracking_map(self) -> str:
        """Which map frames are registered against: ``"learned"`` (the local frame's implicit
        map) or ``"points"`` (its surface point store)."""
        return "learned" if self.cfg.track_sdf == "implicit" else "points"

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "tracking_map": self.tracking_map,
            "frames": self.n_frames,
            "local_frames": len(self.frames),
            "revisits_accepted": self.n_revisits,
            "revisit_checks_dropped": self.revisits.n_dropped,
            "track_failures": self.n_track_failures,
            "map_frames_skipped": self.n_map_skipped,
            "carved_points": self.frames.n_carved,
            "dynamic_points": self.n_dynamic_points,
            "anchors_version": self.anchors_version,
        }
        if self.heading is not None:
            h = self.heading
            out["heading"] = {
                "reference_deg": h.reference_deg,
                "pools": h.n_pools,
                "clear": h.n_clear,
                "corrections": h.n_corrections,
                "gated": h.n_gated,
                "priors": len(self.frames.topo.anchor_priors),
            }
        return out

    def debug(self) -> dict[str, Any]:
        """Data for a rerun recording (:class:`simn_sim.viz.RerunRecorder`), in the SLAM world
        frame: ``local_frames`` (:meth:`LocalFrames.debug`), ``topo_nodes`` (K, 3) anchor
        positions, ``topo_arcs`` list of (2, 3) segments, ``topo_arc_kinds``, ``track_ms``,
        ``map_ms``, ``T_world_cam_est`` and (with ``T_base_cam``) ``T_world_base_est``."""
        topo = self.frames.topo
        ids = topo.frame_ids
        nodes = np.array([topo.anchor(f)[:3, 3] for f in ids]).reshape(-1, 3)
        pos = {f: nodes[k] for k, f in enumerate(ids)}
        arcs, kinds = [], []
        for i, j, e in topo.graph.edges(data=True):
            arcs.append(np.stack([pos[i], pos[j]]))
            kinds.append("loop" if "loop" in e["kinds"] else "odom")
        out: dict[str, Any] = {
            "topo_nodes": nodes,
            "topo_arcs": arcs,
            "topo_arc_kinds": kinds,
            "local_frames": self.frames.debug(),
        }
        last = self.last
        if last is not None:
            out["track_ms"], out["map_ms"] = last.track_ms, last.map_ms
            out["T_world_cam_est"] = last.T_world_cam
            if self.T_base_cam is not None:
                out["T_world_base_est"] = last.T_world_cam @ inv_T(self.T_base_cam)
        return out
