"""Ray sampling: exact labels on analytic surfaces, configured ranges, plane-radius geometry."""

import numpy as np
import pytest
import torch

from simn_sim.config import ConfigError
from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import BEHIND, FRONT, SURFACE, SamplingConfig, rgbd_to_points, sample_rays
from simn_sim.mapping.synthetic import AnalyticScene, Box, Sphere, look_at

CFG = SamplingConfig(
    n_front=4, n_behind=3, n_surface=5, front_range=(0.3, 0.99), behind_max=0.1, surface_radius=0.02
)


def _sphere_scene():
    # a sphere of radius 0.5 in front of the camera inside a large room
    return AnalyticScene(
        room=Box((0.0, 0.0, 0.0), (10.0, 10.0, 10.0)), spheres=(Sphere((0.0, 0.0, 3.0), 0.5),)
    )


def _surface_points(scene, T):
    intr = Intrinsics.from_fovy(64, 48, 20.0)
    pc = rgbd_to_points(scene.render_depth(intr, T), intr)
    pw = pc.points @ T[:3, :3].T + T[:3, 3]
    return pw[np.abs(scene.sdf(pw)) < 1e-4]


def test_labels_are_exact_along_ray_distances_to_an_analytic_surface():
    scene = _sphere_scene()
    T = look_at([0.1, -0.2, 0.0], [0.0, 0.0, 3.0], up=(0.0, -1.0, 0.0))
    pw = _surface_points(scene, T)
    on_sphere = np.abs(np.linalg.norm(pw - [0, 0, 3.0], axis=1) - 0.5) < 1e-4
    pw = pw[on_sphere].astype(np.float32)
    assert len(pw) > 200
    e = T[:3, 3]
    s = sample_rays(
        torch.from_numpy(pw),
        torch.tensor(e, dtype=torch.float32),
        CFG,
        torch.Generator().manual_seed(0),
    )
    x = s.points.numpy().astype(np.float64)
    lab = s.sdf.numpy()
    kind = s.kind.numpy()
    p = pw[s.ray.numpy()].astype(np.float64)
    u = (p - e) / np.linalg.norm(p - e, axis=1, keepdims=True)
    # front: the ray from the sample towards p first meets the surface exactly |label| ahead
    f = kind == FRONT
    t_hit = scene.raycast(x[f], u[f])
    np.testing.assert_allclose(t_hit, lab[f], atol=2e-5)
    assert (lab[f] > 0).all()
    # behind: going back towards the camera the surface is |label| away, and the point is inside
    b = kind == BEHIND
    np.testing.assert_allclose(np.linalg.norm(x[b] - p[b], axis=1), -lab[b], atol=2e-5)
    assert (lab[b] < 0).all()
    # where the ray meets the sphere head-on (chord longer than l_b |p - e|) they are inside it
    normal = (p - [0.0, 0.0, 3.0]) / 0.5
    head_on = b & ((-(normal * u).sum(1)) > np.cos(np.radians(30)))
    assert head_on.sum() > 100 and (scene.sdf(x[head_on]) < 0).all()
    # a head-on ray to a plane: the along-ray label equals the true signed distance
    wall = AnalyticScene(room=Box((0.0, 0.0, 0.0), (5.0, 5.0, 2.0)))
    pts = torch.tensor([[0.0, 0.0, 2.0]])
    sw = sample_rays(pts, torch.zeros(3), CFG, torch.Generator().manual_seed(1))
    ray = sw.kind != SURFACE
    np.testing.assert_allclose(wall.sdf(sw.points[ray].numpy()), sw.sdf[ray].numpy(), atol=1e-6)


def test_samples_fall_in_configured_ranges_with_configured_counts():
    g = torch.Generator().manual_seed(3)
    pts = torch.randn(1000, 3, generator=g) + torch.tensor([0.0, 0.0, 4.0])
    e = torch.tensor([0.2, -0.1, 0.3])
    s = sample_rays(pts, e, CFG, torch.Generator().manual_seed(4))
    assert len(s) == 1000 * (4 + 3 + 5)
    kind = s.kind
    assert int((kind == FRONT).sum()) == 4000 and int((kind == BEHIND).sum()) == 3000
    assert int((kind == SURFACE).sum()) == 5000
    assert s.points.dtype == torch.float32
    p = pts[s.ray]
    d = p - e
    lam = ((s.points - e) * d).sum(1) / (d * d).sum(1)  # ray parameter of each sample
    f, b = kind == FRONT, kind == BEHIND
    assert lam[f].min() >= 0.3 - 1e-5 and lam[f].max() <= 0.99 + 1e-5
    assert lam[b].min() >= 1.01 - 1e-5 and lam[b].max() <= 1.1 + 1e-5
    # spread over the ranges, not clumped
    assert lam[f].min() < 0.35 and lam[f].max() > 0.94
    # label = (1 - l) |p - e|
    np.testing.assert_allclose(
        s.sdf[f | b].numpy(), ((1 - lam) * d.norm(dim=1))[f | b].numpy(), atol=1e-5
    )


def test_plane_radius_samples_lie_on_the_plane_within_the_radius():
    g = torch.Generator().manual_seed(5)
    pts = torch.rand(500, 3, generator=g) * 4 - 2
    e = torch.tensor([0.0, 0.0, -3.0])
    s = sample_rays(pts, e, CFG, torch.Generator().manual_seed(6))
    m = s.kind == SURFACE
    p = pts[s.ray[m]]
    u = (p - e) / (p - e).norm(dim=1, keepdim=True)
    off = s.points[m] - p
    assert off.mul(u).sum(1).abs().max() < 1e-5  # on the plane perpendicular to the ray
    r = off.norm(dim=1)
    assert r.max() <= 0.02 + 1e-6
    assert r.max() > 0.015  # the disc is covered, not only its centre
    assert (s.sdf[m] == 0).all()


def test_sampling_is_deterministic_given_a_generator():
    pts = torch.rand(100, 3) + 1.0
    a = sample_rays(pts, torch.zeros(3), CFG, torch.Generator().manual_seed(9))
    b = sample_rays(pts, torch.zeros(3), CFG, torch.Generator().manual_seed(9))
    assert torch.equal(a.points, b.points) and torch.equal(a.sdf, b.sdf)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"front_range": (0.5, 0.2)}, "front_range"),
        ({"front_range": (0.3, 1.2)}, "front_range"),
        ({"behind_max": 0.0}, "behind_max"),
        ({"surface_radius": -0.1}, "surface_radius"),
        ({"n_front": -1}, "n_front"),
    ],
)
def test_sampling_config_rejects_bad_values(kw, field):
    with pytest.raises(ConfigError, match=f"SamplingConfig.{field}"):
        SamplingConfig(**kw)
