"""LM registration on an analytic SDF scene (box room + boxes + sphere)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from simn_sim.config import ConfigError
from simn_sim.geometry.se3 import inv_T, pose_error, se3_exp
from simn_sim.tracking.lie import adjoint, constant_velocity_prior, se3_log
from simn_sim.tracking.registration import RegistrationConfig, register
from simn_sim.tracking.synthetic import (
    AnalyticScene,
    look_at,
    office_scene,
    plane_scene,
    render_points,
)

SCENE = office_scene()
T_TRUE = look_at(np.array([-0.5, -0.8, 1.2]), np.array([1.5, 1.0, 0.6]))


@pytest.fixture(scope="module")
def points() -> np.ndarray:
    P = render_points(SCENE, T_TRUE, 4000, np.random.default_rng(0))
    assert P.shape[0] > 3500 and P.dtype == np.float32
    return P


def _perturbation(rng: np.random.Generator, deg: float, metres: float) -> np.ndarray:
    w = rng.normal(size=3)
    v = rng.normal(size=3)
    return se3_exp(
        np.concatenate([w / np.linalg.norm(w) * np.radians(deg), v / np.linalg.norm(v) * metres])
    )


def test_lie_roundtrip_and_adjoint() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        xi = rng.normal(size=6) * np.array([1, 1, 1, 2, 2, 2])
        T = se3_exp(xi)
        assert np.allclose(se3_exp(se3_log(T)), T, atol=1e-9)
        eta = rng.normal(size=6) * 0.1
        assert np.allclose(T @ se3_exp(eta) @ inv_T(T), se3_exp(adjoint(T) @ eta), atol=1e-9)


def test_constant_velocity_prior() -> None:
    D = se3_exp(np.array([0.01, -0.02, 0.03, 0.05, 0.0, -0.01]))
    T0 = look_at(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 1.0]))
    T1 = T0 @ D
    assert np.allclose(constant_velocity_prior(T0, T1), T1 @ D, atol=1e-12)
    half = constant_velocity_prior(T0, T1, dt_ratio=0.5)
    step = inv_T(T1) @ half  # half of the last body-frame motion
    assert np.allclose(step @ step, D, atol=1e-9)
    assert np.allclose(constant_velocity_prior(T1, T1), T1)


def test_recovers_10cm_10deg_perturbation(points: np.ndarray) -> None:
    rng = np.random.default_rng(2)
    for _ in range(8):
        T_init = T_TRUE @ _perturbation(rng, 10.0, 0.10)
        res = register(points, SCENE.sdf_and_grad, T_init)
        et, er = pose_error(res.pose, T_TRUE)
        assert res.success, res.reason
        assert et < 2e-3 and np.degrees(er) < 0.2, (et, np.degrees(er))
        assert res.final_rms < 1e-3 and res.n_valid > 0.9 * len(points)
        assert res.iterations <= 15


def test_noisy_points(points: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    for _ in range(4):
        noisy = points + rng.normal(scale=0.005, size=points.shape).astype(np.float32)
        res = register(noisy, SCENE.sdf_and_grad, T_TRUE @ _perturbation(rng, 5.0, 0.05))
        et, er = pose_error(res.pose, T_TRUE)
        assert res.success, res.reason
        # 4k points with 5 mm noise: measured <= 1.1 mm / 0.03 deg; allow 3 mm / 0.15 deg.
        assert et < 3e-3 and np.degrees(er) < 0.15, (et, np.degrees(er))
        assert 0.003 < res.final_rms < 0.007


def test_outliers_are_downweighted(points: np.ndarray) -> None:
    rng = np.random.default_rng(4)
    P = points + rng.normal(scale=0.005, size=points.shape).astype(np.float32)
    idx = rng.choice(len(P), int(0.15 * len(P)), replace=False)
    P[idx] += (rng.normal(size=(len(idx), 3)) * 0.3).astype(np.float32)
    res = register(P, SCENE.sdf_and_grad, T_TRUE @ _perturbation(rng, 3.0, 0.05))
    et, er = pose_error(res.pose, T_TRUE)
    assert res.success and et < 3e-3 and np.degrees(er) < 0.15
    # plain least squares (a very wide fixed kernel) is pulled off by the outliers
    wide = RegistrationConfig(gm_scale=5.0, gm_mad_factor=0.0, max_final_rms=1.0)
    bad = register(P, SCENE.sdf_and_grad, T_TRUE @ _perturbation(rng, 3.0, 0.05), wide)
    assert pose_error(bad.pose, T_TRUE)[0] > 2 * et


def test_covariance_matches_monte_carlo(points: np.ndarray) -> None:
    """Covariance is in gtsam's convention: T_est = T_true exp(delta), delta = (omega, v)."""
    rng = np.random.default_rng(5)
    sigma = 0.005
    deltas, covs = [], []
    for _ in range(25):
        noisy = points + rng.normal(scale=sigma, size=points.shape).astype(np.float32)
        res = register(noisy, SCENE.sdf_and_grad, T_TRUE)
        assert res.success
        deltas.append(se3_log(inv_T(T_TRUE) @ res.pose))
        covs.append(res.covariance)
    cov = np.mean(covs, axis=0)
    assert np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov).min() > 0
    emp = np.var(np.array(deltas), axis=0) + np.mean(deltas, axis=0) ** 2
    ratio = emp / np.diag(cov)
    assert np.all(ratio > 0.2) and np.all(ratio < 5.0), ratio


@pytest.mark.parametrize("kind", ["plane", "corridor"])
def test_degenerate_scenes_report_failure(kind: str) -> None:
    """A single plane (3 free DOF) or a corridor of planes (free along its axis) -> failure."""
    if kind == "plane":
        scene = plane_scene()
    else:
        scene = AnalyticScene(
            planes=(
                (np.array([0.0, 0.0, 1.0]), 0.0),
                (np.array([0.0, 1.0, 0.0]), -1.0),
                (np.array([0.0, -1.0, 0.0]), -1.0),
            )
        )
    T = look_at(np.array([0.0, 0.0, 1.0]), np.array([2.0, 0.3, 0.0]))
    P = render_points(scene, T, 3000, np.random.default_rng(6))
    T_init = T @ _perturbation(np.random.default_rng(7), 3.0, 0.03)
    res = register(P, scene.sdf_and_grad, T_init)
    assert not res.success and "degenerate" in res.reason, res.reason
    assert np.array_equal(res.pose, T_init)
    assert np.all(np.diag(res.covariance) >= 1e3)


def test_not_an_sdf_fails_cleanly(points: np.ndarray) -> None:
    def steep(q):
        s, g, v = SCENE.sdf_and_grad(q)
        return 3 * s, 3 * g, v

    res = register(points, steep, T_TRUE)
    assert not res.success and "valid" in res.reason

    def nowhere(q):  # a map that knows nothing near the points: NaN, no validity output
        return np.full(len(q), np.nan), np.full((len(q), 3), np.nan)

    res = register(points, nowhere, T_TRUE)
    assert not res.success and np.array_equal(res.pose, T_TRUE)


def test_far_prior_reports_failure(points: np.ndarray) -> None:
    """Looking the opposite way along the optical axis: no consistent pose nearby -> failure."""
    T_init = T_TRUE @ se3_exp(np.array([0.0, 0.0, np.pi, 0.0, 0.0, 0.0]))
    res = register(points, SCENE.sdf_and_grad, T_init)
    assert not res.success and "residual" in res.reason
    assert np.array_equal(res.pose, T_init)


def test_torch_callable(points: np.ndarray) -> None:
    def torch_sdf(q: torch.Tensor):
        assert isinstance(q, torch.Tensor) and q.dtype == torch.float32
        s, g, _ = SCENE.sdf_and_grad(q.numpy())
        return torch.from_numpy(s).float(), torch.from_numpy(g).float()

    T_init = T_TRUE @ _perturbation(np.random.default_rng(8), 2.0, 0.02)
    res = register(torch.from_numpy(points), torch_sdf, T_init, points_as="torch")
    et, er = pose_error(res.pose, T_TRUE)
    assert res.success and et < 2e-3 and np.degrees(er) < 0.2


def test_bad_input(points: np.ndarray) -> None:
    f = SCENE.sdf_and_grad
    with pytest.raises(ValueError, match="shape"):
        register(points[:, :2], f, T_TRUE)
    with pytest.raises(ValueError, match="float32"):
        register(points.astype(np.int32), f, T_TRUE)
    with pytest.raises(ValueError, match="empty"):
        register(points[:0], f, T_TRUE)
    bad = points.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        register(bad, f, T_TRUE)
    T = T_TRUE.copy()
    T[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        register(points, f, T)
    with pytest.raises(ValueError, match="4x4"):
        register(points, f, np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        register(points, f, np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ConfigError, match="lambda_reg"):
        RegistrationConfig(lambda_reg=0.0)
    with pytest.raises(ConfigError, match="unknown"):
        RegistrationConfig.from_dict({"lamda_reg": 1e-3})


TUM = str(__import__("pathlib").Path(__file__).parent / "data" / "tum_fr1_desk_9")


@pytest.mark.skipif(not __import__("os").path.isdir(TUM), reason="shared TUM sample not present")
def test_real_tum_frame_to_frame() -> None:
    """Register real fr1/desk depth to the previous frame's point-to-plane surface (no map
    training): the estimate must beat the identity prior and agree with ground truth."""
    from simn_sim.geometry.camera import backproject
    from simn_sim.io.tum import read_tum
    from simn_sim.tracking.pointsdf import PointCloudSDF, voxel_downsample

    seq = read_tum(TUM, camera="fr1")
    rng = np.random.default_rng(0)
    err_t, err_r, prior_r = [], [], []
    for k in (1, 4, 7):
        ref, cur = seq[k - 1], seq[k]
        surf = PointCloudSDF.from_depth(ref.depth, seq.intrinsics)
        P = backproject(cur.depth, seq.intrinsics)[cur.depth > 0]
        P = P[voxel_downsample(P, 0.02)]
        P = P[rng.choice(len(P), min(4000, len(P)), replace=False)]
        res = register(P, surf.sdf_and_grad, np.eye(4))
        gt = inv_T(ref.T_world_cam) @ cur.T_world_cam
        et, er = pose_error(res.pose, gt)
        assert res.success and res.inlier_fraction > 0.9, res.reason
        err_t.append(et)
        err_r.append(np.degrees(er))
        prior_r.append(np.degrees(pose_error(np.eye(4), gt)[1]))
    # measured: 1.4-4.6 mm, 0.06-0.7 deg per pair (ground truth and sensor sync limit it)
    assert max(err_t) < 0.008 and max(err_r) < 1.0, (err_t, err_r)
    assert np.mean(err_r) < 0.6 * np.mean(prior_r)


def test_frame_tracker_constant_velocity_and_rebase() -> None:
    from simn_sim.tracking.tracker import FrameTracker

    rng = np.random.default_rng(9)
    step = se3_exp(np.array([0.0, np.radians(1.5), 0.0, 0.03, 0.0, 0.01]))  # camera-frame motion
    poses = [T_TRUE]
    for _ in range(8):
        poses.append(poses[-1] @ step)
    tr = FrameTracker()
    tr.reset(poses[0], 0.0)
    for k in range(1, 5):
        P = render_points(SCENE, poses[k], 3000, rng)
        res = tr.track(P, SCENE.sdf_and_grad, k / 30.0)
        et, er = pose_error(res.pose, poses[k])
        assert res.success and et < 2e-3 and np.degrees(er) < 0.2
        if k >= 3:  # constant velocity: the prior is already exact, LM needs ~1-2 iterations
            assert res.iterations <= 3
    # a new local frame opens at the current camera: its coordinates are T_new_world
    T_world_new = poses[4]
    tr.rebase(inv_T(T_world_new))
    assert np.allclose(tr.pose, np.eye(4), atol=1e-6)  # tracked pose (float32 points)

    def sdf_new(q):
        s, g, v = SCENE.sdf_and_grad(q @ T_world_new[:3, :3].T + T_world_new[:3, 3])
        return s, g @ T_world_new[:3, :3], v

    P = render_points(SCENE, poses[5], 3000, rng)
    res = tr.track(P, sdf_new, 5 / 30.0)
    et, er = pose_error(T_world_new @ res.pose, poses[5])
    assert res.success and et < 2e-3 and np.degrees(er) < 0.2 and res.iterations <= 3
    # a failing map (a single plane): the prediction is kept and the failure counted
    pred = tr.predict(6 / 30.0)
    res = tr.track(P, plane_scene().sdf_and_grad, 6 / 30.0)
    assert not res.success and tr.n_failures == 1 and np.allclose(tr.pose, pred)
    with pytest.raises(ValueError, match="not after"):
        tr.track(P, sdf_new, 6 / 30.0)


def test_bad_weights(points: np.ndarray) -> None:
    f = SCENE.sdf_and_grad
    n = len(points)
    with pytest.raises(ValueError, match="shape"):
        register(points, f, T_TRUE, weights=np.ones(n - 1))
    with pytest.raises(ValueError, match="shape"):
        register(points, f, T_TRUE, weights=np.ones((n, 1)))
    w = np.ones(n)
    w[5] = -0.1
    with pytest.raises(ValueError, match=">= 0"):
        register(points, f, T_TRUE, weights=w)
    w = np.ones(n)
    w[7] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        register(points, f, T_TRUE, weights=w)
    with pytest.raises(ValueError, match="all zero"):
        register(points, f, T_TRUE, weights=np.zeros(n))


def test_weights_downweight_a_biased_subset(points: np.ndarray) -> None:
    """A third of the points is shifted 1.5 cm along the optical axis (a biased sensor region:
    inside the Geman-McClure scale, so the robust loss keeps them). With equal weights the
    estimate follows them; weighting them 1e-3 recovers the true pose."""
    rng = np.random.default_rng(7)
    P = points + rng.normal(scale=0.002, size=points.shape).astype(np.float32)
    bad = P[:, 0] > np.quantile(P[:, 0], 2 / 3)  # the right third of the image
    P[bad, 2] += 0.015
    w = np.where(bad, 1e-3, 1.0)
    errs = {}
    for name, weights in (("equal", None), ("weighted", w)):
        res = register(
            P, SCENE.sdf_and_grad, T_TRUE @ _perturbation(rng, 3.0, 0.03), weights=weights
        )
        assert res.success, res.reason
        errs[name] = pose_error(res.pose, T_TRUE)
    assert errs["weighted"][0] < 1.5e-3, errs
    assert errs["equal"][0] > 3 * errs["weighted"][0], errs


def test_kernel_point_sdf_keeps_slope_on_a_noisy_slab() -> None:
    """A plane sampled with 1.5 cm normal noise (a depth-noise-thickened surface store): the
    nearest-point SDF barely changes when the query moves off the surface (the nearest sample
    is one the noise moved towards it), the kernel SDF keeps a slope and is less noisy."""
    from simn_sim.tracking.pointsdf import PointCloudSDF

    rng = np.random.default_rng(0)
    g = np.arange(0.0, 1.0, 0.02)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2).repeat(5, axis=0)
    P = np.c_[xy + rng.uniform(-0.01, 0.01, xy.shape), rng.normal(0, 0.015, len(xy))]
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    q = np.c_[rng.uniform(0.3, 0.7, (500, 2)), np.zeros(500)]
    out = {}
    for kernel in (0.0, 0.03):
        f = PointCloudSDF(P, N, max_dist=0.06, kernel=kernel, k=8)
        s0, g0, v0 = f.sdf_and_grad(q)
        s1, _, v1 = f.sdf_and_grad(q + [0.0, 0.0, 0.01])
        assert v0.all() and v1.all()
        assert np.allclose(np.linalg.norm(g0, axis=1), 1.0)  # parallel normals
        out[kernel] = (float(np.mean(s1 - s0) / 0.01), float(np.std(s0)))
    (slope_nn, sd_nn), (slope_k, sd_k) = out[0.0], out[0.03]
    assert slope_k > 3 * slope_nn and slope_k > 0.15, out
    assert sd_k < 0.7 * sd_nn, out
    with pytest.raises(ValueError, match="kernel"):
        PointCloudSDF(P, N, kernel=-1.0)
    with pytest.raises(ValueError, match="confidence"):
        PointCloudSDF(P, N, kernel=0.03, confidence=np.ones(3))


def test_planar_registration_moves_only_on_the_floor_plane(points: np.ndarray) -> None:
    """``up``: a pose perturbed on the floor plane (yaw about the world's z, x-y shift) is
    recovered exactly; a pose lifted and tilted off it keeps its height and tilt (only yaw,
    x and y move); the covariance has rank 3, spanned by the planar twists."""
    from simn_sim.geometry.se3 import planar_T
    from simn_sim.tracking.registration import planar_basis

    up = np.array([0.0, 0.0, 1.0])  # the office scene's floor normal in its (map) frame
    for k, (yaw, dx, dy) in enumerate([(6.0, 0.08, -0.05), (-9.0, -0.06, 0.07)]):
        T_init = planar_T(dx, dy, np.radians(yaw)) @ T_TRUE
        res = register(points, SCENE.sdf_and_grad, T_init, up=up)
        assert res.success, res.reason
        et, er = pose_error(res.pose, T_TRUE)
        assert et < 1e-3 and np.degrees(er) < 0.05, (k, et, np.degrees(er))
        sv = np.linalg.svd(res.covariance, compute_uv=False)
        assert sv[2] > 1e-6 * sv[0] and sv[3] < 1e-9 * sv[0], sv  # rank 3
        # in map (left) coordinates it lies in the planar twists' span
        Ad = adjoint(res.pose)
        Cm = Ad @ res.covariance @ Ad.T
        B = planar_basis(up)
        Bp = np.linalg.pinv(B)
        np.testing.assert_allclose(B @ Bp @ Cm @ Bp.T @ B.T, Cm, atol=1e-9 * sv[0])
    lift = se3_exp(np.array([np.radians(0.5), 0.0, 0.0, 0.0, 0.0, 0.01]))  # off the plane
    T_init = planar_T(0.05, 0.03, np.radians(4.0)) @ T_TRUE @ lift
    res = register(points, SCENE.sdf_and_grad, T_init, up=up)
    assert res.success, res.reason
    D = res.pose @ inv_T(T_init)  # the motion LM made, in map coordinates
    assert pose_error(res.pose, T_init)[0] > 0.01  # it moved
    np.testing.assert_allclose(D[:3, :3] @ up, up, atol=1e-9)  # a rotation about up only
    np.testing.assert_allclose(res.pose[2, 3], T_init[2, 3], atol=1e-9)  # height kept
    unconstrained = register(points, SCENE.sdf_and_grad, T_init)
    assert pose_error(unconstrained.pose, T_TRUE)[0] < 2e-3  # 6 DoF goes back up to the truth
    for bad in ([0.0, 0.0, 2.0], [np.nan, 0.0, 1.0], [0.0, 1.0]):
        with pytest.raises(ValueError, match="up must be a finite unit 3-vector"):
            register(points, SCENE.sdf_and_grad, T_TRUE, up=bad)


def test_depth_noise_weights_lower_the_error_under_stereo_noise() -> None:
    """Depth noise that grows with z^2 along each ray (the D435i's stereo model at 320x240:
    sigma = 0.0052 z^2 m) on a view 1.3-3.6 m deep: the slam front-end's inverse-variance
    weights (``depth_noise_weights``, floor 1 cm) register closer to the true pose than equal
    weights, over 8 draws (measured: mean 3.76 -> 2.70 mm, 0.129 -> 0.091 deg)."""
    from simn_sim.slam.track import depth_noise_weights

    T = look_at(np.array([0.3, 0.0, 1.0]), np.array([1.8, 1.2, 0.4]))
    k = 0.0052
    err = {"equal": [], "weighted": []}
    for seed in range(8):
        rng = np.random.default_rng(seed)
        P = render_points(SCENE, T, 4000, rng).astype(np.float64)
        z = P[:, 2]
        noisy = (P * (1.0 + rng.normal(size=len(z)) * k * z)[:, None]).astype(np.float32)
        w = depth_noise_weights(noisy[:, 2], 0.01, k)  # from the measured depth, as in SLAM
        assert w.max() <= 1.0 and w.min() > 0.0
        T0 = T @ _perturbation(rng, 2.0, 0.02)
        for name, weights in (("equal", None), ("weighted", w)):
            res = register(noisy, SCENE.sdf_and_grad, T0, weights=weights)
            assert res.success, res.reason
            et, er = pose_error(res.pose, T)
            err[name].append((et, np.degrees(er)))
    eq, wt = np.mean(err["equal"], axis=0), np.mean(err["weighted"], axis=0)
    assert wt[0] < 0.8 * eq[0] and wt[1] < 0.8 * eq[1], (eq, wt)
    with pytest.raises(ValueError, match="sigma0"):
        depth_noise_weights(np.ones(3), 0.0, k)
