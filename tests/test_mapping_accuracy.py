"""SDF accuracy on exact synthetic scans of an analytic scene (box room, boxes, sphere).

The map is trained from 8 exact depth images (160 x 120) through the public API, then queried
at points within 10 cm of the observed surfaces (fresh random offsets along the viewing rays,
not the training samples) and compared with the scene's exact Euclidean SDF.
"""

import numpy as np
import pytest

from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import ImplicitMap, MapperConfig, rgbd_to_points
from simn_sim.mapping.synthetic import box_room_scene, orbit_poses

SCENE = box_room_scene()
INTR = Intrinsics.from_fovy(160, 120)
# Eikonal tolerance: |grad| within 0.1 of 1 for at least 80 % of the valid queries, median
# within 0.05. (Edges and corners of boxes have no unit gradient in a smooth field.)
GRAD_TOL, GRAD_SHARE, GRAD_MEDIAN_TOL = 0.1, 0.8, 0.05


@pytest.fixture(scope="module")
def trained():
    cfg = MapperConfig.from_dict(
        {"training": {"max_pending": 400_000, "loss_threshold": 0.0, "max_iters": 600}, "seed": 0}
    )
    m = ImplicitMap(cfg)
    frames = []
    for T in orbit_poses(8, radius=0.5, height=1.3):
        pc = rgbd_to_points(SCENE.render_depth(INTR, T), INTR)
        frames.append((pc.points, T))
        m.integrate_frame(pc.points, T, train=False)
    res = m.train()
    rng = np.random.default_rng(123)
    q = []
    for pts, T in frames:
        pw = pts @ T[:3, :3].T + T[:3, 3]
        p = pw[rng.choice(len(pw), 1500, replace=False)]
        u = (p - T[:3, 3]) / np.linalg.norm(p - T[:3, 3], axis=1, keepdims=True)
        q.append(p + rng.uniform(-0.1, 0.1, (len(p), 1)) * u)
    q = np.concatenate(q).astype(np.float32)
    true = SCENE.sdf(q)
    near = np.abs(true) <= 0.1
    return m, res, q[near], true[near]


def test_training_ran_to_the_cap(trained):
    _, res, _, _ = trained
    assert res.iterations == 600 and not res.converged and np.isfinite(res.final_loss)


def test_sdf_error_within_10cm_of_surfaces_is_at_most_1cm(trained):
    m, _, q, true = trained
    sdf = m.sdf(q)
    valid = np.isfinite(sdf)
    assert valid.mean() >= 0.99
    err = np.abs(sdf[valid] - true[valid])
    assert err.mean() <= 0.01, f"mean abs SDF error {err.mean() * 100:.2f} cm"


def test_sign_is_correct_5cm_or_more_from_surfaces(trained):
    m, _, q, true = trained
    far = np.abs(true) >= 0.05
    sdf = m.sdf(q[far])
    assert far.sum() > 3000 and ((sdf < 0) == (true[far] < 0)).any()
    ok = np.sign(sdf) == np.sign(true[far])
    assert ok.mean() >= 0.99, f"sign correct for {ok.mean():.4f}"


def test_gradient_norm_is_near_one(trained):
    m, _, q, _ = trained
    _, g = m.sdf_and_grad(q)
    n = np.linalg.norm(g[np.isfinite(g).all(1)], axis=1)
    assert abs(np.median(n) - 1.0) <= GRAD_MEDIAN_TOL
    assert (np.abs(n - 1.0) <= GRAD_TOL).mean() >= GRAD_SHARE


def test_mesh_of_the_zero_level_set_lies_on_the_true_surfaces(trained):
    m, _, _, _ = trained
    mesh = m.extract_mesh(resolution=0.04)
    assert len(mesh.faces) > 1000 and mesh.vertices.dtype == np.float32
    d = np.abs(SCENE.sdf(mesh.vertices))
    assert np.median(d) < 0.01 and np.quantile(d, 0.9) < 0.03


def test_mesh_logs_to_rerun(trained):
    rr = pytest.importorskip("rerun")
    from simn_sim.mapping import log_mesh

    m, _, _, _ = trained
    mesh = m.extract_mesh(resolution=0.08)
    rec = rr.RecordingStream("simn-sim-test-mapping")
    with rec:
        mem = rec.memory_recording()
        log_mesh("map/mesh", mesh)
        rec.flush()
    assert len(mesh.faces) > 0 and len(mem.drain_as_bytes()) > 1000
