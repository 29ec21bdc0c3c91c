"""Rerun recordings of episodes, and a do-nothing recorder with the same interface.

Entity paths (all in the world frame, z up, metres; timeline ``step``):

- ``world/floorplan``: obstacle footprints of the true office (line strips at z = 0).
- ``world/goal``: the goal position.
- ``world/robot``: true base pose (transform); ``world/trajectory/true`` and
  ``world/trajectory/estimated``: driven paths (line strips).
- ``world/camera``: true camera pose; ``world/camera/image`` pinhole with ``rgb`` and ``depth``.
- ``world/local_frames/<k>/points``: feature points of local frame k, coloured by label
  (floor green, obstacle red, unknown grey).
- ``world/topo/nodes`` and ``world/topo/arcs``: the topological map.
- ``world/planner/tree`` (RRT* edges) and ``world/planner/path`` (chosen path).
- ``metrics/plan_ms``, ``metrics/map_ms``, ``metrics/track_ms``: scalar plots.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

LABEL_COLOURS = np.array(
    [[150, 150, 150], [60, 200, 80], [220, 60, 50], [80, 80, 220], [230, 160, 40]], np.uint8
)


class NullRecorder:
    """Same interface as :class:`RerunRecorder`; records nothing."""

    path: Path | None = None

    def log_layout(self, footprints: list[np.ndarray], goal_xy: np.ndarray) -> None:
        pass

    def log_step(self, step: int, obs: dict, info: dict, agent_debug: dict | None = None) -> None:
        pass

    def set_agent_frame(self, T_world_agent: np.ndarray) -> None:
        """Pose of the agent's own frame (its start frame) in the world, for drawing what an
        agent reports with ``debug()["frame"] == "start"`` over the true world."""

    def close(self) -> None:
        pass


class RerunRecorder(NullRecorder):
    """Writes one ``.rrd`` file. RGB is stored as JPEG (quality 85); ``image_every``: log the
    camera images every n-th step only (recording size)."""

    def __init__(
        self, path: str | Path, intrinsics, application_id: str = "simn_sim", image_every: int = 1
    ):
        import rerun as rr

        self.rr = rr
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.rec = rr.RecordingStream(application_id, recording_id=self.path.stem)
        self.rec.save(str(self.path))
        self.intr = intrinsics
        self.image_every = max(1, int(image_every))
        self._true: list[np.ndarray] = []
        self._T_wa = np.eye(4)
        self._est: list[np.ndarray] = []
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def log_layout(self, footprints: list[np.ndarray], goal_xy: np.ndarray) -> None:
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

    def set_agent_frame(self, T_world_agent: np.ndarray) -> None:
        self._T_wa = np.asarray(T_world_agent, float).copy()

    def _to_world(self, pts: np.ndarray, dbg: dict) -> np.ndarray:
        """(N, 2|3) agent-frame points -> world (3-D; 2-D points get z = 0)."""
        pts = np.asarray(pts, float)
        if dbg.get("frame") != "start":
            return pts
        flat = pts.reshape(-1, pts.shape[-1])
        if flat.shape[1] == 2:
            flat = np.c_[flat, np.zeros(len(flat))]
        out = flat @ self._T_wa[:3, :3].T + self._T_wa[:3, 3]
        return out.reshape(*pts.shape[:-1], 3)

    def log_step(self, step: int, obs: dict, info: dict, agent_debug: dict | None = None) -> None:
        rr = self.rr
        rec = self.rec
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
            T_est = np.asarray(dbg["T_world_base_est"], float)
            if dbg.get("frame") == "start":
                T_est = self._T_wa @ T_est
            self._est.append(T_est[:3, 3].copy())
            rec.log(
                "world/trajectory/estimated",
                rr.LineStrips3D([np.array(self._est)], colors=[[255, 120, 40]]),
            )
        rec.log("world/camera", rr.Transform3D(translation=T_wc[:3, 3], mat3x3=T_wc[:3, :3]))
        if step % self.image_every == 0:
            intr = self.intr
            rec.log(
                "world/camera/image",
                rr.Pinhole(
                    focal_length=[intr.fx, intr.fy],
                    principal_point=[intr.cx, intr.cy],
                    resolution=[intr.width, intr.height],
                    camera_xyz=rr.ViewCoordinates.RDF,
                ),
            )
            rec.log("world/camera/image/rgb", rr.Image(obs["rgb"]).compress(jpeg_quality=85))
            depth_mm = np.round(np.clip(obs["depth"], 0.0, 65.0) * 1000.0).astype(np.uint16)
            rec.log("world/camera/image/depth", rr.DepthImage(depth_mm, meter=1000.0))
        for k, pts in (dbg.get("local_frames") or {}).items():
            p, lab = pts
            p = self._to_world(p, dbg)
            rec.log(
                f"world/local_frames/{k}/points",
                rr.Points3D(
                    p, colors=LABEL_COLOURS[np.clip(lab, 0, len(LABEL_COLOURS) - 1)], radii=[0.02]
                ),
            )
        if dbg.get("topo_nodes") is not None:
            nodes = self._to_world(np.asarray(dbg["topo_nodes"], float).reshape(-1, 3), dbg)
            rec.log("world/topo/nodes", rr.Points3D(nodes, colors=[[255, 0, 255]], radii=[0.12]))
            arcs = dbg.get("topo_arcs") or []
            if arcs:
                rec.log(
                    "world/topo/arcs",
                    rr.LineStrips3D([np.asarray(a) for a in arcs], colors=[[200, 0, 200]]),
                )
        if dbg.get("tree_edges") is not None and len(dbg["tree_edges"]):
            edges = np.asarray(dbg["tree_edges"], float)  # (E, 2, 2) or (E, 2, 3)
            if edges.shape[-1] == 2:
                edges = np.concatenate([edges, np.full((*edges.shape[:2], 1), 0.02)], -1)
            edges = self._to_world(edges, dbg)
            rec.log("world/planner/tree", rr.LineStrips3D(list(edges), colors=[[160, 160, 160]]))
        if dbg.get("path") is not None and len(dbg["path"]):
            path = np.asarray(dbg["path"], float)
            if path.shape[1] == 2:
                path = np.c_[path, np.full(len(path), 0.04)]
            path = self._to_world(path, dbg)
            rec.log("world/planner/path", rr.LineStrips3D([path], colors=[[0, 220, 120]]))
        for key in ("plan_ms", "map_ms", "track_ms"):
            if dbg.get(key) is not None:
                rec.log(f"metrics/{key}", rr.Scalars(float(dbg[key])))

    def close(self) -> None:
        self.rec.flush()
        self.rec.disconnect()


def make_recorder(path: str | Path | None, intrinsics: Any = None, **kw: Any) -> NullRecorder:
    return NullRecorder() if path is None else RerunRecorder(path, intrinsics, **kw)
