"""Neural-point store: one point per voxel, exact k-NN through the voxel index, IDW weights."""

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from simn_sim.config import ConfigError
from simn_sim.mapping import NeuralPointMap, NeuralPointsConfig
from simn_sim.mapping.neural_points import idw_interpolate
from simn_sim.mapping.point_index import pack_keys, unpack_keys


def _surface_cloud(n=20000, seed=0):
    rng = np.random.default_rng(seed)
    # points on two planes and a sphere, like a room corner with an object
    a = np.c_[rng.uniform(-1, 1, (n // 3, 2)), np.zeros(n // 3)]
    b = np.c_[rng.uniform(-1, 1, n // 3), np.full(n // 3, 1.0), rng.uniform(0, 1, n // 3)]
    d = rng.normal(size=(n - 2 * (n // 3), 3))
    c = 0.3 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.2, 0.3, 0.4]
    return np.concatenate([a, b, c]).astype(np.float32)


def test_pack_unpack_roundtrip():
    ijk = torch.tensor([[0, 0, 0], [-5, 7, 123456], [1048575, -1048576, 3]])
    assert torch.equal(unpack_keys(pack_keys(ijk)), ijk)


def test_one_point_per_voxel_and_stable_indices():
    cfg = NeuralPointsConfig(voxel_size=0.05)
    npm = NeuralPointMap(cfg, generator=torch.Generator().manual_seed(0))
    pts = torch.from_numpy(_surface_cloud())
    new = npm.add_points(pts)
    keys = torch.floor(npm.positions / 0.05).long()
    assert len(torch.unique(keys, dim=0)) == len(npm) == len(new)
    assert len(torch.unique(torch.floor(pts / 0.05).long(), dim=0)) == len(npm)
    before = npm.positions.clone()
    again = npm.add_points(pts + 0.001)  # same voxels (mostly): few or no new points
    assert len(again) < 0.1 * len(new)
    assert torch.equal(npm.positions[: len(before)], before)  # old indices unchanged
    assert npm.features.shape == (len(npm), cfg.feature_dim)


def test_knn_matches_brute_force_within_radius():
    cfg = NeuralPointsConfig(voxel_size=0.05, k_neighbors=6, search_radius=0.15, query_chunk=700)
    npm = NeuralPointMap(cfg, generator=torch.Generator().manual_seed(0))
    npm.add_points(torch.from_numpy(_surface_cloud()))
    rng = np.random.default_rng(1)
    q = (
        npm.positions.numpy()[rng.integers(0, len(npm), 3000)] + rng.normal(0, 0.08, (3000, 3))
    ).astype(np.float32)
    idx, d2 = npm.knn(torch.from_numpy(q))
    tree = cKDTree(npm.positions.numpy())
    dt, it = tree.query(q, k=6, distance_upper_bound=0.15)
    valid_ref = np.isfinite(dt)
    assert (idx.numpy() >= 0).tolist() == valid_ref.tolist()
    np.testing.assert_allclose(np.sqrt(d2.numpy()[valid_ref]), dt[valid_ref], atol=1e-5)
    assert valid_ref[:, 0].mean() > 0.8 and (~valid_ref[:, -1]).any()  # both cases exercised


def test_query_far_from_points_is_invalid_not_garbage():
    npm = NeuralPointMap(NeuralPointsConfig(), generator=torch.Generator().manual_seed(0))
    npm.add_points(torch.tensor([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0]]))
    idx, d2 = npm.knn(torch.tensor([[5.0, 5.0, 5.0], [0.0, 0.0, 0.01]]))
    assert (idx[0] == -1).all() and torch.isinf(d2[0]).all()
    assert idx[1, 0] == 0 and idx[1, 1] == 1 and (idx[1, 2:] == -1).all()
    empty = NeuralPointMap(NeuralPointsConfig())
    i, _ = empty.knn(torch.zeros(4, 3))
    assert (i == -1).all()


@pytest.mark.parametrize("power", [1.0, 2.0])
def test_idw_weights_follow_the_configured_power(power):
    x = torch.zeros(1, 3)
    pos = torch.tensor([[[1.0, 0, 0], [0, 0.5, 0], [0, 0, 2.0]]])
    feat = torch.tensor([[[1.0], [2.0], [4.0]]])
    valid = torch.tensor([[True, True, False]])
    f, c, ctr = idw_interpolate(x, pos, valid, feat, torch.zeros(1, 3, 3), power)
    w = np.array([1.0, 0.5**-power])
    np.testing.assert_allclose(f.item(), (w * [1, 2]).sum() / w.sum(), rtol=1e-6)
    np.testing.assert_allclose(
        ctr[0].numpy(), (w[:, None] * [[1, 0, 0], [0, 0.5, 0]]).sum(0) / w.sum(), rtol=1e-6
    )


def test_labels_are_stored_and_unknown_ones_filled_in():
    npm = NeuralPointMap(NeuralPointsConfig(voxel_size=0.1))
    npm.add_points(torch.tensor([[0.0, 0, 0], [1.0, 0, 0]]), labels=torch.tensor([0, 2]))
    npm.add_points(
        torch.tensor([[0.01, 0, 0], [1.01, 0, 0], [2.0, 0, 0]]), labels=torch.tensor([1, 1, 1])
    )
    assert npm.labels.tolist() == [1, 2, 1]  # unknown -> 1; obstacle kept; new point labelled


def test_neural_points_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="search_radius"):
        NeuralPointsConfig(voxel_size=0.1, search_radius=0.05)
    with pytest.raises(ConfigError, match="k_neighbors"):
        NeuralPointsConfig(k_neighbors=0)
