"""Tracking on the learned map through its SDF cache (the fast path of ``track_sdf: implicit``),
against the network itself (the exact path) on an analytic office; the KD-tree k-NN against
the bucket grids; training on the worker thread against synchronous training."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simn_sim.mapping import ImplicitMap
from simn_sim.mapping.sdf_cache import SdfCache
from simn_sim.slam.config import tracking_mapper_config
from simn_sim.tracking.lie import se3_log
from simn_sim.tracking.registration import RegistrationConfig, register
from simn_sim.tracking.synthetic import look_at, office_scene, render_points

torch.set_num_threads(1)

REG = RegistrationConfig(degeneracy_ratio=1e-7, min_valid_fraction=0.2, grad_norm_min=0.3)


def _mapped_office(train_iters: int = 30):
    """The learned map of the tracking preset (2 cm neural points, geometric prior + learned
    residual) from three views of the analytic office near a reference pose, trained."""
    scene = office_scene()
    rng = np.random.default_rng(0)
    T_map = look_at(np.array([0.0, -0.5, 1.2]), np.array([1.8, 1.0, 0.4]))
    cfg = tracking_mapper_config()
    cfg = cfg.replace(training=cfg.training.replace(batch_size=1024), seed=3)
    m = ImplicitMap(cfg)
    for _ in range(3):
        Tk = T_map.copy()
        Tk[:3, 3] += rng.normal(0, 0.05, 3)
        m.integrate_frame(render_points(scene, Tk, 30000, rng), Tk, train=False)
    m.train(train_iters)
    T_true = T_map.copy()
    T_true[:3, 3] += [0.02, 0.03, -0.01]
    pts = render_points(scene, T_true, 2500, rng)
    return m, T_true, pts


def _perturbed(T_true: np.ndarray) -> np.ndarray:
    """5 cm and 3 deg away from ``T_true``."""
    a = np.radians(3.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    T = T_true.copy()
    T[:3, :3] = R @ T_true[:3, :3]
    T[:3, 3] += np.array([0.03, -0.04, 0.0])  # 5 cm
    return T


def _error(T_true, T):
    e = se3_log(np.linalg.inv(T_true) @ T)
    return float(np.linalg.norm(e[3:])), float(np.degrees(np.linalg.norm(e[:3])))


@pytest.fixture(scope="module")
def office():
    return _mapped_office()


def test_cache_is_the_network_at_its_vertices_and_exact_on_planes(office):
    m, T_true, pts = office
    cache = SdfCache(m, 0.02, 0.03)
    X = pts @ T_true[:3, :3].T + T_true[:3, 3]
    s, g, ok = cache.sdf_and_grad(X)
    assert ok.mean() > 0.8
    # at vertices: the network's own values
    keys = cache.keys[cache.ok][:200]
    from simn_sim.mapping.sdf_cache import _unpack

    V = (_unpack(keys) * 0.02).astype(np.float32)
    sv, gv = m.tracking_sdf(0.0, 0.03).sdf_and_grad(torch.from_numpy(V))
    cs, cg, cok = cache.sdf_and_grad(V.astype(np.float64))
    assert cok.all()
    np.testing.assert_allclose(cs, sv.numpy(), atol=1e-5)
    # between vertices: within a fraction of a millimetre of the network on this scene
    se, _ = m.tracking_sdf(0.0, 0.03).sdf_and_grad(torch.from_numpy(X.astype(np.float32)))
    se = se.numpy()
    both = ok & np.isfinite(se)
    assert np.median(np.abs(s[both] - se[both])) < 5e-4
    assert np.all(np.abs(np.linalg.norm(g[ok], axis=1) - 1) < 0.5)


def test_fast_path_recovers_a_5cm_3deg_perturbation_deterministically(office):
    """Measured when the test was written: fast and exact both end within ~1 mm / 0.05 deg; the bounds
    leave margin for BLAS / CPU differences, not for a broken cache."""
    m, T_true, pts = office
    T0 = _perturbed(T_true)
    assert _error(T_true, T0)[0] > 0.049
    runs = []
    for _ in range(2):
        cache = SdfCache(m, 0.02, 0.03)
        cache.prepare(pts @ T0[:3, :3].T + T0[:3, 3])
        res = register(pts, cache.sdf_and_grad, T0, REG)
        assert res.success, res.reason
        runs.append(res.pose)
    et, er = _error(T_true, runs[0])
    assert et < 0.005 and er < 0.25, (et, er)
    np.testing.assert_array_equal(runs[0], runs[1])  # bit-identical
    exact = register(pts, m.tracking_sdf(0.0, 0.03).sdf_and_grad, T0, REG)
    assert exact.success
    dt, dr = _error(exact.pose, runs[0])
    assert dt < 0.003 and dr < 0.15, (dt, dr)


def test_cache_rebakes_when_the_map_changed(office):
    m, T_true, pts = office
    X = pts @ T_true[:3, :3].T + T_true[:3, 3]
    cache = SdfCache(m, 0.02, 0.03)
    cache.prepare(X)
    n0, baked0 = len(cache), cache.baked
    assert n0 == baked0 > 0
    cache.prepare(X)  # nothing changed: nothing baked
    cache.sdf_and_grad(X)
    assert cache.baked == baked0
    m.n_trainings += 1  # as after a training: every vertex touched is re-baked
    try:
        cache.prepare(X)
    finally:
        m.n_trainings -= 1
    assert cache.baked == 2 * baked0 and len(cache) == n0


def test_kdtree_knn_equals_the_bucket_grids():
    from simn_sim.mapping.config import NeuralPointsConfig
    from simn_sim.mapping.neural_points import NeuralPointMap

    g = torch.Generator().manual_seed(0)
    m = NeuralPointMap(NeuralPointsConfig(voxel_size=0.02, k_neighbors=8), "cpu", g)
    u = torch.rand(40000, 2, generator=g)
    floor = torch.stack([u[:20000, 0] * 3, u[:20000, 1] * 2, torch.zeros(20000)], 1)
    wall = torch.stack([u[20000:, 0] * 3, torch.full((20000,), 2.0), u[20000:, 1] * 2], 1)
    m.add_points(torch.cat([floor, wall]))
    m.add_points(torch.rand(3000, 3, generator=g) * torch.tensor([3.0, 2.0, 0.0]) + 0.3)
    q = torch.cat([floor[:3000], wall[:3000]]) + torch.randn(6000, 3, generator=g) * 0.05
    assert m._trees is not None
    i1, d1 = m.knn(q)
    m.use_trees = False
    m._rebuild_index()
    assert m._trees is None and m._fine is not None
    i2, d2 = m.knn(q)
    assert (i1 == i2).all()
    torch.testing.assert_close(d1, d2)
    m._fine = None  # the coarse grid alone (one level)
    i3, _ = m.knn(q)
    assert (i3 == i2).all()


@pytest.mark.parametrize("latency", [0, 1])
def test_training_on_the_worker_thread_gives_the_synchronous_poses(latency):
    """``train_async``: the next frame joins the training before it tracks (``train_latency``
    0) or after (1: it tracks against the map as it was before that training), so the poses
    are bit-identical to training in the step with the same latency (frames rendered from the
    analytic office), and either latency tracks the true poses to within 1 cm."""
    from simn_sim.geometry.camera import Intrinsics
    from simn_sim.slam import SimnSlam, SlamConfig

    scene = office_scene()
    intr = Intrinsics.from_fovy(96, 72)
    poses = []
    for i in range(6):
        eye = np.array([-0.5 + 0.04 * i, -0.6, 1.2])
        a = np.radians(2.0 * i)
        poses.append(look_at(eye, eye + np.array([np.cos(a), np.sin(a) + 0.6, -0.3])))
    frames = [scene.render_depth(intr, T) for T in poses]
    trajs, jobs = [], []
    for async_ in (False, True):
        cfg = SlamConfig.for_agent(  # a camera without a base: no floor plane to keep
            train_async=async_,
            train_latency=latency,
            planar=False,
            semantics=False,
            open_train_iters=3,
            train_iters=2,
        )
        slam = SimnSlam(cfg, intr)
        for k, depth in enumerate(frames):
            slam.process(0.1 * (k + 1), None, depth)
        slam.close()
        trajs.append(np.stack([T for _, T in slam.trajectory()]))
        jobs.append(0 if slam.trainer is None else slam.trainer.jobs)
        assert slam.tracking_map == "learned"
        assert slam.n_track_failures <= 1
    assert jobs == [0, len(frames)]
    np.testing.assert_array_equal(trajs[0], trajs[1])
    # against the true poses (the first frame defines the world): the camera moved 4 cm per
    # frame; either latency tracks it to within 1 cm
    T0 = poses[0]
    err = [
        np.linalg.norm((T0 @ T)[:3, 3] - Tt[:3, 3]) for T, Tt in zip(trajs[0], poses, strict=True)
    ]
    assert max(err) < 0.01


def test_torch_threads_stay_held_while_a_chunk_runs_on_the_worker():
    """With ``train_async`` the caller's torch threads stay at ``torch_threads`` from a frame's
    ``process`` until its training chunk is joined (``sync``, the next frame or ``close``),
    then are given back. Given back mid-chunk they made in-process episodes irreproducible
    (one seed: 151-157 steps at 2 threads)."""
    from simn_sim.geometry.camera import Intrinsics
    from simn_sim.slam import SimnSlam, SlamConfig

    scene = office_scene()
    intr = Intrinsics.from_fovy(96, 72)
    eye = np.array([-0.5, -0.6, 1.2])
    depth = scene.render_depth(intr, look_at(eye, eye + np.array([0.0, 0.6, -0.3])))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        cfg = SlamConfig.for_agent(
            train_async=True,
            planar=False,  # a camera without a base
            semantics=False,
            open_train_iters=2,
            train_iters=1,
            torch_threads=1,
        )
        slam = SimnSlam(cfg, intr)
        slam.process(0.1, None, depth)
        assert slam.trainer is not None and slam.trainer.busy  # the chunk is on the worker
        assert torch.get_num_threads() == 1  # held
        slam.sync()
        assert torch.get_num_threads() == 2  # given back at the join
        slam.process(0.2, None, depth)
        assert slam.trainer.busy and torch.get_num_threads() == 1
        slam.close()
        assert torch.get_num_threads() == 2
        # without a worker thread nothing runs beside the caller: given back at once
        slam = SimnSlam(
            SlamConfig.for_agent(train_async=False, planar=False, semantics=False), intr
        )
        slam.process(0.1, None, depth)
        assert torch.get_num_threads() == 2
        slam.close()
    finally:
        torch.set_num_threads(before)


def test_reused_neighbour_tables_equal_a_fresh_query():
    """TrackingSdf with ``reuse_distance``: within it the neighbours of the last k-NN search
    and their gathered tables are reused (no search, no gather), and the SDF and gradient equal
    ``ImplicitMap.query`` given the neighbours of an exact k-NN search at the search points
    (tables gathered afresh); beyond it, or after a training (features changed, no point
    added), it searches and gathers again."""
    m, T_true, pts = _mapped_office(train_iters=5)
    X = torch.from_numpy((pts @ T_true[:3, :3].T + T_true[:3, 3]).astype(np.float32))
    tsdf = m.tracking_sdf(0.005, None)
    tsdf.sdf_and_grad(X)
    assert tsdf.searches == 1
    idx0, _ = m.points.knn(X)  # the exact KD-tree neighbours at the search points
    X2 = X + torch.tensor([0.002, -0.002, 0.001])  # 3 mm: reused
    s2, g2 = tsdf.sdf_and_grad(X2)
    assert tsdf.searches == 1 and tsdf.evaluations == 2
    ref = m.query(X2, with_grad=True, neighbors=idx0)
    torch.testing.assert_close(s2, ref.sdf, rtol=0, atol=0, equal_nan=True)
    torch.testing.assert_close(g2, ref.grad, rtol=0, atol=0, equal_nan=True)
    X3 = X + torch.tensor([0.006, 0.0, 0.0])  # 6 mm: searched again, exact neighbours
    s3, _ = tsdf.sdf_and_grad(X3)
    assert tsdf.searches == 2
    ref3 = m.query(X3, with_grad=True)  # the map's own k-NN at X3
    torch.testing.assert_close(s3, ref3.sdf, rtol=0, atol=0, equal_nan=True)
    # a training changes the features, not the points: the tables are gathered again
    rng = np.random.default_rng(1)
    m.integrate_frame(render_points(office_scene(), T_true, 5000, rng), T_true, train=False)
    tsdf.sdf_and_grad(X3)
    n_search = tsdf.searches
    m.train(3)
    s4, g4 = tsdf.sdf_and_grad(X3)
    assert tsdf.searches == n_search + 1
    ref4 = m.query(X3, with_grad=True)
    torch.testing.assert_close(s4, ref4.sdf, rtol=0, atol=0, equal_nan=True)
    torch.testing.assert_close(g4, ref4.grad, rtol=0, atol=0, equal_nan=True)
    assert not torch.equal(torch.nan_to_num(s4), torch.nan_to_num(s3))  # the training did change it


def test_normal_space_selection_spreads_the_points_over_the_normal_directions():
    """``track_point_selection: normals``: registration points round robin over the normal
    bins, so a bin with fewer points than its share keeps them all (here a wall facing along
    the corridor of 10 voxels among 1000), the same points for the same seed; ``random`` (the
    agent's) draws as before."""
    from simn_sim.geometry.voxel import voxel_mean
    from simn_sim.slam import SlamConfig
    from simn_sim.slam.track import Tracker

    # one point per 6 cm voxel: floor (normal z) 900, side wall (x) 90, end wall (y) 10
    g = np.stack(np.meshgrid(np.arange(30), np.arange(30), indexing="ij"), -1).reshape(-1, 2)
    floor = np.c_[g * 0.06 + 0.03, np.full(900, 1.03)]
    side = np.c_[
        np.full(90, 0.03), (np.arange(90) % 30) * 0.06 + 0.03, (np.arange(90) // 30) * 0.06 + 1.21
    ]
    end = np.c_[(np.arange(10) * 0.06 + 0.03), np.full(10, 2.43), np.full(10, 1.51)]
    pts = np.concatenate([floor, side, end]).astype(np.float32)
    nrm = np.repeat(np.eye(3)[[2, 0, 1]], [900, 90, 10], axis=0).astype(np.float32)
    assert len(voxel_mean(pts, 0.06)[0]) == 1000
    picks = []
    for _ in range(2):
        cfg = SlamConfig.for_agent(max_track_points=100, track_point_selection="normals")
        tr = Tracker(cfg, None, np.random.default_rng(5))
        tp = tr.track_points(pts, nrm)
        assert len(tp) == 100
        kind = np.where(tp[:, 2] < 1.1, 0, np.where(np.abs(tp[:, 0] - 0.03) < 1e-4, 1, 2))
        kind[(tp[:, 1] > 2.4)] = 2
        assert np.bincount(kind, minlength=3).tolist() == [45, 45, 10]
        picks.append(tp)
    np.testing.assert_array_equal(picks[0], picks[1])
    cfg = SlamConfig.for_points_agent(max_track_points=100)  # random selection
    tr = Tracker(cfg, None, np.random.default_rng(5))
    ref = voxel_mean(pts, 0.06)[0][np.random.default_rng(5).choice(1000, 100, replace=False)]
    np.testing.assert_array_equal(tr.track_points(pts, nrm), ref.astype(np.float32))
