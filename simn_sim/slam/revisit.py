"""Topology: revisit checks of a newly opened local frame against earlier ones.

Candidates come from the topological map's frame descriptors
(:meth:`~simn_sim.tracking.topomap.TopoMap.candidates`), optionally filtered by overlap with
the candidate's region; each is verified by registration and an inlier test, and an accepted
revisit closes the loop with the gtsam pose graph
(:func:`~simn_sim.tracking.topomap.close_loop_steps`), moving the anchors. The check runs at
once, ``revisit_checks_per_frame`` candidates per following frame, or
``revisit_registrations_per_frame`` registrations per following frame (bounded work per step;
the same result as checking at once, since the observation and its pose are kept).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simn_sim.geometry.se3 import transform_points
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.slam.track import Tracker
from simn_sim.tracking.topomap import close_loop_steps, describe


class RevisitError(RuntimeError):
    """A revisit check could not be carried out (e.g. a candidate without a map)."""


class Revisits:
    """Revisit checks (see the module docstring). ``log`` holds one entry per finished check."""

    def __init__(self, cfg: SlamConfig, frames: LocalFrames, tracker: Tracker) -> None:
        self.cfg = cfg
        self.frames = frames
        self.tracker = tracker
        self.n_accepted = 0
        self.log: list[dict[str, Any]] = []
        # deferred checks: (frame, points, remaining candidates) or a running generator
        self._pending: tuple[int, np.ndarray, list[int]] | None = None
        self._job: tuple[int, Any] | None = None

    def _loop_register(self, fid: int, pts: np.ndarray, T_init: np.ndarray):
        """Registration callback of the check: against frame ``fid``'s SDF."""
        if self.cfg.track_sdf == "implicit":
            sdf = self.tracker.sdf_of(fid, growth=0.0)
        else:  # a wider validity radius than tracking: the drift may be decimetres
            st = self.frames.states[fid]
            if st.loop_sdf is None or st.loop_sdf[0] != len(st.surface.surface):
                P, N = st.surface.surface.points, st.surface.surface.extra
                st.loop_sdf = (len(P), self.tracker.point_sdf(P, N, self.cfg.loop_sdf_max_dist))
            st.loop_sdf[1].kernel = self.tracker.kernel if self.cfg.loop_kernel else 0.0
            sdf = st.loop_sdf[1].sdf_and_grad
        if sdf is None:
            raise RevisitError(f"frame {fid} has no map to register against")
        return self.tracker.register_c2f(pts, sdf, T_init, self.cfg.registration)

    def candidates(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray) -> list[int]:
        """Earlier frames to check for a revisit, most similar first."""
        if len(self.frames) <= self.cfg.loop.exclude_recent + 1:
            return []
        c, topo = self.cfg.loop, self.frames.topo
        Pw = transform_points(T_world_cam, pts.astype(np.float64))
        desc = describe(Pw, None, topo.desc_cfg)
        found = topo.candidates(desc, c.exclude_recent, c.top, c.min_similarity, exclude=[fid])
        out = []
        for f, _ in found:
            if self.cfg.revisit_min_overlap > 0:
                # the check moves the guess by at most max_correction_m: an observation that does
                # not reach the candidate's region grown by that much cannot pass it
                r = topo.region(f)
                g = c.max_correction_m
                inside = np.all((Pw[:, :2] >= r[:2] - g) & (Pw[:, :2] <= r[2:] + g), axis=1)
                if not np.all(np.isfinite(r)) or inside.mean() < self.cfg.revisit_min_overlap:
                    continue
            out.append(int(f))
        return out

    def _steps(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray, cands: list[int] | None):
        return close_loop_steps(
            self.frames.topo,
            fid,
            pts,
            T_world_cam,
            self._loop_register,
            self.cfg.loop,
            candidate_ids=cands,
            pose_graph_cfg=self.cfg.pose_graph,
        )

    def _advance(self, fid: int, steps: Any, budget: int | None) -> tuple[bool, int | None]:
        """Run a check for at most ``budget`` registrations (None: to the end). Returns
        (finished, accepted frame or None). A :class:`RevisitError` ends the check, logged."""
        n = 0
        try:
            while budget is None or n < budget:
                next(steps)
                n += 1
            return False, None
        except StopIteration as done:
            res = done.value
        except RevisitError as e:
            self.log.append({"frame": fid, "error": str(e)})
            return True, None
        self.log.append(
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
            }
        )
        if res.accepted is None:
            return True, None
        self.n_accepted += 1
        self.frames.anchors_version += 1
        return True, int(res.accepted)

    def _check_now(self, fid, pts, T_world_cam, cands: list[int] | None = None) -> int | None:
        if cands is None and len(self.frames) <= self.cfg.loop.exclude_recent + 1:
            return None
        return self._advance(fid, self._steps(fid, pts, T_world_cam, cands), None)[1]

    def on_open(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray) -> int | None:
        """Frame ``fid`` opened with observation ``pts`` at ``T_world_cam`` (its anchor): check
        now, or queue the check. Returns the accepted frame when checked now and accepted."""
        self._pending = self._job = None
        if not self.cfg.revisits or len(pts) < 100:
            return None
        if self.cfg.revisit_registrations_per_frame > 0:
            cands = self.candidates(fid, pts, T_world_cam)
            if cands:
                self._job = (fid, self._steps(fid, pts, T_world_cam, cands))
            return None
        if self.cfg.revisit_checks_per_frame > 0:
            cands = self.candidates(fid, pts, T_world_cam)
            if cands:
                self._pending = (fid, pts, cands)
            return None
        return self._check_now(fid, pts, T_world_cam)

    def step(self) -> int | None:
        """Advance a deferred check by this frame's budget; the accepted frame or None."""
        if self._job is not None:
            fid, steps = self._job
            done, accepted = self._advance(fid, steps, self.cfg.revisit_registrations_per_frame)
            if done:
                self._job = None
            return accepted
        if self._pending is not None:
            fid, pts, queue = self._pending
            k = self.cfg.revisit_checks_per_frame
            self._pending = (fid, pts, queue[k:]) if len(queue) > k else None
            accepted = self._check_now(fid, pts, self.frames.topo.anchor(fid), queue[:k])
            if accepted is not None:
                self._pending = None
            return accepted
        return None
