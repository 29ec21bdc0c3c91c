"""gtsam pose graph of local-frame anchors: loop closure on a drifted square."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.geometry.se3 import inv_T, planar_T, se3_exp
from simn_sim.tracking.posegraph import (
    PoseGraphConfig,
    covariance_from_sigmas,
    optimize_anchors,
    optimize_pose_graph,
)

ODOM_COV = covariance_from_sigmas(np.radians(1.0), 0.02)
LOOP_COV = covariance_from_sigmas(np.radians(0.2), 0.005)


def square_loop(side: float = 4.0, step: float = 0.5) -> list[np.ndarray]:
    """Ground-truth anchors along a closed square (heading along the path), z = 0.3 m."""
    out = []
    n = int(round(side / step))
    for edge in range(4):
        for k in range(n):
            s = k * step
            x, y = [(s, 0.0), (side, s), (side - s, side), (0.0, side - s)][edge]
            out.append(planar_T(x, y, edge * np.pi / 2, 0.3))
    return out


def drifted_odometry(gt: list[np.ndarray], rng: np.random.Generator):
    """Odometry arcs with a yaw bias (0.8 deg/step) and noise; anchors chained from them."""
    arcs, anchors = [], {0: gt[0].copy()}
    for i in range(len(gt) - 1):
        true = inv_T(gt[i]) @ gt[i + 1]
        err = se3_exp(
            np.concatenate(
                [
                    rng.normal(scale=np.radians(0.2), size=3) + [0, 0, np.radians(0.8)],
                    rng.normal(scale=0.005, size=3),
                ]  # fmt: skip
            )
        )
        meas = true @ err
        arcs.append((i, i + 1, meas, ODOM_COV))
        anchors[i + 1] = anchors[i] @ meas
    return anchors, arcs


def ate(est: dict[int, np.ndarray], gt: list[np.ndarray]) -> float:
    """RMS anchor position error; anchor 0 is held at its true pose (no alignment needed)."""
    return float(np.sqrt(np.mean([np.sum((est[k][:3, 3] - gt[k][:3, 3]) ** 2) for k in est])))


def test_loop_closure_reduces_ate() -> None:
    rng = np.random.default_rng(0)
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, rng)
    last = len(gt) - 1
    loop_meas = inv_T(gt[last]) @ gt[0] @ se3_exp(rng.normal(scale=[0.002] * 3 + [0.003] * 3))
    loop = [(last, 0, loop_meas, LOOP_COV)]
    before = ate(anchors, gt)
    odom_only = optimize_anchors(anchors, odom, [])
    assert ate(odom_only, gt) == pytest.approx(before, rel=1e-3)  # nothing to correct with
    res = optimize_pose_graph(anchors, odom, loop)
    after = ate(res.anchors, gt)
    assert before > 0.3
    assert after < before / 8, (before, after)
    assert res.final_error < res.initial_error
    assert np.allclose(res.anchors[0], gt[0], atol=1e-3)


@pytest.mark.parametrize("seed", [1, 2])
def test_gnc_rejects_wrong_loops(seed: int) -> None:
    rng = np.random.default_rng(seed)
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, rng)
    last = len(gt) - 1

    def arc(i: int, j: int, err: np.ndarray | None = None):
        T = inv_T(gt[i]) @ gt[j]
        return (i, j, T if err is None else T @ err, LOOP_COV)

    good = [arc(last, 0), arc(last - 1, 1)]
    # false revisits: each claims an anchor sits far from where it is
    bad = [arc(20, 4, planar_T(1.5, 0.0, 0.5)), arc(28, 10, planar_T(0.5, 0.3, 0.2))]
    res = optimize_pose_graph(anchors, odom, good + bad)  # default: GNC-TLS on loop arcs
    assert res.loop_inliers == [True, True, False, False]
    only_good = optimize_anchors(anchors, odom, good)
    assert ate(res.anchors, gt) < 1.2 * ate(only_good, gt) + 1e-3
    plain = optimize_anchors(anchors, odom, good + bad, PoseGraphConfig(loop_robust="none"))
    assert ate(plain, gt) > 3 * ate(res.anchors, gt)


def test_bad_input() -> None:
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, np.random.default_rng(2))
    with pytest.raises(ValueError, match="unknown anchor"):
        optimize_anchors(anchors, odom + [(0, 99, np.eye(4), ODOM_COV)])
    with pytest.raises(ValueError, match="positive definite"):
        optimize_anchors(anchors, [(0, 1, np.eye(4), -ODOM_COV)] + odom[1:])
    with pytest.raises(ValueError, match="6x6"):
        optimize_anchors(anchors, [(0, 1, np.eye(4), np.eye(3))] + odom[1:])
    with pytest.raises(ValueError, match="not connected"):
        optimize_anchors(anchors, odom[:-3])
    with pytest.raises(ValueError, match="itself"):
        optimize_anchors(anchors, odom + [(3, 3, np.eye(4), ODOM_COV)])
    with pytest.raises(ConfigError, match="loop_robust"):
        PoseGraphConfig(loop_robust="tukey")
    with pytest.raises(ConfigError, match="gnc_inlier_probability"):
        PoseGraphConfig(gnc_inlier_probability=1.0)


# ---------------------------------------------------------------------------------------------
# Local frames and the topological map (simn_sim.tracking.localframes / topomap)
# ---------------------------------------------------------------------------------------------
from simn_sim.config import ConfigError as _ConfigError  # noqa: E402
from simn_sim.geometry.se3 import make_T, pose_error  # noqa: E402
from simn_sim.tracking.localframes import (  # noqa: E402
    FrameTrigger,
    FrameTriggerConfig,
    LocalFrame,
    unpack_feature_points,
)
from simn_sim.tracking.synthetic import AnalyticFrameMap, loop_scene, render_points  # noqa: E402
from simn_sim.tracking.topomap import (  # noqa: E402
    LoopClosureConfig,
    TopoMap,
    close_loop,
    describe,
    registration_callback,
)


def test_trigger_translation_only() -> None:
    trig = FrameTrigger(FrameTriggerConfig(max_travel_m=1.0, max_rotation_deg=30.0))
    fired = [trig.update(planar_T(0.1 * k, 0.0, 0.3)) for k in range(25)]
    assert [k for k, f in enumerate(fired) if f] == [11, 22]  # travel 1.1 m > 1.0 m
    assert trig.reason == "travel"


def test_trigger_rotation_only() -> None:
    trig = FrameTrigger(FrameTriggerConfig(max_travel_m=1.0, max_rotation_deg=30.0))
    fired = [trig.update(planar_T(1.0, 2.0, np.radians(4.0 * k))) for k in range(20)]
    assert [k for k, f in enumerate(fired) if f] == [8, 16]  # 32 deg > 30 deg
    assert trig.reason == "rotation"


def test_trigger_accumulates_travel_and_counts() -> None:
    trig = FrameTrigger(FrameTriggerConfig(max_travel_m=1.0, max_observations=0))
    xs = [0.0, 0.3, 0.0, 0.3, 0.0, 0.3]  # back and forth: 1.5 m travelled, 0.3 m displaced
    fired = [trig.update(planar_T(x, 0.0, 0.0)) for x in xs]
    assert fired == [False, False, False, False, True, False]
    trig = FrameTrigger(FrameTriggerConfig(max_observations=3))
    assert [trig.update(np.eye(4)) for _ in range(5)] == [False, False, False, True, False]
    with pytest.raises(_ConfigError, match="max_rotation_deg"):
        FrameTriggerConfig(max_rotation_deg=0.0)


CAM_HEIGHT = 1.0


def _T_base_cam(pitch_down_deg: float = 20.0) -> np.ndarray:
    R_base_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    a = np.radians(-pitch_down_deg)
    Rp = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return make_T(R_base_cam @ Rp, np.array([0.0, 0.0, CAM_HEIGHT]))


def _square_cameras(side: float = 4.0, step: float = 0.5, extra: int = 1) -> list[np.ndarray]:
    """Camera poses around a square in the hall, then ``extra`` frames re-driving the first edge."""
    n, h, out = int(round(side / step)), side / 2, []
    for edge in range(5):
        for k in range(n if edge < 4 else extra):
            s = k * step
            x, y = [(-h + s, -h), (h, -h + s), (h - s, h), (-h, h - s), (-h + s, -h)][edge]
            out.append(planar_T(x, y, edge * np.pi / 2) @ _T_base_cam())
    return out


@pytest.fixture(scope="module")
def drifted_topomap():
    return _make_drifted_topomap()


def _make_drifted_topomap():
    """32 frames around a square + 1 revisiting frame 0; each frame's map is the analytic scene
    seen from its true pose (valid near its own points only); anchors chained from odometry
    with a heading bias of 0.25 deg per frame."""
    scene = loop_scene()
    gt = _square_cameras()
    rng = np.random.default_rng(0)
    obs = [render_points(scene, T, 2500, rng) for T in gt]
    topo = TopoMap()
    est = [gt[0].copy()]
    for i in range(len(gt)):
        if i:
            err = se3_exp(
                np.concatenate(
                    [
                        rng.normal(scale=np.radians(0.1), size=3) + [0.0, np.radians(0.25), 0.0],
                        rng.normal(scale=0.005, size=3),
                    ]  # fmt: skip
                )
            )
            meas = inv_T(gt[i - 1]) @ gt[i] @ err
            est.append(est[-1] @ meas)
        frame = LocalFrame(i, est[i].copy(), AnalyticFrameMap(scene, gt[i], obs[i]))
        topo.add_frame(frame)
        if i:
            topo.add_arc(i - 1, i, meas, ODOM_COV)
    return topo, gt, obs, est


def _anchor_ate(topo: TopoMap, gt: list[np.ndarray]) -> float:
    return ate({k: topo.anchor(k) for k in topo.frame_ids}, gt)


def test_descriptor_ranks_the_revisited_frames(drifted_topomap) -> None:
    topo, gt, obs, est = drifted_topomap
    cur = len(gt) - 1
    d = describe(topo.frame(cur).points_world())
    cands = topo.candidates(d, exclude_recent=4, top=3)
    assert cands[0][0] in (0, 1) and cands[0][1] > 0.8
    assert all(c not in range(cur - 3, cur + 1) for c, _ in cands)
    far = topo.candidates(d, exclude_recent=4, top=40)
    sims = dict(far)
    assert sims[0] > sims[16] + 0.2  # the opposite side of the hall looks different


def test_loop_closure_via_registration(drifted_topomap) -> None:
    topo, gt, obs, est = drifted_topomap
    cur = len(gt) - 1
    anchors_before = {k: topo.anchor(k).copy() for k in topo.frame_ids}
    before = _anchor_ate(topo, gt)
    assert before > 0.1
    cb = registration_callback(topo)
    # wrong candidates (other sides of the square): verification rejects all of them
    wrong = close_loop(topo, cur, obs[cur], est[cur], cb, candidate_ids=[8, 16, 24])
    assert wrong.accepted is None and len(wrong.attempts) == 3
    assert not any(a.accepted for a in wrong.attempts)
    assert topo.arcs("loop") == []
    assert all(np.array_equal(topo.anchor(k), anchors_before[k]) for k in topo.frame_ids)

    res = close_loop(topo, cur, obs[cur], est[cur], cb, LoopClosureConfig(exclude_recent=4))
    assert res.accepted in (0, 1), [a.reason for a in res.attempts]
    i = res.accepted
    et, er = pose_error(res.T_i_j, inv_T(gt[i]) @ gt[cur])
    assert et < 0.01 and np.degrees(er) < 0.5
    assert len(topo.arcs("loop")) == 1 and res.pose_graph.loop_inliers == [True]
    after = _anchor_ate(topo, gt)
    assert after < before / 4, (before, after)
    # moving an anchor moved its map: frame points in world follow the optimised anchor
    P, _, _ = unpack_feature_points(topo.frame(cur).map.feature_points())
    pw = topo.frame(cur).points_world()
    assert np.allclose(pw, P @ topo.anchor(cur)[:3, :3].T + topo.anchor(cur)[:3, 3], atol=1e-4)
    box = topo.region(cur)
    assert np.all(pw[:, 0] >= box[0] - 1e-5) and np.all(pw[:, 1] <= box[3] + 1e-5)
    # routing now uses the loop arc instead of walking around the square
    assert len(topo.route(0, cur)) <= 3


def test_feature_point_protocol_and_errors() -> None:
    class FP:  # the learned map's FeaturePoints snapshot shape
        positions = np.zeros((4, 3), np.float32)
        features = np.ones((4, 8), np.float32)
        labels = np.zeros(4, np.int16)

    P, F, L = unpack_feature_points(FP())
    assert P.shape == (4, 3) and F.shape == (4, 8) and L.dtype == np.int64
    with pytest.raises(ValueError, match="features"):
        unpack_feature_points((np.zeros((4, 3)), np.zeros((3, 2)), np.zeros(4)))
    topo = TopoMap()
    m = AnalyticFrameMap(loop_scene(), np.eye(4), np.zeros((5, 3), np.float32))
    topo.add_frame(LocalFrame(0, np.eye(4), m))
    with pytest.raises(ValueError, match="already"):
        topo.add_frame(LocalFrame(0, np.eye(4), m))
    with pytest.raises(ValueError, match="unknown frame"):
        topo.add_arc(0, 1, np.eye(4), ODOM_COV)
    with pytest.raises(ValueError, match="empty"):
        describe(np.zeros((0, 3)))


def test_topomap_drops_rejected_loops_and_refreshes() -> None:
    rng = np.random.default_rng(3)
    gt = square_loop()
    anchors, odom = drifted_odometry(gt, rng)
    scene = loop_scene()
    topo = TopoMap()
    for k in sorted(anchors):
        pts = rng.uniform([-0.3, -0.3, 0.0], [0.3, 0.3, 1.0], size=(50, 3)).astype(np.float32)
        topo.add_frame(LocalFrame(k, anchors[k].copy(), AnalyticFrameMap(scene, gt[k], pts)))
    for i, j, T, C in odom:
        topo.add_arc(i, j, T, C)
    last = len(gt) - 1
    good = topo.add_loop(last, 0, inv_T(gt[last]) @ gt[0], LOOP_COV)
    bad = topo.add_loop(16, 2, inv_T(gt[16]) @ gt[2] @ planar_T(1.0, 0.5, 0.4), LOOP_COV)
    assert len(topo.route(2, 16)) == 2  # the false arc is a shortcut before optimisation
    cells_before = topo.descriptor(20).cells.copy()
    res = topo.optimize()
    assert res.loop_inliers == [True, False] or res.loop_inliers == [False, True]
    kept = topo.arcs("loop")
    assert len(kept) == 1 and kept[0][2] is good[2] and kept[0][2] is not bad[2]
    assert not topo.graph.has_edge(16, 2) and len(topo.route(2, 16)) > 2
    assert ate({k: topo.anchor(k) for k in topo.frame_ids}, gt) < 0.1
    # descriptors and regions follow the moved anchors
    assert not np.array_equal(cells_before, topo.descriptor(20).cells)
    x, y = topo.anchor(20)[:2, 3]
    assert 20 in topo.frames_containing(np.array([x, y]), margin=0.5)


def test_close_loop_steps_yields_per_registration_and_matches_close_loop() -> None:
    """The generator form (one registration per step, as the agent runs it over control
    steps) ends with the same revisit, loop arc and optimised anchors as one call."""
    import copy

    from simn_sim.tracking.topomap import close_loop_steps

    topo0, gt, obs, est = _make_drifted_topomap()  # fresh: other tests close its loop
    cur = len(gt) - 1
    cfg = LoopClosureConfig(exclude_recent=4)
    ta, tb = copy.deepcopy(topo0), copy.deepcopy(topo0)
    calls = []
    cb_b = registration_callback(tb)

    def counting(fid, pts, T):
        calls.append(fid)
        return cb_b(fid, pts, T)

    # wrong candidates first: each is tried at every yaw of the search before the right one
    ids = [8, 16, 0]
    ra = close_loop(ta, cur, obs[cur], est[cur], registration_callback(ta), cfg, candidate_ids=ids)
    steps = close_loop_steps(tb, cur, obs[cur], est[cur], counting, cfg, candidate_ids=ids)
    n_yields = 0
    while True:
        n_before = len(tb.arcs("loop"))
        try:
            next(steps)
        except StopIteration as done:
            rb = done.value
            break
        n_yields += 1
        assert len(calls) == n_yields  # one registration per step
        assert len(tb.arcs("loop")) == n_before  # the map changes only at the end
    assert n_yields >= 2 * len(cfg.yaw_search_deg) + 1
    assert ra.accepted == rb.accepted == 0, [a.reason for a in ra.attempts]
    assert [a.reason for a in ra.attempts] == [a.reason for a in rb.attempts]
    assert np.allclose(ra.T_i_j, rb.T_i_j, atol=1e-9)
    assert all(np.allclose(ta.anchor(k), tb.anchor(k), atol=1e-9) for k in ta.frame_ids)


def test_descriptor_from_a_subsample_keeps_the_region_and_the_ranking(drifted_topomap) -> None:
    """``DescriptorConfig.max_points`` (the agent preset describes frames from 3000 points):
    regions still come from every point; on a 1 m occupancy grid the subsampled descriptor
    ranks the revisited frames as the full one does."""
    from simn_sim.tracking.topomap import DescriptorConfig, similarity

    topo, gt, obs, est = drifted_topomap
    full = TopoMap()
    sub = TopoMap(DescriptorConfig(max_points=300))  # frames hold 2500 points: every 9th
    for i in range(len(gt)):
        for t in (full, sub):
            fr = topo.frame(i)
            t.add_frame(LocalFrame(i, fr.T_world_anchor.copy(), fr.map))
    cur = len(gt) - 1
    for i in range(len(gt)):
        assert np.array_equal(full.region(i), sub.region(i))
        assert similarity(full.descriptor(i), sub.descriptor(i)) > 0.95
    d = describe(topo.frame(cur).points_world())
    top_full = [f for f, _ in full.candidates(d, exclude_recent=4, top=3)]
    top_sub = [f for f, _ in sub.candidates(d, exclude_recent=4, top=3)]
    assert top_sub[0] == top_full[0] and top_sub[0] in (0, 1)
    with pytest.raises(_ConfigError, match="max_points"):
        DescriptorConfig(max_points=-1)


def test_passing_registrations_far_apart_make_the_candidate_ambiguous(drifted_topomap) -> None:
    """Registrations from the five starting headings that all pass but end at different
    places (a scene that leaves the pose free along a wall): with the spread limits the
    candidate fails as ambiguous; results that agree pass; without the limits the best
    inlier fraction wins as before."""
    from simn_sim.tracking.registration import RegistrationResult
    from simn_sim.tracking.topomap import verify_candidate_steps

    topo, gt, obs, est = drifted_topomap
    cur, fid = len(gt) - 1, 0
    guess = inv_T(topo.anchor(fid)) @ est[cur]

    def run(offsets_m: list[float], cfg: LoopClosureConfig):
        """The k-th registration ends ``offsets_m[k]`` metres along the camera's x axis from the
        guess, fitting 0.90 + 0.01 k of the points (none reaches good_enough_fraction)."""
        calls = iter(range(len(offsets_m)))

        def register(f, pts, T_init):
            k = next(calls)
            pose = guess @ make_T(np.eye(3), [offsets_m[k], 0.0, 0.0])
            return RegistrationResult(
                pose,
                np.eye(6) * 1e-6,
                5,
                1000,
                900,
                0.004,
                0.01,
                True,
                "ok",
                True,
                0.1,
                0.0,
                0.90 + 0.01 * k,
            )

        steps = verify_candidate_steps(topo, fid, obs[cur], est[cur], register, cfg)
        try:
            while True:
                next(steps)
        except StopIteration as done:
            return done.value

    spread = LoopClosureConfig(max_spread_m=0.05, max_spread_deg=2.0)
    res, why = run([0.0, 0.03, 0.06, 0.10, 0.14], spread)  # 0.14 m apart: ambiguous
    assert res is None and why.startswith("ambiguous: 5 passing results up to 0.14 m"), why
    res, why = run([0.0, 0.01, 0.02, 0.01, 0.0], spread)  # they agree: the best one passes
    assert why == "ok" and pose_error(res.pose, guess)[0] == pytest.approx(0.0, abs=1e-9)
    res, why = run([0.0, 0.03, 0.06, 0.10, 0.14], LoopClosureConfig())  # limits off
    assert why == "ok" and pose_error(res.pose, guess)[0] == pytest.approx(0.14, abs=1e-9)
    with pytest.raises(_ConfigError, match="max_spread_m"):
        LoopClosureConfig(max_spread_m=-0.1)


def test_drift_budget_grows_with_the_arc_path_between_the_frames() -> None:
    from simn_sim.tracking.topomap import drift_budget

    topo, gt, obs, est = _make_drifted_topomap()
    cur = len(gt) - 1
    # no loop yet: the shortest path is the odometry chain, 0 -> 1 -> ... -> cur
    chain = sum(float(np.linalg.norm(T[:3, 3])) for i, j, T, _ in topo.arcs("odom"))
    cfg = LoopClosureConfig(drift_floor_m=0.05, drift_per_m=0.03, max_correction_m=10.0)
    assert drift_budget(topo, 0, cur, cfg) == pytest.approx(0.05 + 0.03 * chain)
    assert drift_budget(topo, cur - 4, cur, cfg) < drift_budget(topo, 0, cur, cfg)
    assert drift_budget(topo, 0, cur, LoopClosureConfig()) == LoopClosureConfig().max_correction_m
    # capped by max_correction_m
    cap = LoopClosureConfig(drift_per_m=0.03, max_correction_m=0.2)
    assert drift_budget(topo, 0, cur, cap) == 0.2
    # a close frame pair gets a budget too small for a correction the chain cannot have made
    tight = LoopClosureConfig(drift_floor_m=0.01, drift_per_m=0.001)
    est_off = est[cur] @ make_T(np.eye(3), [0.3, 0.0, 0.0])  # the guess 0.3 m off
    res = close_loop(
        topo, cur, obs[cur], est_off, registration_callback(topo), tight, candidate_ids=[0, 1]
    )
    assert res.accepted is None
    assert any("correction" in a.reason for a in res.attempts), [a.reason for a in res.attempts]
    # the same check with the budget off moves the guess back and closes the loop
    res = close_loop(
        topo, cur, obs[cur], est_off, registration_callback(topo), candidate_ids=[0, 1]
    )
    assert res.accepted in (0, 1), [a.reason for a in res.attempts]
    # a closed loop is a short path: frames joined by it get the floor's budget
    assert drift_budget(topo, 0, cur, cfg) < 0.05 + 0.03 * 0.5


def test_unary_heading_prior_shares_the_turn_with_the_arcs() -> None:
    """A chain 0 -> 1 -> 2 (z-up anchors, 1 m apart along x; arcs of rotation sigma s) and a
    prior on anchor 2 that its yaw is 3 deg less, information about z only, sigma s: least
    squares puts two thirds of the turn on anchor 2 and one third on anchor 1 (two arcs
    against one prior), and the prior does not pull any position of its own."""
    from simn_sim.geometry.se3 import yaw_of

    s = np.radians(1.0)
    A = {k: planar_T(float(k), 0.0, 0.0) for k in range(3)}
    C = covariance_from_sigmas(s, 1e-4)
    arcs = [(0, 1, inv_T(A[0]) @ A[1], C), (1, 2, inv_T(A[1]) @ A[2], C)]
    info = np.eye(6) * 1e-9
    info[2, 2] += 1.0 / s**2
    prior = planar_T(2.0, 0.5, np.radians(-3.0))  # its position far off: no information
    res = optimize_pose_graph(A, arcs, (), unary=[(2, prior, info)])
    yaw = {k: np.degrees(yaw_of(T)) for k, T in res.anchors.items()}
    assert yaw[0] == pytest.approx(0.0, abs=1e-3)
    assert yaw[1] == pytest.approx(-1.0, abs=0.01)
    assert yaw[2] == pytest.approx(-2.0, abs=0.01)
    # anchor 2 moved only as the turned chain carries it (1 m from anchor 1, turned 1 deg)
    np.testing.assert_allclose(
        res.anchors[2][:2, 3], [1.0 + np.cos(np.radians(-1.0)), np.sin(np.radians(-1.0))], atol=1e-3
    )
    with pytest.raises(ValueError, match="not an anchor"):
        optimize_pose_graph(A, arcs, (), unary=[(7, prior, info)])
    with pytest.raises(ValueError, match="positive definite"):
        optimize_pose_graph(A, arcs, (), unary=[(2, prior, np.zeros((6, 6)))])
    with pytest.raises(ValueError, match=r"\(6, 6\)"):
        optimize_pose_graph(A, arcs, (), unary=[(2, prior, np.eye(3))])
