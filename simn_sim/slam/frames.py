"""The one owner of the spatial-implicit local frames: their maps, point stores and carving.

Each local frame has a map in its anchor coordinates (the learned
:class:`~simn_sim.mapping.mapper.ImplicitMap`, or the learning-free :class:`PointFrameMap`),
a surface store (the tracking model: ``surface_voxel`` grid with normals), and obstacle / floor
stores (``StoreConfig``) that feed the planner. Anchors live in the topological map
(:class:`~simn_sim.tracking.topomap.TopoMap`); moving an anchor (pose graph) moves everything
of its frame rigidly. Free-space carving (:meth:`LocalFrames.carve`) removes stored obstacle
points of the recent frames that the current depth image sees through.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from simn_sim.geometry.bounds import column_bounds
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.geometry.voxel import VoxelStore
from simn_sim.mapping.mapper import ImplicitMap
from simn_sim.perception.frame import Frame
from simn_sim.semantics import FLOOR, OBSTACLE
from simn_sim.slam.config import SlamConfig
from simn_sim.tracking.lie import se3_log
from simn_sim.tracking.localframes import LocalFrame, unpack_feature_points
from simn_sim.tracking.pointsdf import PointCloudSDF
from simn_sim.tracking.posegraph import covariance_from_sigmas
from simn_sim.tracking.topomap import TopoMap


class PointFrameMap:
    """The learning-free per-frame map (``map_kind="points"``): a surface voxel store with
    normals in anchor coordinates; ``sdf_and_grad`` is its point-to-plane SDF. Implements the
    :class:`~simn_sim.tracking.localframes.FrameMap` protocol (no learned features)."""

    def __init__(
        self,
        surface: VoxelStore,
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
        """The point-to-plane SDF, rebuilt when the store grew by ``rebuild_growth``; None while
        the store has fewer than 50 points."""
        n = len(self.surface)
        if n < 50:
            return None
        if self._sdf is None or n > self._n * (1 + rebuild_growth) or n < self._n:
            try:
                sdf = PointCloudSDF(
                    self.surface.points,
                    self.surface.extra,
                    max_dist=self.max_dist,
                    kernel=self.kernel,
                    k=self.k,
                    confidence=self.surface.count if self.count_weight else None,
                    normal_gate=self.normal_gate,
                )
            except ValueError:  # no usable normals yet: no model (tracking says "no map")
                return None
            self._sdf, self._n = sdf, n
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
class FrameState:
    """Everything of one local frame (anchor coordinates)."""

    frame: LocalFrame
    obstacles: VoxelStore
    floor: VoxelStore
    surface: PointFrameMap  # tracking model (surface_voxel grid + normals)
    n_trained: int = 0
    n_obs: int = 0
    loop_sdf: tuple[int, PointCloudSDF] | None = None


class LocalFrames:
    """The local frames of one run: open / close, their stores, carving, and the planner's
    obstacle and floor points through the current anchors."""

    def __init__(self, cfg: SlamConfig) -> None:
        self.cfg = cfg
        self.topo = TopoMap(cfg.descriptor)
        self.states: dict[int, FrameState] = {}
        self.current_id = -1
        self.anchors_version = 0  # increments whenever the pose graph moves anchors
        self.n_carved = 0  # obstacle points removed by carving, in all
        self._base_map: ImplicitMap | None = None
        self._obst_cache: tuple[tuple, np.ndarray] | None = None
        self._observed_cache: tuple[tuple, np.ndarray] | None = None
        # per frame: (version, points, labels) of the last debug() (recorders ask every step)
        self._debug_cache: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self._floor_cache: tuple[tuple, np.ndarray] | None = None
        # per frame: (obstacle store version, centre, radius) of its points (carve)
        self._bounds_cache: dict[int, tuple[int, np.ndarray, float]] = {}

    def __len__(self) -> int:
        return len(self.states)

    @property
    def current(self) -> FrameState:
        return self.states[self.current_id]

    # ---- lifecycle ---------------------------------------------------------------------------
    def point_map(self, surface: VoxelStore) -> PointFrameMap:
        c = self.cfg
        return PointFrameMap(
            surface,
            c.point_sdf_max_dist,
            c.point_sdf_kernel,
            c.point_sdf_k,
            c.point_sdf_count_weight,
            np.cos(np.radians(c.point_sdf_normal_gate_deg)),
        )

    def _new_map(self, surface: VoxelStore):
        if self.cfg.map_kind == "points":
            return self.point_map(surface)
        if self._base_map is None:
            self._base_map = ImplicitMap(self.cfg.mapper)
            return self._base_map
        # share_decoder: one F_theta (with its EWC state and the closed frames' replay) for all
        # frames; otherwise each frame starts from a copy of the previous frame's decoder
        return self.current.frame.map.new_map(share_decoder=self.cfg.share_decoder)

    def open(self, T_world_cam: np.ndarray, t: float) -> int:
        """Open a frame anchored at ``T_world_cam``, with an odometry arc from the current one."""
        c = self.cfg
        fid = len(self.states)
        surface = VoxelStore(c.surface_voxel, keep=c.surface_keep, extra_dim=3)
        frame = LocalFrame(fid, T_world_cam.copy(), self._new_map(surface), t_start=t, t_end=t)
        self.states[fid] = FrameState(
            frame,
            # extras: each point where it was observed (world, through the anchor of then)
            VoxelStore(c.stores.obstacle_voxel, extra_dim=3),
            VoxelStore(c.stores.floor_voxel),
            frame.map if isinstance(frame.map, PointFrameMap) else self.point_map(surface),
        )
        self.topo.add_frame(frame)
        prev = self.current_id
        if prev >= 0:
            T_pc = inv_T(self.topo.anchor(prev)) @ T_world_cam
            ang = float(np.linalg.norm(se3_log(T_pc)[:3]))
            dist = float(np.linalg.norm(T_pc[:3, 3]))
            cov = covariance_from_sigmas(
                c.odom_sigma_rot + c.odom_sigma_rot_per_rad * ang,
                c.odom_sigma_trans + c.odom_sigma_trans_per_m * dist,
            )
            self.topo.add_arc(prev, fid, T_pc, cov)
        self.current_id = fid
        return fid

    def close(self, fid: int) -> None:
        """Close frame ``fid``: a learned map trains on what is pending and is closed (EWC
        Fisher added to the shared decoder's, a share of its samples joins the replay of later
        frames: :meth:`ImplicitMap.close`); its topological node is refreshed."""
        st = self.states[fid]
        if isinstance(st.frame.map, ImplicitMap):
            if st.n_trained and st.frame.map.n_pending:
                st.frame.map.train(self.cfg.train_iters)
            st.frame.map.close()
        if len(unpack_feature_points(st.frame.map.feature_points())[0]):
            self.topo.refresh(fid)

    def implicit_maps(self) -> dict[int, ImplicitMap]:
        """``{frame id: learned map}`` of the frames with a learned map."""
        return {
            f: s.frame.map for f, s in self.states.items() if isinstance(s.frame.map, ImplicitMap)
        }

    def save_maps(self, path) -> None:
        """Write the frames' learned maps to one file, a shared decoder once
        (:func:`~simn_sim.mapping.persistence.save_frame_maps`; read with
        :meth:`ImplicitMap.load_frames`)."""
        from simn_sim.mapping.persistence import save_frame_maps

        return save_frame_maps(self.implicit_maps(), path)

    # ---- stores ------------------------------------------------------------------------------
    def store(self, st: FrameState, frame: Frame, T_anchor_cam: np.ndarray) -> None:
        """Add a labelled frame's obstacle and floor points to frame ``st``'s stores."""
        if len(frame) == 0 or frame.labels is None:
            return
        Pa = transform_points(T_anchor_cam, frame.points.astype(np.float64)).astype(np.float32)
        Po = Pa[frame.labels == OBSTACLE]
        T_wa = self.topo.anchor(st.frame.frame_id)
        st.obstacles.add(Po, transform_points(T_wa, Po.astype(np.float64)).astype(np.float32))
        st.floor.add(Pa[frame.labels == FLOOR])

    def restamp_observed(self, fid: int) -> None:
        """Frame ``fid``'s obstacle points observed where its current anchor puts them: for a
        frame whose anchor a revisit moved right after its first (and only) view was stored."""
        st = self.states[fid]
        P = st.obstacles.points.astype(np.float64)
        st.obstacles.extra = transform_points(self.topo.anchor(fid), P).astype(np.float32)
        st.obstacles.version += 1

    def carve(self, frame: Frame, T_world_cam: np.ndarray) -> int:
        """Remove stored obstacle points of the recent frames (``stores.carve_frames``; 0: every
        local frame) that ``frame`` sees through; returns how many were removed. A frame whose
        points all lie too deep for the view to see past them, or all behind the camera, is
        skipped on its bounding sphere (the same points are removed as without the test)."""
        zimg, s, intr = frame.depth, frame.stride, frame.intrinsics
        hh, ww = zimg.shape
        sc = self.cfg.stores
        T_cam_world = inv_T(T_world_cam)
        zmax = float(zimg.max()) if zimg.size else 0.0
        ids = sorted(self.states)
        removed = 0
        for fid in ids[-sc.carve_frames :] if sc.carve_frames > 0 else ids:
            st = self.states[fid]
            if len(st.obstacles) == 0:
                continue
            T = T_cam_world @ self.topo.anchor(fid)
            if self.beyond_view(fid, T, zmax):
                continue
            pc = transform_points(T, st.obstacles.points.astype(np.float64))
            z = pc[:, 2]
            front = z > self.cfg.perception.min_depth
            u = np.round((intr.fx * pc[:, 0] / np.where(front, z, 1) + intr.cx) / s).astype(int)
            v = np.round((intr.fy * pc[:, 1] / np.where(front, z, 1) + intr.cy) / s).astype(int)
            inside = front & (u >= 0) & (u < ww) & (v >= 0) & (v < hh)
            zo = np.zeros(len(z))
            zo[inside] = zimg[v[inside], u[inside]]
            through = inside & (zo > 0) & (zo > z + sc.carve_margin)
            if through.any():
                st.obstacles.remove(through)
                removed += int(through.sum())
        if removed:
            self._obst_cache = None
        self.n_carved += removed
        return removed

    def beyond_view(self, fid: int, T_cam_anchor: np.ndarray, zmax: float) -> bool:
        """Whether no obstacle point of frame ``fid`` can be seen through by a view at
        ``T_cam_anchor`` whose deepest reading is ``zmax``: by the points' bounding sphere, all
        of them deeper than ``zmax`` less the carve margin, or all behind the camera (1 um of
        slack keeps the test conservative against rounding)."""
        centre, radius = self._bounds(fid, self.states[fid])
        cz = float(T_cam_anchor[2, :3] @ centre + T_cam_anchor[2, 3])
        return (
            cz - radius + self.cfg.stores.carve_margin >= zmax + 1e-6
            or cz + radius <= self.cfg.perception.min_depth - 1e-6
        )

    def _bounds(self, fid: int, st: FrameState) -> tuple[np.ndarray, float]:
        """(centre, radius) of a sphere holding frame ``fid``'s obstacle points (anchor
        coordinates), kept per store version."""
        b = self._bounds_cache.get(fid)
        if b is None or b[0] != st.obstacles.version:
            P = st.obstacles.points.astype(np.float64)
            lo, hi = column_bounds(P)
            c = 0.5 * (lo + hi)
            b = self._bounds_cache[fid] = (
                st.obstacles.version,
                c,
                float(np.sqrt(((P - c) ** 2).sum(axis=1).max())),
            )
        return b[1], b[2]

    # ---- outputs -----------------------------------------------------------------------------
    def _world_points(
        self, which: str, cache: tuple | None, min_frame: int = 0, observed: bool = False
    ) -> tuple[tuple, np.ndarray]:
        """``(key, points)``: store ``which`` of the frames with id >= ``min_frame``, stacked in
        frame order, through the current anchors; ``observed``: the stores' extras instead
        (where each point was observed, which anchor moves do not change)."""
        key = (
            None if observed else self.anchors_version,
            min_frame,
            *((f, getattr(s, which).version) for f, s in self.states.items() if f >= min_frame),
        )
        if cache is not None and cache[0] == key:
            return cache
        parts = [
            getattr(s, which).extra
            if observed
            else transform_points(self.topo.anchor(f), getattr(s, which).points.astype(np.float64))
            for f, s in self.states.items()
            if f >= min_frame and len(getattr(s, which))
        ]
        pts = np.concatenate(parts).astype(np.float32) if parts else np.zeros((0, 3), np.float32)
        return key, pts

    def obstacle_points_world(self, min_frame: int = 0) -> np.ndarray:
        """(N, 3) float32 OBSTACLE points of the local frames with id >= ``min_frame`` (0: all),
        world coordinates through the current anchors (one point per ``stores.obstacle_voxel``
        voxel per frame)."""
        self._obst_cache = self._world_points("obstacles", self._obst_cache, min_frame)
        return self._obst_cache[1]

    def obstacle_points_observed(self, min_frame: int = 0) -> np.ndarray:
        """(N, 3) float32: the points of :meth:`obstacle_points_world` (same order) where they
        were observed, in the world through the anchors of the view that stored them (what
        :class:`~simn_sim.world.transient.TransientCells` saw; the pose graph moves anchors
        later, and the points with them, but not the views' records)."""
        self._observed_cache = self._world_points(
            "obstacles", self._observed_cache, min_frame, observed=True
        )
        return self._observed_cache[1]

    def floor_points_world(self) -> np.ndarray:
        """(N, 3) float32 FLOOR points of all local frames (world)."""
        self._floor_cache = self._world_points("floor", self._floor_cache)
        return self._floor_cache[1]

    def debug(self) -> dict[int, dict[str, Any]]:
        """Per local frame, for recordings: ``T_anchor`` (4, 4) world <- anchor, ``points`` (N, 3)
        float32 anchor coordinates (obstacle then floor), ``labels`` (N,) int8, ``version``."""
        out: dict[int, dict[str, Any]] = {}
        for f, s in self.states.items():
            version = s.obstacles.version + s.floor.version  # both only grow
            cached = self._debug_cache.get(f)
            if cached is None or cached[0] != version:
                P = np.concatenate([s.obstacles.points, s.floor.points])
                lab = np.concatenate(
                    [
                        np.full(len(s.obstacles), OBSTACLE, np.int8),
                        np.full(len(s.floor), FLOOR, np.int8),
                    ]
                )
                cached = self._debug_cache[f] = (version, P, lab)
            out[f] = {
                "T_anchor": self.topo.anchor(f),
                "points": cached[1],
                "labels": cached[2],
                "version": version,
            }
        return out
