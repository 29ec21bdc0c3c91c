"""Topology: revisit checks of a newly opened local frame against earlier ones.

Candidates are ranked (``SlamConfig.revisit_features``, :meth:`Revisits.candidates`) by

* ``learned`` (the default with the learned map): the new frame's neural key points, trained on
  its first observation, matched to each earlier frame's key points by their learned feature
  vectors (:class:`~simn_sim.tracking.descriptors.KeyPointIndex`, through the anchors);
* ``keypoints``: the same matching without the features (the share of key points in reach);
* ``geometric`` (the default with the point store): the topological map's pooled frame
  descriptors (:meth:`~simn_sim.tracking.topomap.TopoMap.candidates`) of the observation;

optionally filtered by overlap with the candidate's region; each is verified by registration
and an inlier test, and an accepted
revisit closes the loop with the gtsam pose graph
(:func:`~simn_sim.tracking.topomap.close_loop_steps`), moving the anchors. The check runs at
once, ``revisit_checks_per_frame`` candidates per following frame, or
``revisit_registrations_per_frame`` registrations per following frame (bounded work per step;
the same result as checking at once, since the observation and its pose are kept).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simn_sim.geometry.bounds import column_bounds
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.frames import LocalFrames
from simn_sim.slam.track import Tracker
from simn_sim.tracking.descriptors import KeyPointIndex
from simn_sim.tracking.localframes import unpack_feature_points
from simn_sim.tracking.topomap import close_loop_steps, describe, verify_candidate_steps

RANKINGS = ("learned", "keypoints", "geometric")
Ranked = list[tuple[int, float]]  # (frame, score) candidates, best first


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
        # deferred checks, each with its ranked candidates (logged when it ends): (frame,
        # points, remaining candidates, ranked) or (frame, running generator, ranked)
        self._pending: tuple[int, np.ndarray, Ranked, Ranked] | None = None
        self._job: tuple[int, Any, Ranked] | None = None
        self._next: tuple[int, Any, Ranked] | None = None  # revisit_finish_checks: waiting
        self.n_dropped = 0  # deferred checks dropped before they finished
        f = cfg.revisit_features
        self.ranking = (
            f if f != "auto" else ("learned" if cfg.map_kind == "implicit" else "geometric")
        )
        # per frame: (key, KeyPointIndex) while the frame's map is unchanged
        self._index: dict[int, tuple[tuple, KeyPointIndex | None]] = {}

    def _loop_register(self, fid: int, pts: np.ndarray, T_init: np.ndarray):
        """Registration callback of the check: against frame ``fid``'s SDF."""
        if self.cfg.track_sdf == "implicit" and self.cfg.revisit_sdf == "tracking":
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
        # planar_registration: on the floor plane, as tracking (the anchors are on it)
        return self.tracker.register_c2f(
            pts, sdf, T_init, self.cfg.registration, up=self.tracker.up_cam
        )

    def _key_points(self, fid: int) -> KeyPointIndex | None:
        """Frame ``fid``'s key points and learned features (anchor coordinates), indexed; None
        for a frame without key points. Rebuilt when its map grew or trained."""
        m = self.frames.topo.frame(fid).map
        if hasattr(m, "n_trainings"):  # ImplicitMap: points are only added; training moves f
            key: tuple | None = (len(m.points), m.n_trainings)
        elif hasattr(m, "surface"):  # PointFrameMap: its surface store
            key = (len(m.surface), m.surface.version)
        else:
            key = None
        hit = self._index.get(fid)
        if key is not None and hit is not None and hit[0] == key:
            return hit[1]
        P, F, _ = unpack_feature_points(m.feature_points())
        idx = KeyPointIndex(P, F) if len(P) else None
        self._index[fid] = (key, idx)
        return idx

    def _rank_key_points(self, fid: int, use_features: bool) -> list[tuple[int, float]] | None:
        """Earlier frames scored by matching frame ``fid``'s key points to theirs; None when
        ``fid`` has no key points yet."""
        c, topo, dc = self.cfg.loop, self.frames.topo, self.frames.topo.desc_cfg
        q = self._key_points(fid)
        if q is None:
            return None
        tree_pts = q.tree.data
        stride = -(-len(tree_pts) // dc.match_points)
        Pq, Fq = tree_pts[::stride], q.features[::stride]
        Fq = Fq if use_features and q.has_features else None
        A = topo.anchor(fid)
        Pw = transform_points(A, Pq)
        lo, hi = column_bounds(Pw[:, :2])
        skip = {fid, *topo.frame_ids[-c.exclude_recent :]} if c.exclude_recent else {fid}
        out = []
        for f in topo.frame_ids:
            if f in skip:
                continue
            r = topo.region(f)
            g = dc.match_radius
            if not np.all(np.isfinite(r)) or np.any(lo > r[2:] + g) or np.any(hi < r[:2] - g):
                continue  # no key point of the observation can reach the frame's
            idx = self._key_points(f)
            if idx is None:
                continue
            T = inv_T(topo.anchor(f)) @ A
            score, reach = idx.match(transform_points(T, Pq), Fq, dc)
            if reach >= c.min_reach and (Fq is None or score >= c.min_match):
                out.append((int(f), score))
        out.sort(key=lambda x: -x[1])
        return out[: c.top]

    def candidates(
        self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray, ranking: str | None = None
    ) -> list[tuple[int, float]]:
        """Earlier frames to check for a revisit, ``[(frame, score)]`` best first, ranked by
        ``ranking`` (default: :attr:`ranking`; see the module docstring). ``pts``: the
        observation (camera frame) at ``T_world_cam``, which the geometric ranking describes;
        the key-point rankings use frame ``fid``'s map (the observation integrated), and fall
        back to the geometric ranking while it has no key points."""
        ranking = ranking or self.ranking
        if ranking not in RANKINGS:
            raise ValueError(f"ranking must be one of {RANKINGS}, got {ranking!r}")
        if len(self.frames) <= self.cfg.loop.exclude_recent + 1:
            return []
        c, topo = self.cfg.loop, self.frames.topo
        Pw = transform_points(T_world_cam, pts.astype(np.float64))
        found = None
        if ranking != "geometric":
            found = self._rank_key_points(fid, use_features=ranking == "learned")
        if found is None:
            desc = describe(Pw, None, topo.desc_cfg)
            found = topo.candidates(desc, c.exclude_recent, c.top, c.min_similarity, exclude=[fid])
        out = []
        for f, sim in found:
            if self.cfg.revisit_min_overlap > 0:
                # the check moves the guess by at most max_correction_m: an observation that does
                # not reach the candidate's region grown by that much cannot pass it
                r = topo.region(f)
                g = c.max_correction_m
                inside = np.all((Pw[:, :2] >= r[:2] - g) & (Pw[:, :2] <= r[2:] + g), axis=1)
                if not np.all(np.isfinite(r)) or inside.mean() < self.cfg.revisit_min_overlap:
                    continue
            out.append((int(f), float(sim)))
        return out

    def verify(self, candidate: int, pts: np.ndarray, T_world_cam: np.ndarray) -> bool:
        """Whether the observation ``pts`` (camera frame, taken at ``T_world_cam``) passes the
        revisit check's registration against frame ``candidate``; adds no loop and moves no
        anchor (for measuring candidates, e.g. ``scripts/bench_revisits.py``)."""
        steps = verify_candidate_steps(
            self.frames.topo, candidate, pts, T_world_cam, self._loop_register, self.cfg.loop
        )
        try:
            while True:
                next(steps)
        except StopIteration as done:
            return done.value[0] is not None
        except RevisitError:
            return False

    def _steps(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray, cands: list | None):
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

    def _advance(
        self, fid: int, steps: Any, budget: int | None, ranked: Ranked
    ) -> tuple[bool, int | None]:
        """Run a check for at most ``budget`` registrations (None: to the end). Returns
        (finished, accepted frame or None). A :class:`RevisitError` ends the check, logged;
        ``ranked``: the frame's ranked candidates, for the log."""
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
                "ranking": self.ranking,
                "candidates": [[f, round(v, 4)] for f, v in ranked],
                "accepted": res.accepted,
                # the loop arc: this frame's anchor in the accepted frame (None if none)
                "T_i_j": None if res.T_i_j is None else np.asarray(res.T_i_j).tolist(),
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

    def _check_now(self, fid, pts, T_world_cam, cands: list, ranked: list) -> int | None:
        return self._advance(fid, self._steps(fid, pts, T_world_cam, cands), None, ranked)[1]

    def on_open(self, fid: int, pts: np.ndarray, T_world_cam: np.ndarray) -> int | None:
        """Frame ``fid`` opened with observation ``pts`` at ``T_world_cam`` (its anchor) and
        the observation integrated into its map: check now, or queue the check. Returns the
        accepted frame when checked now and accepted. A deferred check still running is
        dropped, or with ``revisit_finish_checks`` finished first while the new one waits (a
        newer frame's check replaces a waiting one)."""
        finish = self.cfg.revisit_finish_checks and self.cfg.revisit_registrations_per_frame > 0
        if not finish:
            self.n_dropped += int(self._job is not None or self._pending is not None)
            self._pending = self._job = None
        if not self.cfg.revisits or len(pts) < 100:
            return None
        if len(self.frames) <= self.cfg.loop.exclude_recent + 1:
            return None
        cands = self.candidates(fid, pts, T_world_cam)
        if self.cfg.revisit_registrations_per_frame > 0:
            if cands:
                job = (fid, self._steps(fid, pts, T_world_cam, cands), cands)
                if finish and self._job is not None:
                    self.n_dropped += int(self._next is not None)
                    self._next = job
                else:
                    self._job = job
            return None
        if self.cfg.revisit_checks_per_frame > 0:
            if cands:
                self._pending = (fid, pts, cands, cands)
            return None
        # logged even without candidates
        return self._check_now(fid, pts, T_world_cam, cands, cands)

    def step(self) -> int | None:
        """Advance a deferred check by this frame's budget; the accepted frame or None."""
        if self._job is not None:
            fid, steps, ranked = self._job
            k = self.cfg.revisit_registrations_per_frame
            done, accepted = self._advance(fid, steps, k, ranked)
            if done:
                self._job, self._next = self._next, None
            return accepted
        if self._pending is not None:
            fid, pts, queue, ranked = self._pending
            k = self.cfg.revisit_checks_per_frame
            self._pending = (fid, pts, queue[k:], ranked) if len(queue) > k else None
            T = self.frames.topo.anchor(fid)
            accepted = self._check_now(fid, pts, T, queue[:k], ranked)
            if accepted is not None:
                self._pending = None
            return accepted
        return None
