"""The decoder's geometric prior, per-neighbour decoding, normal-corrected ray labels and the
tracking SDF, against exact ground truth (planes at known distance, an analytic office)."""

import numpy as np
import pytest
import torch

from simn_sim.config import ConfigError
from simn_sim.mapping import ImplicitMap, MapperConfig
from simn_sim.mapping.config import SamplingConfig
from simn_sim.mapping.mapper import estimate_normals
from simn_sim.mapping.sampling import sample_rays
from simn_sim.tracking.lie import se3_log
from simn_sim.tracking.registration import RegistrationConfig, register
from simn_sim.tracking.synthetic import look_at, office_scene, render_points

torch.set_num_threads(1)


def _cfg(decoder=None, points=None, training=None):
    d = {"decoder": {"geometric_prior": True, **(decoder or {})}, "seed": 1}
    d["points"] = points or {}
    d["training"] = {"batch_size": 1024, "max_iters": 20, "min_iters": 5, **(training or {})}
    return MapperConfig.from_dict(d)


def _tilted_plane(n_side=60, half=0.6, dist=1.5):
    """Camera-frame points of the plane n . p = dist, n tilted 30 deg from the optical axis
    (normal towards the camera: n . p < 0 in front), and its unit normal (pointing at the
    camera)."""
    a = np.radians(30)
    n = np.array([np.sin(a), 0.0, -np.cos(a)])  # towards the camera (origin)
    centre = -n * dist
    u = np.array([np.cos(a), 0.0, np.sin(a)])
    v = np.array([0.0, 1.0, 0.0])
    s = np.linspace(-half, half, n_side)
    S, T = np.meshgrid(s, s)
    P = centre + S.reshape(-1, 1) * u + T.reshape(-1, 1) * v
    return P.astype(np.float32), n


@pytest.mark.parametrize("given_normals", [True, False])
def test_untrained_prior_is_the_distance_to_a_plane(given_normals):
    P, n = _tilted_plane()
    m = ImplicitMap(_cfg())
    nrm = np.broadcast_to(n, P.shape).astype(np.float32) if given_normals else None
    m.integrate_frame(P, np.eye(4), train=False, normals=nrm)
    rng = np.random.default_rng(0)
    base = P[rng.choice(len(P), 300)]
    inner = np.abs(base[:, 1]) < 0.4  # away from the patch's border
    u = np.array([np.cos(np.radians(30)), 0.0, np.sin(np.radians(30))])
    base = base[inner & (np.abs(base @ u) < 0.4)]
    off = rng.uniform(-0.04, 0.04, len(base))
    X = (base + off[:, None] * n).astype(np.float32)
    q = m.query(X, with_grad=True)
    assert q.valid.all()
    np.testing.assert_allclose(q.sdf, off, atol=1e-3)  # exact plane distance, sign in front +
    np.testing.assert_allclose(q.grad, np.broadcast_to(n, q.grad.shape), atol=2e-3)


def test_prior_only_ablation_learns_nothing_and_equals_the_prior():
    P, n = _tilted_plane()
    nrm = np.broadcast_to(n, P.shape).astype(np.float32)
    prior_only = ImplicitMap(_cfg({"residual": False}))
    prior_only.integrate_frame(P, np.eye(4), train=False, normals=nrm)
    res = prior_only.train()
    assert res.iterations == 0
    learned = ImplicitMap(_cfg())
    learned.integrate_frame(P, np.eye(4), train=False, normals=nrm)
    X = P[::7] + 0.01 * n.astype(np.float32)
    # the residual's last layer starts at zero: untrained, both are the prior
    np.testing.assert_allclose(learned.sdf(X), prior_only.sdf(X), atol=1e-6)
    learned.train(20)
    assert learned.n_trainings == 1
    assert not np.allclose(learned.sdf(X), prior_only.sdf(X), atol=1e-6)  # it learned
    with pytest.raises(ConfigError):
        MapperConfig.from_dict({"decoder": {"residual": False}})  # nothing at all


def test_normal_corrected_labels_are_plane_distances():
    P, n = _tilted_plane(n_side=20)
    cfg = SamplingConfig()
    pts = torch.from_numpy(P)
    nrm = torch.from_numpy(np.broadcast_to(n, P.shape).astype(np.float32))
    g = torch.Generator().manual_seed(0)
    s = sample_rays(pts, torch.zeros(3), cfg, g, normals=nrm)
    true = (s.points.numpy().astype(np.float64) + n * 1.5) @ n  # n . x - n . c
    np.testing.assert_allclose(s.sdf.numpy(), true, atol=1e-5)
    plain = sample_rays(pts, torch.zeros(3), cfg, torch.Generator().manual_seed(0))
    front = plain.sdf.numpy() > 0.05
    # along-ray labels over-state the distance to an oblique plane by 1 / cos(theta)
    over = plain.sdf.numpy()[front] / true[front]
    assert (over > 1 - 1e-5).all() and over.mean() > 1.03


def test_per_neighbour_decoding_is_the_idw_blend_of_per_point_decodes():
    P, n = _tilted_plane(n_side=30)
    m = ImplicitMap(_cfg({"decoding": "per_neighbor", "geometric_prior": False}))
    m.integrate_frame(P, np.eye(4), train=False)
    torch.nn.init.normal_(m.decoder.mlp[-1].weight)  # a non-trivial decoder
    X = torch.from_numpy(P[::11] + 0.02 * n.astype(np.float32))
    idx, _ = m.points.knn(X)
    pos, col, feat = m.points.positions, m.points.colors, m.points.features
    want = []
    for i in range(len(X)):
        ids = idx[i][idx[i] >= 0]
        d = (pos[ids] - X[i]).norm(dim=1).clamp(min=1e-3)
        w = d.pow(-m.cfg.points.idw_power)
        w = w / w.sum()
        rel = (X[i] - pos[ids]) / m.cfg.points.search_radius
        out = m.decoder.mlp(torch.cat([feat[ids], col[ids], rel], 1)).squeeze(1)
        want.append(float((w * out).sum()))
    got = m.sdf(X).detach().numpy()
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    # gradient by autograd matches central differences (same neighbours: the k-NN set may
    # change within the step)
    nb = idx[:5]
    q = m.query(X[:5], with_grad=True, neighbors=nb)
    h = 1e-3
    for j in range(3):
        e = torch.zeros(3)
        e[j] = h
        fd = (m.query(X[:5] + e, neighbors=nb).sdf - m.query(X[:5] - e, neighbors=nb).sdf) / (2 * h)
        np.testing.assert_allclose(q.grad[:, j].numpy(), fd.numpy(), atol=5e-3)


def test_tracking_sdf_reuses_neighbours_and_bounds_validity():
    P, n = _tilted_plane()
    m = ImplicitMap(_cfg())
    m.integrate_frame(P, np.eye(4), train=False)
    X = P[::5] + 0.005 * n.astype(np.float32)
    ts = m.tracking_sdf(reuse_distance=0.02)
    s1, g1 = ts.sdf_and_grad(X)
    s2, g2 = ts.sdf_and_grad(X + 0.003)  # moved 5 mm: neighbours reused
    assert ts.searches == 1
    np.testing.assert_allclose(s1, m.sdf(X), atol=1e-6)
    ts.sdf_and_grad(X + 0.05)  # moved beyond the reuse distance: searched again
    assert ts.searches == 2
    # beyond the patch's edge, along the plane: within the map's 15 cm radius, but not
    # within 5 cm of the observed surface
    edge = P[np.argmax(P[:, 1])]  # a point on the y = +0.6 m border
    beyond = (edge + np.array([0.0, 0.08, 0.0])).astype(np.float32)[None]
    assert np.isfinite(m.sdf(beyond)).all()
    s, _ = m.tracking_sdf(max_distance=0.05).sdf_and_grad(beyond)
    assert np.isnan(s).all()
    # 4 cm off the plane (depth noise, not missing map) stays valid
    off = X + 0.04 * n.astype(np.float32)
    s, _ = m.tracking_sdf(max_distance=0.05).sdf_and_grad(off)
    np.testing.assert_allclose(s, 0.045, atol=1e-3)


def test_planes_survive_save_and_load(tmp_path):
    P, n = _tilted_plane()
    m = ImplicitMap(_cfg())
    m.integrate_frame(P, np.eye(4), train=True)
    X = P[::9] + 0.01 * n.astype(np.float32)
    m.consolidate()  # EWC on the prior + residual decoder
    assert m.ewc.active
    m2 = ImplicitMap.load(m.save(tmp_path / "map.pt"))
    np.testing.assert_allclose(m2.sdf(X), m.sdf(X), atol=1e-6)


def test_estimated_normals_point_at_the_camera():
    P, n = _tilted_plane(n_side=25)
    est = estimate_normals(P)
    np.testing.assert_allclose(est, np.broadcast_to(n, est.shape), atol=1e-4)


def test_registration_on_the_prior_map_of_an_analytic_office():
    """Map one view of the analytic office (prior only, exact depth), register a second view
    from a known 5 cm / 3 deg perturbation: recovered to within 2 mm / 0.2 deg."""
    scene = office_scene()
    rng = np.random.default_rng(0)
    T_map = look_at(np.array([0.0, -0.5, 1.2]), np.array([1.8, 1.0, 0.4]))
    m = ImplicitMap(_cfg({"residual": False}, {"weighting": "gaussian"}))
    for _ in range(3):
        Tk = T_map.copy()
        Tk[:3, 3] += rng.normal(0, 0.05, 3)
        pts = render_points(scene, Tk, 30000, rng)
        m.integrate_frame(pts, Tk, train=False)
    T_true = T_map.copy()
    T_true[:3, 3] += [0.02, 0.03, -0.01]
    pts = render_points(scene, T_true, 4000, rng)
    a = np.radians(3.0)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    T_init = T_true.copy()
    T_init[:3, :3] = R @ T_true[:3, :3]
    T_init[:3, 3] += [0.04, -0.03, 0.0]
    res = register(pts, m.tracking_sdf().sdf_and_grad, T_init, RegistrationConfig())
    assert res.success, res.reason
    e = se3_log(np.linalg.inv(T_true) @ res.pose)
    assert np.linalg.norm(e[3:]) < 2e-3 and np.degrees(np.linalg.norm(e[:3])) < 0.2


def _noisy_plane(sigma=0.004, seed=0):
    """The tilted plane with its points moved along the normal by Gaussian noise (a noisy
    depth map of it), and the exact normals."""
    P, n = _tilted_plane()
    rng = np.random.default_rng(seed)
    Pn = (P + rng.normal(0.0, sigma, (len(P), 1)) * n).astype(np.float32)
    return Pn, n, np.broadcast_to(n, P.shape).astype(np.float32)


def test_prior_grad_planes_is_the_blended_normal_on_noisy_points():
    # On a noisy plane the neighbours' plane distances differ by the noise; differentiating
    # through the Gaussian blend weights turns those differences into a tangential gradient.
    # With prior_grad "planes" the weights are held: the gradient is the blend of the
    # neighbours' normals, here exactly n. The value is the same either way.
    Pn, n, nrm = _noisy_plane()
    pts = {"voxel_size": 0.02, "weighting": "gaussian", "gaussian_width": 0.015}
    maps = {}
    for mode in ("full", "planes"):
        m = ImplicitMap(_cfg({"residual": False, "prior_grad": mode}, points=pts))
        m.integrate_frame(Pn, np.eye(4), train=False, normals=nrm)
        maps[mode] = m
    P, _ = _tilted_plane()
    X = P[::5] + 0.005 * n.astype(np.float32)
    full = maps["full"].query(X, with_grad=True)
    held = maps["planes"].query(X, with_grad=True)
    assert held.valid.all() and full.valid.all()
    np.testing.assert_allclose(held.sdf, full.sdf, atol=1e-6)
    np.testing.assert_allclose(held.grad, np.broadcast_to(n, held.grad.shape), atol=1e-5)
    tangential = full.grad - (full.grad @ n)[:, None] * n
    assert np.median(np.linalg.norm(tangential, axis=1)) > 0.05  # what "planes" removes
    with pytest.raises(ConfigError, match="prior_grad"):
        MapperConfig.from_dict({"decoder": {"prior_grad": "planes", "decoding": "per_neighbor"}})


def test_residual_weight_shrinks_the_learned_residual():
    # The residual fitted to noisy labels moves the surface off the averaged prior; a Gaussian
    # prior on the residual (residual_weight) keeps it closer to zero. residual = sdf - prior,
    # the prior read from a prior-only map of the same points.
    Pn, n, nrm = _noisy_plane(sigma=0.006)
    pts = {"voxel_size": 0.02, "weighting": "gaussian", "gaussian_width": 0.02}
    X = _tilted_plane()[0][::3]
    prior = ImplicitMap(_cfg({"residual": False}, points=pts))
    prior.integrate_frame(Pn, np.eye(4), train=False, normals=nrm)
    size = {}
    for lam in (0.0, 5.0):
        m = ImplicitMap(
            _cfg(points=pts, training={"residual_weight": lam, "sigma": 0.02, "max_iters": 60})
        )
        m.integrate_frame(Pn, np.eye(4), train=False, normals=nrm)
        m.train(60)
        size[lam] = float(np.median(np.abs(m.sdf(X) - prior.sdf(X))))
    assert size[0.0] > 2e-4  # it learned something
    assert size[5.0] < 0.5 * size[0.0]
    with pytest.raises(ConfigError, match="residual_weight"):
        MapperConfig.from_dict({"training": {"residual_weight": -1.0}})


def test_plane_cache_updated_row_by_row_equals_a_full_recomputation():
    # planes() recomputes only the rows whose statistics changed and the new points; the
    # result must be bit-identical to computing every row afresh, over many insertions
    from simn_sim.mapping.neural_points import NeuralPointMap, _plane_rows

    rng = np.random.default_rng(5)
    pm = NeuralPointMap(generator=torch.Generator().manual_seed(0))
    for it in range(6):
        p = torch.from_numpy(rng.uniform(-0.3, 0.3, (400, 3)).astype(np.float32))
        n = torch.from_numpy(rng.normal(size=(400, 3)).astype(np.float32))
        n = n / n.norm(dim=1, keepdim=True)
        n[::7] = float("nan")  # rows without a normal
        pm.add_points(p, normals=n)
        if it % 2 == 0:  # also several changes between two reads
            q, nrm = pm.planes()
            rq, rn = _plane_rows(pm.positions, pm.plane_sum, pm.normal_sum, pm.plane_count)
            assert q.shape == (len(pm), 3)
            assert torch.equal(q, rq) and torch.equal(nrm, rn)
    q, nrm = pm.planes()
    rq, rn = _plane_rows(pm.positions, pm.plane_sum, pm.normal_sum, pm.plane_count)
    assert torch.equal(q, rq) and torch.equal(nrm, rn)
    # points seen with normals have unit normals; the rest zero (the prior's definition)
    has = pm.plane_count > 0
    assert has.any() and (~has).any()
    assert torch.allclose(nrm[has].norm(dim=1), torch.ones(int(has.sum())), atol=1e-5)
    assert (nrm[~has] == 0).all()
