"""Rerun recordings of episodes, and a do-nothing recorder with the same interface.

Entity paths (all in the world frame, z up, metres; timeline ``step``); the README's table
"Rerun recordings" lists the same (a test keeps the two equal):

- ``world``: view coordinates (z up), static.
- ``world/floorplan``: obstacle footprints of the true office (line strips at z = 0), static.
- ``world/goal``: the goal position, static.
- ``world/robot``: true base pose (transform, every step) and, static in the base frame, the
  robot body (wireframe cylinder of the robot radius over its height band) with a heading arrow.
- ``world/trajectory/true`` and ``world/trajectory/estimated``: driven paths (line strips).
- ``world/camera``: true camera pose; ``world/camera/image``: its pinhole (static);
  ``world/camera/image/rgb`` (JPEG) and ``world/camera/image/depth`` (PNG, lossless uint16 mm,
  full resolution so it stays aligned with the pinhole), both every ``image_every``-th step.
- ``world/local_frames/<k>``: pose of local frame k's anchor (world <- anchor), logged when the
  anchor moves; ``world/local_frames/<k>/points``: its points in the anchor's coordinates,
  coloured by label (floor green, obstacle red, unknown grey), logged when its version changes.
- ``world/topo/nodes`` and ``world/topo/arcs``: the topological map (logged when it changes).
- ``world/planner/tree`` (RRT* edges, cyan) and ``world/planner/path`` (chosen path, green),
  logged when they change.
- ``metrics/plan_ms``, ``metrics/map_ms``, ``metrics/track_ms``: timings in ms.

Everything an agent reports with ``debug()["frame"] == "start"`` is in its own start frame and
is drawn through :meth:`RerunRecorder.set_agent_frame` (the true start pose). A default
blueprint (:func:`default_blueprint`) goes into the file: a large 3-D view, separate rgb and
depth views and one small timing plot.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

LABEL_COLOURS = np.array(
    [[150, 150, 150], [60, 200, 80], [220, 60, 50], [80, 80, 220], [230, 160, 40]], np.uint8
)
TREE_COLOUR = (0, 200, 220)  # cyan: clearly apart from the grey floor plan
METRICS = {"plan_ms": "plan (ms)", "map_ms": "map (ms)", "track_ms": "track (ms)"}


def default_blueprint() -> Any:
    """The layout a recording opens with: the 3-D world view on the left (two thirds), on the
    right the rgb and the depth image in separate views and below them one small time-series
    view with all timings (ms). The depth image is left out of the 3-D view (the local frame
    points show the geometry); the rgb image stays in the camera frustum."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="world",
                origin="world",
                contents=["+ $origin/**", "- $origin/camera/image/depth"],
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="rgb", origin="world/camera/image", contents="$origin/rgb"),
                rrb.Spatial2DView(
                    name="depth", origin="world/camera/image", contents="$origin/depth"
                ),
                rrb.TimeSeriesView(
                    name="timings (ms)",
                    origin="metrics",
                    plot_legend=rrb.PlotLegend(visible=True),
                ),
                row_shares=[2.0, 2.0, 1.4],
            ),
            column_shares=[2.0, 1.0],
        ),
        collapse_panels=True,
    )


class NullRecorder:
    """Same interface as :class:`RerunRecorder`; records nothing."""

    path: Path | None = None

    def log_layout(
        self,
        footprints: list[np.ndarray],
        goal_xy: np.ndarray,
        robot_radius: float | None = None,
        robot_z: tuple[float, float] | None = None,
    ) -> None:
        pass

    def log_step(self, step: int, obs: dict, info: dict, agent_debug: dict | None = None) -> None:
        pass

    def set_agent_frame(self, T_world_agent: np.ndarray) -> None:
        """Pose of the agent's own frame (its start frame) in the world, for drawing what an
        agent reports with ``debug()["frame"] == "start"`` over the true world."""

    def close(self) -> None:
        pass


def _changed(old: Any, new: Any) -> bool:
    if old is None or new is None:
        return old is not new
    return old.shape != new.shape or not np.array_equal(old, new)


class RerunRecorder(NullRecorder):
    """Writes one ``.rrd`` file (with :func:`default_blueprint`).

    Size: rgb is JPEG (``jpeg_quality``), depth is a lossless PNG of uint16 mm at full
    resolution, both every ``image_every``-th step; the pinhole is static. The topological map,
    the planner tree and path are logged only when they change. Local frames
    (``debug()["local_frames"]``: ``{k: {"T_anchor", "points", "labels", "version"}}``): the
    anchor transform is logged only when the anchor moved; a frame's points when it first
    appears, then when ``version`` changed, but at most every ``points_every`` steps (a frame
    that keeps growing is drawn up to ``points_every - 1`` steps late; its last version is
    written at :meth:`close` at the latest); frames no longer reported are cleared.
    """

    def __init__(
        self,
        path: str | Path,
        intrinsics,
        application_id: str = "simn_sim",
        image_every: int = 2,
        points_every: int = 10,
        jpeg_quality: int = 85,
    ):
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(application_id, recording_id=self.path.stem)
        self.rec.save(str(self.path), default_blueprint=default_blueprint())
        self.intr = intrinsics
        self.image_every = max(1, int(image_every))
        self.points_every = max(1, int(points_every))
        self.jpeg_quality = int(jpeg_quality)
        self._true: list[np.ndarray] = []
        self._T_wa = np.eye(4)
        self._est: list[np.ndarray] = []
        self._last: dict[str, Any] = {}  # entity -> last logged array (log on change)
        self._lf_T: dict[int, np.ndarray] = {}  # frame -> last logged world <- anchor
        self._lf_ver: dict[int, Any] = {}  # frame -> last logged points version
        self._lf_step: dict[int, int] = {}  # frame -> step of that log
        self._lf_pending: dict[int, dict] = {}  # frame -> newest unlogged entry
        self._metric_named: set[str] = set()
        self._step = 0
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if intrinsics is not None:
            self.rec.log(
                "world/camera/image",
                rr.Pinhole(
                    focal_length=[intrinsics.fx, intrinsics.fy],
                    principal_point=[intrinsics.cx, intrinsics.cy],
                    resolution=[intrinsics.width, intrinsics.height],
                    camera_xyz=rr.ViewCoordinates.RDF,
                    image_plane_distance=0.4,
                ),
                static=True,
            )

    def log_layout(
        self,
        footprints: list[np.ndarray],
        goal_xy: np.ndarray,
        robot_radius: float | None = None,
        robot_z: tuple[float, float] | None = None,
    ) -> None:
        rr = self.rr
        strips = [np.c_[np.vstack([f, f[:1]]), np.zeros(len(f) + 1)] for f in footprints]
        self.rec.log(
            "world/floorplan", rr.LineStrips3D(strips, colors=[[120, 120, 120]]), static=True
        )
        self.rec.log(
            "world/goal",
            rr.Points3D([[goal_xy[0], goal_xy[1], 0.05]], colors=[[255, 200, 0]], radii=[0.15]),
            static=True,
        )
        if robot_radius is not None:
            z0, z1 = robot_z if robot_z is not None else (0.0, 0.9)
            r = float(robot_radius)
            self.rec.log(
                "world/robot",
                rr.Cylinders3D(
                    lengths=[z1 - z0],
                    radii=[r],
                    centers=[[0.0, 0.0, 0.5 * (z0 + z1)]],
                    colors=[[40, 160, 255]],
                    fill_mode=rr.components.FillMode.MajorWireframe,
                ),
                rr.Arrows3D(
                    origins=[[0.0, 0.0, z1]], vectors=[[1.6 * r, 0.0, 0.0]], colors=[[40, 160, 255]]
                ),
                static=True,
            )

    def set_agent_frame(self, T_world_agent: np.ndarray) -> None:
        T = np.asarray(T_world_agent, float).copy()
        if not np.array_equal(T, self._T_wa):  # re-log what is drawn through the old pose
            self._lf_T.clear()
            self._last.clear()
        self._T_wa = T

    def _to_world(self, pts: np.ndarray, dbg: dict) -> np.ndarray:
        """(..., 2|3) agent-frame points -> world (..., 3) (2-D points get z = 0)."""
        pts = np.asarray(pts, float)
        if pts.shape[-1] == 2:
            pts = np.concatenate([pts, np.zeros((*pts.shape[:-1], 1))], -1)
        if dbg.get("frame") != "start":
            return pts
        return pts @ self._T_wa[:3, :3].T + self._T_wa[:3, 3]

    def _pose_to_world(self, T: np.ndarray, dbg: dict) -> np.ndarray:
        T = np.asarray(T, float)
        return self._T_wa @ T if dbg.get("frame") == "start" else T

    def _log_if_changed(self, entity: str, value: np.ndarray | None, make) -> None:
        """Log ``make(value)`` at ``entity`` when ``value`` differs from the last logged one;
        a value that disappears (None / empty) clears the entity."""
        if value is not None and len(value) == 0:
            value = None
        old = self._last.get(entity)
        if not _changed(old, value):
            return
        self._last[entity] = None if value is None else value.copy()
        if value is None:
            self.rec.log(entity, self.rr.Clear(recursive=False))
        else:
            self.rec.log(entity, make(value))

    def _log_local_frames(self, frames: Any, dbg: dict, step: int) -> None:
        rr = self.rr
        if not isinstance(frames, dict):
            return  # not reported
        given = frames
        frames = {
            int(k): v
            for k, v in given.items()
            if isinstance(v, dict) and "T_anchor" in v and "points" in v
        }
        if given and not frames:
            return  # an older shape of the key ({"current": (points, labels)}): not drawn
        for k in sorted(set(self._lf_ver) | set(self._lf_T)):
            if k not in frames:  # the frame is gone (merged / dropped)
                self.rec.log(f"world/local_frames/{k}", rr.Clear(recursive=True))
                for d in (self._lf_T, self._lf_ver, self._lf_step, self._lf_pending):
                    d.pop(k, None)
        for k, fr in sorted(frames.items()):
            T = self._pose_to_world(fr["T_anchor"], dbg)
            old_T = self._lf_T.get(k)
            if old_T is None or not np.allclose(old_T, T, rtol=0.0, atol=1e-6):
                self.rec.log(
                    f"world/local_frames/{k}",
                    rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
                )
                self._lf_T[k] = T
            ver = fr.get("version")
            if k in self._lf_ver and self._lf_ver[k] == ver:
                self._lf_pending.pop(k, None)
                continue
            last = self._lf_step.get(k)
            if last is not None and step - last < self.points_every:
                self._lf_pending[k] = fr  # still growing: wait a few steps
                continue
            self._log_frame_points(k, fr, step)

    def _log_frame_points(self, k: int, fr: dict, step: int) -> None:
        rr = self.rr
        pts = np.asarray(fr["points"], np.float32).reshape(-1, 3)
        lab = np.asarray(fr.get("labels", np.zeros(len(pts))), np.int64).reshape(-1)
        cols = LABEL_COLOURS[np.clip(lab, 0, len(LABEL_COLOURS) - 1)]
        self.rec.log(f"world/local_frames/{k}/points", rr.Points3D(pts, colors=cols, radii=[0.02]))
        self._lf_ver[k] = fr.get("version")
        self._lf_step[k] = step
        self._lf_pending.pop(k, None)

    def log_step(self, step: int, obs: dict, info: dict, agent_debug: dict | None = None) -> None:
        rr = self.rr
        rec = self.rec
        self._step = int(step)
        rec.set_time("step", sequence=int(step))
        T_wb = info["T_world_base"]
        T_wc = info["T_world_cam"]
        rec.log("world/robot", rr.Transform3D(translation=T_wb[:3, 3], mat3x3=T_wb[:3, :3]))
        self._true.append(T_wb[:3, 3].copy())
        rec.log(
            "world/trajectory/true",
            rr.LineStrips3D([np.array(self._true)], colors=[[40, 160, 255]]),
        )
        dbg = agent_debug or {}
        if dbg.get("T_world_base_est") is not None:
            T_est = self._pose_to_world(dbg["T_world_base_est"], dbg)
            self._est.append(T_est[:3, 3].copy())
            rec.log(
                "world/trajectory/estimated",
                rr.LineStrips3D([np.array(self._est)], colors=[[255, 120, 40]]),
            )
        rec.log("world/camera", rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]))
        if step % self.image_every == 0:
            rgb = np.ascontiguousarray(obs["rgb"])
            rec.log(
                "world/camera/image/rgb", rr.Image(rgb).compress(jpeg_quality=self.jpeg_quality)
            )
            depth_mm = np.round(np.clip(np.nan_to_num(obs["depth"]), 0.0, 65.0) * 1000.0)
            rec.log(
                "world/camera/image/depth",
                rr.DepthImage(depth_mm.astype(np.uint16), meter=1000.0).compress(),
            )
        self._log_local_frames(dbg.get("local_frames"), dbg, int(step))
        nodes = dbg.get("topo_nodes")
        if nodes is not None:
            nodes = self._to_world(np.asarray(nodes, float).reshape(-1, 3), dbg)
            self._log_if_changed(
                "world/topo/nodes",
                nodes,
                lambda v: rr.Points3D(v, colors=[[255, 0, 255]], radii=[0.12]),
            )
            arcs = dbg.get("topo_arcs")
            arcs = (
                self._to_world(np.asarray(arcs, float).reshape(-1, 2, 3), dbg)
                if arcs is not None and len(arcs)
                else None
            )
            self._log_if_changed(
                "world/topo/arcs", arcs, lambda v: rr.LineStrips3D(v, colors=[[200, 0, 200]])
            )
        edges = dbg.get("tree_edges")
        if edges is not None and len(edges):
            edges = np.asarray(edges, float)  # (E, 2, 2) or (E, 2, 3)
            if edges.shape[-1] == 2:
                edges = np.concatenate([edges, np.full((*edges.shape[:2], 1), 0.02)], -1)
            edges = self._to_world(edges, dbg)
        self._log_if_changed(
            "world/planner/tree",
            None if edges is None or not len(edges) else edges,
            lambda v: rr.LineStrips3D(v, colors=[TREE_COLOUR], radii=[0.008]),
        )
        path = dbg.get("path")
        if path is not None and len(path):
            path = np.asarray(path, float)
            if path.shape[1] == 2:
                path = np.c_[path, np.full(len(path), 0.04)]
            path = self._to_world(path, dbg)
        self._log_if_changed(
            "world/planner/path",
            None if path is None or not len(path) else path,
            lambda v: rr.LineStrips3D([v], colors=[[0, 220, 120]], radii=[0.025]),
        )
        for key, name in METRICS.items():
            if dbg.get(key) is not None:
                if key not in self._metric_named:
                    rec.log(f"metrics/{key}", rr.SeriesLines(names=name), static=True)
                    self._metric_named.add(key)
                rec.log(f"metrics/{key}", rr.Scalars(float(dbg[key])))

    def close(self) -> None:
        if self._lf_pending:  # the newest version of a still-growing frame
            self.rec.set_time("step", sequence=self._step)
            for k, fr in sorted(self._lf_pending.items()):
                self._log_frame_points(k, fr, self._step)
        self.rec.flush()
        self.rec.disconnect()


def make_recorder(path: str | Path | None, intrinsics: Any = None, **kw: Any) -> NullRecorder:
    return NullRecorder() if path is None else RerunRecorder(path, intrinsics, **kw)
