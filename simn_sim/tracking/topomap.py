"""Topological map of local frames (paper: "Building Topological Map").

Nodes are local frames: anchor pose ``T_world_anchor`` (4, 4), the frame's map, a descriptor, a
2-D region (world x/y bounding box of its feature points) and a point count. Arcs hold the
relative pose ``T_i_j`` between two frames with a (6, 6) covariance (gtsam convention, see
:mod:`simn_sim.tracking.posegraph`) and a ``weight`` = metric length of the arc for routing.

Descriptor (:class:`FrameDescriptor`) pooled from a frame's key points (world coordinates through
the anchor) and their learned features, in three parts:

* ``occupancy``: a spatial occupancy signature -- the points' mass on a world-fixed x/y grid
  (cell ``occupancy_cell`` m, bilinear splatting, unit L2 norm, stored sparsely). Two frames
  that observed the same stretch of the world share cells even with anchor drift of a fraction
  of a cell; frames that looked at different walls do not. This is the discriminative part.
* ``shape``: a gravity-aligned, yaw-invariant shape signature -- histograms of point heights and
  of horizontal distances from the points' centroid, each square-rooted (cosine = Bhattacharyya
  coefficient). Cheap, drift-insensitive, weakly discriminative.
* ``feature`` (when the map has learned features): mean and standard deviation of the per-point
  feature vectors, centred and normalised.

Similarity is the weighted mean (``*_weight``) of the cosines of the parts present in both.

Revisits: :func:`close_loop` ranks earlier frames by descriptor similarity and accepts one only
after registration of the current observation against that frame's map succeeds (and the
correction it implies stays within the drift budget); then the loop arc is added and the anchors
re-optimised ("because points live in frame coordinates, moving an anchor moves its map").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Generator, Iterable
from typing import Any

import networkx as nx
import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.bounds import column_bounds
from simn_sim.geometry.se3 import inv_T, pose_error, rot_z, transform_points
from simn_sim.tracking.descriptors import (
    DescriptorConfig,
    FrameDescriptor,
    describe,
    similarity,
)
from simn_sim.tracking.lie import adjoint, check_pose
from simn_sim.tracking.localframes import FrameMap, LocalFrame, unpack_feature_points
from simn_sim.tracking.posegraph import (
    PoseGraphConfig,
    PoseGraphResult,
    check_covariance,
    optimize_pose_graph,
)
from simn_sim.tracking.registration import RegistrationConfig, RegistrationResult, register


class TopoMap:
    """networkx graph of local frames; see the module docstring."""

    def __init__(self, descriptor_cfg: DescriptorConfig | None = None) -> None:
        self.graph = nx.Graph()
        self.desc_cfg = descriptor_cfg or DescriptorConfig()
        self._order: list[int] = []  # frame ids in the order they were added
        self.n_optimized = 0  # pose-graph runs so far (each may move every anchor)
        # applied to every optimised anchor before it is set (e.g. SimnSlam's floor plane)
        self.anchor_constraint: Callable[[np.ndarray], np.ndarray] | None = None
        # absolute priors on anchors for the pose graph: id -> (T_world_anchor, (6, 6) info)
        self.anchor_priors: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    # ------------------------------------------------------------------ nodes
    def add_frame(self, frame: LocalFrame, descriptor: FrameDescriptor | None = None) -> int:
        """Add a local frame as a node; its descriptor is computed from its map if not given."""
        fid = int(frame.frame_id)
        if fid in self.graph:
            raise ValueError(f"frame {fid} is already in the map")
        frame.T_world_anchor = check_pose(frame.T_world_anchor, "T_world_anchor")
        self.graph.add_node(fid, frame=frame)
        self._order.append(fid)
        self.refresh(fid, descriptor)
        return fid

    def refresh(self, fid: int, descriptor: FrameDescriptor | None = None) -> None:
        """Recompute a frame's region, point count and (unless one was given) its descriptor,
        after its map grew or its anchor moved. An explicitly given descriptor is kept."""
        node = self.graph.nodes[fid]
        frame: LocalFrame = node["frame"]
        P, F, _ = unpack_feature_points(frame.map.feature_points())
        Pw = transform_points(frame.T_world_anchor, P.astype(np.float64))
        node["n_points"] = len(P)
        if len(P):
            node["region"] = np.concatenate(column_bounds(Pw[:, :2]))
        else:
            node["region"] = np.full(4, np.nan)
        if descriptor is not None:
            node["descriptor"], node["auto_descriptor"] = descriptor, False
        elif node.get("auto_descriptor", True):
            m = self.desc_cfg.max_points
            if m and len(P) > m:
                k = -(-len(P) // m)
                Pw, F = Pw[::k], F[::k]
            node["descriptor"] = describe(Pw, F, self.desc_cfg) if len(P) else None
            node["auto_descriptor"] = True

    def frames_containing(self, xy: np.ndarray, margin: float = 0.0) -> list[int]:
        """Frames whose region (grown by ``margin`` m) contains the world point ``xy`` (2,)."""
        x, y = float(xy[0]), float(xy[1])
        out = []
        for fid in self._order:
            r = self.graph.nodes[fid]["region"]
            if r[0] - margin <= x <= r[2] + margin and r[1] - margin <= y <= r[3] + margin:
                out.append(fid)
        return out

    def frame(self, fid: int) -> LocalFrame:
        return self.graph.nodes[fid]["frame"]

    def anchor(self, fid: int) -> np.ndarray:
        return self.frame(fid).T_world_anchor

    def region(self, fid: int) -> np.ndarray:
        """(4,) world bounding box ``[xmin, ymin, xmax, ymax]`` of the frame's points."""
        return self.graph.nodes[fid]["region"]

    def descriptor(self, fid: int) -> FrameDescriptor | None:
        return self.graph.nodes[fid]["descriptor"]

    @property
    def frame_ids(self) -> list[int]:
        return list(self._order)

    # ------------------------------------------------------------------ arcs
    def _add_arc(self, i: int, j: int, T_i_j: np.ndarray, cov: np.ndarray, kind: str) -> tuple:
        for k in (i, j):
            if k not in self.graph:
                raise ValueError(f"unknown frame {k}")
        if i == j:
            raise ValueError("an arc needs two different frames")
        T = check_pose(T_i_j, "T_i_j")
        C = check_covariance(cov)
        meas = (int(i), int(j), T, C, kind)
        length = float(np.linalg.norm(T[:3, 3]))
        if self.graph.has_edge(i, j):
            e = self.graph.edges[i, j]
            e["measurements"].append(meas)
            e["kinds"].add(kind)
        else:
            self.graph.add_edge(i, j, measurements=[meas], kinds={kind}, weight=length)
        return meas

    def add_arc(self, i: int, j: int, T_i_j: np.ndarray, cov: np.ndarray) -> tuple:
        """Odometry arc: pose of frame ``j`` in frame ``i`` with (6, 6) covariance.

        Returns the stored measurement ``(i, j, T_i_j, cov, "odom")``."""
        return self._add_arc(i, j, T_i_j, cov, "odom")

    def add_loop(self, i: int, j: int, T_i_j: np.ndarray, cov: np.ndarray) -> tuple:
        """Loop arc (a verified revisit); call :meth:`optimize` afterwards.

        Returns the stored measurement ``(i, j, T_i_j, cov, "loop")``."""
        return self._add_arc(i, j, T_i_j, cov, "loop")

    def arcs(self, kind: str | None = None) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
        out = []
        for _, _, e in self.graph.edges(data=True):
            for i, j, T, C, k in e["measurements"]:
                if kind is None or k == kind:
                    out.append((i, j, T, C))
        return out

    def relative_pose(self, i: int, j: int) -> np.ndarray:
        """Current estimate of ``T_i_j`` from the anchors."""
        return inv_T(self.anchor(i)) @ self.anchor(j)

    def route(self, i: int, j: int) -> list[int]:
        """Shortest sequence of frames from ``i`` to ``j`` by arc length."""
        return nx.shortest_path(self.graph, i, j, weight="weight")

    # ------------------------------------------------------------------ revisits
    def candidates(
        self,
        descriptor: FrameDescriptor,
        exclude_recent: int = 3,
        top: int = 3,
        min_sim: float = 0.0,
        exclude: Iterable[int] = (),
    ) -> list[tuple[int, float]]:
        """Earlier frames most similar to ``descriptor``: ``[(frame_id, similarity)]``, best first.

        The ``exclude_recent`` most recently added frames (and ``exclude``) are skipped: the
        current frame and its neighbours are not revisits.
        """
        skip = set(exclude)
        if exclude_recent > 0:
            skip |= set(self._order[-exclude_recent:])
        out = []
        for fid in self._order:
            d = self.graph.nodes[fid]["descriptor"]
            if fid in skip or d is None:
                continue
            s = similarity(descriptor, d, self.desc_cfg)
            if s >= min_sim:
                out.append((fid, s))
        out.sort(key=lambda x: -x[1])
        return out[:top]

    def optimize(self, cfg: PoseGraphConfig | None = None) -> PoseGraphResult:
        """Pose-graph optimisation of all anchors (gtsam); updates anchors and regions.

        The first frame added is held fixed. Frames not connected to it are left untouched.
        """
        if not self._order:
            raise ValueError("empty map")
        root = self._order[0]
        comp = nx.node_connected_component(self.graph, root)
        anchors = {k: self.anchor(k) for k in comp}
        odom = [a for a in self.arcs("odom") if a[0] in comp]
        loops = [a for a in self.arcs("loop") if a[0] in comp]
        unary = [(k, T, info) for k, (T, info) in self.anchor_priors.items() if k in comp]
        res = optimize_pose_graph(anchors, odom, loops, cfg, fixed=root, unary=unary)
        self.n_optimized += 1
        for k, T in res.anchors.items():
            c = self.anchor_constraint
            self.frame(k).T_world_anchor = T if c is None else c(T)
            self.refresh(k)
        # loop arcs the robust loss rejected leave the map (routing must not use them)
        rejected = {id(loops[m][2]) for m, ok in enumerate(res.loop_inliers) if not ok}
        if rejected:
            for i, j, e in list(self.graph.edges(data=True)):
                e["measurements"] = [x for x in e["measurements"] if id(x[2]) not in rejected]
                if not e["measurements"]:
                    self.graph.remove_edge(i, j)
                else:
                    e["kinds"] = {x[4] for x in e["measurements"]}
        return res


# ---------------------------------------------------------------------- loop closure
RegisterFn = Callable[[int, np.ndarray, np.ndarray], RegistrationResult]


@dataclasses.dataclass(frozen=True)
class LoopClosureConfig(Config):
    exclude_recent: int = 3
    top: int = 3
    min_similarity: float = 0.5
    # key-point rankings (SlamConfig.revisit_features "learned" / "keypoints",
    # descriptors.KeyPointIndex): a candidate needs at least min_reach of the query's key points
    # within reach of its own and, ranked by the learned features, a score of at least
    # min_match (chosen on two rendered loops, where every true revisit had reach >= 0.46 and
    # score >= 0.21; docs/slam.md, "Revisit candidates")
    min_reach: float = 0.3
    min_match: float = 0.2
    max_correction_m: float = 1.0  # drift budget: registration may move the guess this far...
    max_correction_deg: float = 30.0  # ... and turn it this much, no more
    yaw_search_deg: tuple[float, ...] = (0.0, 7.5, -7.5, 15.0, -15.0)  # extra starting headings
    min_inlier_fraction: float = 0.85  # of the observation within 2 cm of the candidate's surface
    good_enough_fraction: float = 0.95  # stop the yaw search at a result this good
    cov_floor_rot: float = 0.002  # rad, added in quadrature to the registration covariance
    cov_floor_trans: float = 0.005  # m
    # ambiguity: when registrations from different starting headings pass but end further
    # apart than this (m, deg), the candidate fails: the scene leaves the pose free along some
    # direction (a wall seen flat on), and the best inlier fraction is a near-tie between
    # the ends (dyn-ref-002: 4 passing results 0.91-0.93 spread over 0.14 m; the one
    # accepted was 0.13 m from the truth). 0: off
    max_spread_m: float = 0.0
    max_spread_deg: float = 0.0
    # drift budget by distance: the check may move the guess by at most drift_floor_m +
    # drift_per_m x the length of the shortest arc path between the two frames in the graph
    # (and never beyond max_correction_m): two frames a few metres apart along the chain, or
    # joined by an earlier loop, cannot have drifted decimetres apart (dyn-ref-002: a check
    # 3 m along the chain moved a guess that was 6 mm off the truth by 0.16 m). 0: off
    drift_floor_m: float = 0.05
    drift_per_m: float = 0.0

    def validate(self) -> None:
        n = type(self).__name__
        require(self.exclude_recent >= 0, n, "exclude_recent", "must be >= 0")
        require(self.top >= 1, n, "top", "must be >= 1")
        require(-1 <= self.min_similarity <= 1, n, "min_similarity", "must be in [-1, 1]")
        require(0 <= self.min_match <= 1, n, "min_match", "must be in [0, 1]")
        require(0 <= self.min_reach <= 1, n, "min_reach", "must be in [0, 1]")
        require(self.max_correction_m > 0, n, "max_correction_m", "must be > 0")
        require(self.max_correction_deg > 0, n, "max_correction_deg", "must be > 0")
        require(self.cov_floor_rot > 0 and self.cov_floor_trans > 0, n, "cov_floor_rot", "> 0")
        require(self.max_spread_m >= 0, n, "max_spread_m", "must be >= 0 (0: off)")
        require(self.max_spread_deg >= 0, n, "max_spread_deg", "must be >= 0 (0: off)")
        require(self.drift_floor_m >= 0, n, "drift_floor_m", "must be >= 0")
        require(self.drift_per_m >= 0, n, "drift_per_m", "must be >= 0 (0: off)")
        require(len(self.yaw_search_deg) >= 1, n, "yaw_search_deg", "needs at least one heading")
        require(0 < self.min_inlier_fraction <= 1, n, "min_inlier_fraction", "must be in (0, 1]")
        require(
            self.min_inlier_fraction <= self.good_enough_fraction <= 1,
            n, "good_enough_fraction", "must be in [min_inlier_fraction, 1]",
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class LoopAttempt:
    frame_id: int
    similarity: float
    accepted: bool
    reason: str
    T_frame_cam: np.ndarray | None  # registered camera pose in the candidate frame


@dataclasses.dataclass(frozen=True)
class LoopClosureResult:
    accepted: int | None  # the frame the revisit was accepted against, or None
    attempts: list[LoopAttempt]
    T_i_j: np.ndarray | None  # loop arc (accepted frame -> current frame)
    pose_graph: PoseGraphResult | None


def registration_callback(
    topo: TopoMap, cfg: RegistrationConfig | None = None, points_as: str = "numpy"
) -> RegisterFn:
    """Default callback: :func:`register` against the candidate frame's own ``sdf_and_grad``."""

    def fn(fid: int, points_cam: np.ndarray, T_frame_cam_init: np.ndarray) -> RegistrationResult:
        m: FrameMap = topo.frame(fid).map
        return register(points_cam, m.sdf_and_grad, T_frame_cam_init, cfg, points_as=points_as)

    return fn


def close_loop(
    topo: TopoMap,
    current: int,
    points_cam: np.ndarray,
    T_world_cam: np.ndarray,
    register_fn: RegisterFn,
    cfg: LoopClosureConfig | None = None,
    descriptor: FrameDescriptor | None = None,
    candidate_ids: Iterable[int | tuple[int, float]] | None = None,
    pose_graph_cfg: PoseGraphConfig | None = None,
) -> LoopClosureResult:
    """Check whether the camera revisits an earlier frame; on success add the loop and optimise.

    current: id of the frame being built (its anchor and the tracked ``T_world_cam`` give the
    camera pose in it). points_cam: (N, 3) the current observation, camera frame. Candidates come
    from descriptor similarity (``descriptor`` defaults to one computed from ``points_cam``), or
    from ``candidate_ids`` (frame ids, or ``(id, similarity)`` pairs, checked in that order). A
    candidate is accepted when ``register_fn(fid, points_cam, T_fid_cam_guess)`` succeeds and
    moves the guess by at most the drift budget.
    """
    steps = close_loop_steps(
        topo, current, points_cam, T_world_cam, register_fn, cfg, descriptor, candidate_ids,
        pose_graph_cfg,
    )  # fmt: skip
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def close_loop_steps(
    topo: TopoMap,
    current: int,
    points_cam: np.ndarray,
    T_world_cam: np.ndarray,
    register_fn: RegisterFn,
    cfg: LoopClosureConfig | None = None,
    descriptor: FrameDescriptor | None = None,
    candidate_ids: Iterable[int | tuple[int, float]] | None = None,
    pose_graph_cfg: PoseGraphConfig | None = None,
) -> Generator[None, None, LoopClosureResult]:
    """:func:`close_loop` as a generator that yields after each registration and returns the
    :class:`LoopClosureResult` (``StopIteration.value``): a caller with a time budget per frame
    (the 10 Hz control loop) advances it one registration per frame. The result is the same as
    ``close_loop``'s with the same arguments, provided the topological map does not change in
    between (``T_world_cam`` is the pose the observation was taken at, e.g. a frame's anchor)."""
    cfg = cfg or LoopClosureConfig()
    T_world_cam = check_pose(T_world_cam, "T_world_cam")
    T_cur_cam = inv_T(topo.anchor(current)) @ T_world_cam
    if candidate_ids is None:
        if descriptor is None:
            pw = transform_points(T_world_cam, np.asarray(points_cam, dtype=np.float64))
            descriptor = describe(pw, None, topo.desc_cfg)
        cands = topo.candidates(
            descriptor, cfg.exclude_recent, cfg.top, cfg.min_similarity, exclude=[current]
        )
    else:
        cands = []
        for c in candidate_ids:  # ids, or (id, similarity) pairs ranked by the caller
            fid, sim = (c[0], c[1]) if isinstance(c, tuple | list) else (c, float("nan"))
            if int(fid) != current:
                cands.append((int(fid), float(sim)))
    attempts: list[LoopAttempt] = []
    for fid, sim in cands:
        res, why = yield from verify_candidate_steps(
            topo,
            fid,
            points_cam,
            T_world_cam,
            register_fn,
            cfg,
            drift_budget(topo, fid, current, cfg),
        )
        if res is None:
            attempts.append(LoopAttempt(fid, sim, False, why, None))
            continue
        attempts.append(LoopAttempt(fid, sim, True, "ok", res.pose))
        T_i_j = res.pose @ inv_T(T_cur_cam)  # current frame's anchor in the candidate frame
        Ad = adjoint(T_cur_cam)  # camera-frame covariance -> covariance of T_i_j
        cov = Ad @ res.covariance @ Ad.T
        cov += np.diag([cfg.cov_floor_rot**2] * 3 + [cfg.cov_floor_trans**2] * 3)
        stored = topo.add_loop(fid, current, T_i_j, 0.5 * (cov + cov.T))
        pg = topo.optimize(pose_graph_cfg)
        if not any(a[2] is stored[2] for a in topo.arcs("loop")):
            # the pose graph's robust loss threw the new arc out
            attempts[-1] = LoopAttempt(fid, sim, False, "rejected by the pose graph", res.pose)
            return LoopClosureResult(None, attempts, None, pg)
        return LoopClosureResult(fid, attempts, T_i_j, pg)
    return LoopClosureResult(None, attempts, None, None)


def drift_budget(topo: TopoMap, i: int, j: int, cfg: LoopClosureConfig) -> float:
    """The most a revisit check of frame ``j`` against frame ``i`` may move its guess (m):
    ``max_correction_m``, or with ``drift_per_m`` the smaller of that and ``drift_floor_m`` +
    ``drift_per_m`` x the shortest arc path between them (the arcs' translation lengths)."""
    if cfg.drift_per_m <= 0:
        return cfg.max_correction_m
    try:
        path = nx.shortest_path_length(topo.graph, i, j, weight="weight")
    except (nx.NetworkXNoPath, nx.NodeNotFound):
        return cfg.max_correction_m
    return min(cfg.max_correction_m, cfg.drift_floor_m + cfg.drift_per_m * float(path))


def verify_candidate_steps(
    topo: TopoMap,
    fid: int,
    points_cam: np.ndarray,
    T_world_cam: np.ndarray,
    register_fn: RegisterFn,
    cfg: LoopClosureConfig | None = None,
    max_move_m: float | None = None,
) -> Generator[None, None, tuple[RegistrationResult | None, str]]:
    """The verification of one revisit candidate ``fid`` (a generator that yields after each
    registration): the observation ``points_cam`` taken at ``T_world_cam`` is registered against
    the frame from the guess and from the guess turned by each ``yaw_search_deg``; a result
    passes when it moves the guess by at most the drift budget and at least
    ``min_inlier_fraction`` of the points fit. Returns (the best passing registration, "ok") or
    (None, why each heading failed). ``max_move_m``: the drift budget (default
    ``max_correction_m``; :func:`drift_budget`). With ``max_spread_m`` / ``max_spread_deg``, passing
    results that lie further apart than that fail the candidate as ambiguous. Nothing in
    ``topo`` changes."""
    cfg = cfg or LoopClosureConfig()
    budget = cfg.max_correction_m if max_move_m is None else float(max_move_m)
    T_world_cam = check_pose(T_world_cam, "T_world_cam")
    A = topo.anchor(fid)
    guess = inv_T(A) @ T_world_cam
    best, whys, passed = None, [], []
    for yaw in cfg.yaw_search_deg:
        # turn the guess about the world vertical through the camera centre (drift is
        # mostly heading for a ground robot; it is what leaves the registration basin first)
        Tw = T_world_cam.copy()
        Tw[:3, :3] = rot_z(np.radians(yaw)) @ Tw[:3, :3]
        res = register_fn(fid, points_cam, inv_T(A) @ Tw)
        yield
        if not res.success:
            whys.append(f"{yaw:+.1f} deg: registration: {res.reason}")
            continue
        dt, dr = pose_error(guess, res.pose)
        if dt > budget or np.degrees(dr) > cfg.max_correction_deg:
            whys.append(f"{yaw:+.1f} deg: correction {dt:.2f} m / {np.degrees(dr):.1f} deg")
            continue
        frac = getattr(res, "inlier_fraction", 1.0)
        if frac < cfg.min_inlier_fraction:
            whys.append(f"{yaw:+.1f} deg: only {frac:.2f} of the points fit")
            continue
        passed.append(res.pose)
        if best is None or frac > best[1]:
            best = (res, frac)
        if frac >= cfg.good_enough_fraction:
            break
    if best is None:
        return None, "; ".join(whys)
    if (cfg.max_spread_m > 0 or cfg.max_spread_deg > 0) and len(passed) > 1:
        apart = [pose_error(a, b) for k, a in enumerate(passed) for b in passed[k + 1 :]]
        dt = max(d for d, _ in apart)
        dr = float(np.degrees(max(r for _, r in apart)))
        if (cfg.max_spread_m > 0 and dt > cfg.max_spread_m) or (
            cfg.max_spread_deg > 0 and dr > cfg.max_spread_deg
        ):
            return (
                None,
                f"ambiguous: {len(passed)} passing results up to {dt:.2f} m / {dr:.1f} deg apart",
            )
    return best[0], "ok"


def as_frame_map(obj: Any) -> FrameMap:
    """Check that ``obj`` implements :class:`FrameMap` (raises TypeError otherwise)."""
    if not isinstance(obj, FrameMap):
        raise TypeError(f"{type(obj).__name__} lacks feature_points() / sdf_and_grad()")
    return obj
