"""ImplicitMap API: integration, training schedule, queries, persistence, errors, EWC, replay."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from simn_sim.config import ConfigError
from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import (
    EmptyFrameError,
    ImplicitMap,
    MapFileError,
    MapperConfig,
    TrainingConfig,
    rgbd_to_points,
)
from simn_sim.mapping.replay import ReplayPool
from simn_sim.mapping.synthetic import box_room_scene, orbit_poses

INTR = Intrinsics.from_fovy(64, 48)
SCENE = box_room_scene()


def _cfg(**training):
    tr = {"batch_size": 1024, "max_iters": 30, "min_iters": 5, "loss_window": 5, **training}
    return MapperConfig.from_dict({"training": tr, "seed": 3})


def _frames(n=3):
    out = []
    for T in orbit_poses(n, radius=0.4):
        pc = rgbd_to_points(SCENE.render_depth(INTR, T), INTR)
        out.append((pc.points, T))
    return out


@pytest.fixture(scope="module")
def small_map():
    m = ImplicitMap(_cfg(train_every=3))
    for pts, T in _frames(3):
        m.integrate_frame(pts, T, labels=np.full(len(pts), 2, np.int16))
    return m


def test_training_runs_every_kth_frame_and_reports_iterations():
    m = ImplicitMap(_cfg(train_every=2))
    res = [m.integrate_frame(p, T) for p, T in _frames(4)]
    assert [r.train is not None for r in res] == [False, True, False, True]
    for r in res[1::2]:
        assert 5 <= r.train.iterations <= 30 and r.train.n_samples > 0
    assert res[3].train.n_replayed > 0  # second call mixes in old samples
    assert m.n_pending == 0 and m.frame_count == 4


def test_adaptive_loop_stops_on_windowed_loss_change_or_cap():
    frames = _frames(1)
    m = ImplicitMap(_cfg(loss_threshold=10.0))  # any change is "small": stop as early as allowed
    r = m.integrate_frame(*frames[0], train=True).train
    assert r.converged and r.iterations == 10  # max(min_iters=5, 2 * loss_window=10)
    m2 = ImplicitMap(_cfg(loss_threshold=0.0))  # never small enough: run to the cap
    r2 = m2.integrate_frame(*frames[0], train=True).train
    assert not r2.converged and r2.iterations == 30


def test_query_shapes_types_and_invalid_mask(small_map):
    pos = small_map.feature_points().positions
    x = np.concatenate([pos[:50] + 0.02, [[50.0, 50.0, 50.0]]]).astype(np.float32)
    q = small_map.query(x, with_grad=True)
    assert q.sdf.shape == (51,) and q.grad.shape == (51, 3) and q.valid.dtype == bool
    assert q.valid[:50].all() and not q.valid[50]
    assert np.isfinite(q.sdf[:50]).all() and np.isnan(q.sdf[50]) and np.isnan(q.grad[50]).all()
    s, g = small_map.sdf_and_grad(torch.from_numpy(x))
    assert isinstance(s, torch.Tensor) and s.shape == (51,) and g.shape == (51, 3)
    np.testing.assert_allclose(s[:50].numpy(), q.sdf[:50], atol=1e-6)
    np.testing.assert_allclose(small_map.sdf(x)[:50], q.sdf[:50], atol=1e-6)
    # gradient agrees with finite differences of the queried field (same neighbourhoods)
    h = 1e-3
    i = np.arange(10)
    fd = np.stack(
        [
            (small_map.sdf(x[i] + h * e) - small_map.sdf(x[i] - h * e)) / (2 * h)
            for e in np.eye(3, dtype=np.float32)
        ],
        1,
    )
    assert np.median(np.abs(fd - q.grad[i])) < 0.05


def test_feature_points_carry_labels(small_map):
    fp = small_map.feature_points()
    n = len(fp.positions)
    assert n > 100 and fp.positions.dtype == np.float32 and fp.features.shape == (n, 8)
    assert fp.labels.shape == (n,) and (fp.labels == 2).all() and fp.colors.shape == (n, 3)


def test_save_load_round_trip_gives_identical_queries(small_map, tmp_path):
    path = small_map.save(tmp_path / "frame0.map")
    m2 = ImplicitMap.load(path)
    x = small_map.feature_points().positions[:500] + np.float32(0.03)
    a, ga = small_map.sdf_and_grad(x)
    b, gb = m2.sdf_and_grad(x)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ga, gb)
    np.testing.assert_array_equal(m2.feature_points().labels, small_map.feature_points().labels)
    assert m2.cfg == small_map.cfg and m2.frame_count == small_map.frame_count


def test_corrupt_foreign_and_missing_files_get_clear_errors(small_map, tmp_path):
    bad = tmp_path / "garbage.map"
    bad.write_bytes(b"\x00\x01 definitely not a map" * 10)
    with pytest.raises(MapFileError, match="not a readable simn-sim map"):
        ImplicitMap.load(bad)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(MapFileError, match="not a simn-sim implicit map"):
        ImplicitMap.load(foreign)
    good = small_map.save(tmp_path / "good.map")
    trunc = tmp_path / "truncated.map"
    trunc.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(MapFileError):
        ImplicitMap.load(trunc)
    with pytest.raises(MapFileError, match="no such map file"):
        ImplicitMap.load(tmp_path / "nope.map")


def test_bad_frames_get_clear_errors():
    m = ImplicitMap(_cfg())
    pts, T = _frames(1)[0]
    with pytest.raises(EmptyFrameError, match="no points"):
        m.integrate_frame(np.zeros((0, 3), np.float32), T)
    with pytest.raises(EmptyFrameError, match="NaN"):
        m.integrate_frame(np.full((10, 3), np.nan, np.float32), T)
    with pytest.raises(EmptyFrameError, match="invalid"):
        m.integrate_rgbd(np.zeros((48, 64), np.float32), INTR, T)
    T_nan = T.copy()
    T_nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        m.integrate_frame(pts, T_nan)
    with pytest.raises(ValueError, match=r"shape \(4, 4\)"):
        m.integrate_frame(pts, T[:3])
    with pytest.raises(ValueError, match="not a rigid transform"):
        m.integrate_frame(pts, 2.0 * T)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        m.integrate_frame(pts[:, :2], T)
    with pytest.raises(TypeError, match="float32 or float64"):
        m.integrate_frame(pts.astype(np.int32), T)
    with pytest.raises(TypeError, match="numpy array or torch tensor"):
        m.integrate_frame(pts.tolist(), T)
    with pytest.raises(ValueError, match="colors must be"):
        m.integrate_frame(pts, T, colors=np.zeros((3, 3), np.float32))
    with pytest.raises(TypeError, match="labels must be integers"):
        m.integrate_frame(pts, T, labels=np.zeros(len(pts), np.float32))
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        m.query(np.zeros((5, 4), np.float32))
    assert m.frame_count == 0  # nothing was half-integrated
    # a frame with some NaN points keeps the rest and counts the dropped ones
    bad = pts.copy()
    bad[:7] = np.nan
    r = m.integrate_frame(bad, T, train=False)
    assert r.n_dropped == 7 and r.n_points > 0


def test_config_is_validated_with_clear_errors():
    with pytest.raises(ConfigError, match="TrainingConfig.lr"):
        TrainingConfig(lr=-1.0)
    with pytest.raises(ConfigError, match="unknown config key"):
        MapperConfig.from_dict({"training": {"learning_rate": 1e-3}})
    with pytest.raises(ConfigError, match="activation"):
        MapperConfig.from_dict({"decoder": {"activation": "softplus"}})
    with pytest.raises(ConfigError, match="MapperConfig.device"):
        MapperConfig(device="tpu")
    cfg = MapperConfig()
    assert cfg.training.lr == 1e-3 and cfg.training.bce_weight == 1.0
    assert cfg.training.eikonal_weight == 0.5 and cfg.training.ewc_weight == 0.1
    assert cfg.training.loss_threshold == 1e-4 and cfg.training.train_every == 5
    assert cfg.points.k_neighbors == 6 and cfg.points.feature_dim == 8
    assert cfg.decoder.hidden_dim == 64 and cfg.decoder.hidden_layers == 2
    assert MapperConfig.from_dict(cfg.to_dict()) == cfg


def test_sibling_maps_share_or_copy_the_decoder(small_map):
    shared = small_map.new_map(share_decoder=True)
    copied = small_map.new_map(share_decoder=False)
    assert shared.decoder is small_map.decoder and len(shared.points) == 0
    assert copied.decoder is not small_map.decoder
    for a, b in zip(copied.decoder.parameters(), small_map.decoder.parameters(), strict=True):
        assert torch.equal(a, b) and a.data_ptr() != b.data_ptr()


def test_ewc_consolidation_penalises_moving_important_weights():
    m = ImplicitMap(_cfg())
    for p, T in _frames(2):
        m.integrate_frame(p, T, train=True)
    assert not m.ewc.active
    m.consolidate()
    assert m.ewc.active and m.ewc.count == 1
    assert float(m.ewc.penalty(m.decoder).detach()) == 0.0
    fisher = torch.cat([f.reshape(-1) for f in m.ewc.fisher.values()])
    assert (fisher >= 0).all() and fisher.max() > 0
    with torch.no_grad():
        for p in m.decoder.parameters():
            p.add_(0.01)
    assert float(m.ewc.penalty(m.decoder).detach()) > 0


def test_replay_pool_is_bounded_and_keeps_a_uniform_sample():
    g = torch.Generator().manual_seed(0)
    pool = ReplayPool(1000)
    for s in range(20):  # 20 batches of 500 = 10000 samples, ids in the sdf field
        ids = torch.arange(s * 500, (s + 1) * 500, dtype=torch.float32)
        pool.add(torch.zeros(500, 3), ids, torch.zeros(500, dtype=torch.int8), g)
    assert len(pool) == 1000 and pool.seen == 10000
    kept = pool.sdf.numpy()
    assert len(np.unique(kept)) == 1000
    # each half of the stream keeps about half of the pool
    assert 400 < (kept < 5000).sum() < 600


def test_mapping_package_does_not_import_mujoco():
    code = "import sys, simn_sim.mapping; assert 'mujoco' not in sys.modules, 'mujoco imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def _two_frames_sharing_a_decoder():
    """Frame A (first two views) closed, frame B (third view) open, sharing one decoder."""
    a = ImplicitMap(_cfg())
    fr = _frames(3)
    for p, T in fr[:2]:
        a.integrate_frame(p, T, train=True)
    a.close()
    b = a.new_map(share_decoder=True)
    b.integrate_frame(fr[2][0], fr[2][1], train=True)
    return a, b


def test_closing_a_frame_shares_ewc_and_replay_with_the_next():
    a, b = _two_frames_sharing_a_decoder()
    # one decoder, one EWC state (Fisher of A, anchored at the close), one pool of closed frames
    assert b.decoder is a.decoder and b.ewc is a.ewc and b.frame_replay is a.frame_replay
    assert a.ewc.active and a.ewc.count == 1
    assert a.frame_replay.n_frames == 1 and len(a.frame_replay) > 0
    # B's first training replayed A's samples (decoded with A's neural points), and its own
    # replay pool holds only B's samples
    assert b.last_train.n_replayed == len(a.frame_replay)
    assert len(b.replay) == b.last_train.n_samples
    b.close()  # both frames now share the pool evenly
    assert a.frame_replay.n_frames == 2 and a.ewc.count == 2
    n0, n1 = (e[1].shape[0] for e in a.frame_replay.entries)
    assert n0 <= a.cfg.training.frame_replay_capacity // 2 >= n1


def test_copied_decoder_starts_with_empty_ewc_and_replay():
    a, _ = _two_frames_sharing_a_decoder()
    c = a.new_map(share_decoder=False)
    assert c.decoder is not a.decoder and not c.ewc.active and len(c.frame_replay) == 0


def test_frames_sharing_a_decoder_save_it_once_and_load_shared(tmp_path):
    from simn_sim.mapping.persistence import save_frame_maps

    a, b = _two_frames_sharing_a_decoder()
    path = save_frame_maps({0: a, 1: b}, tmp_path / "maps.pt")
    state = torch.load(path, weights_only=True)
    assert len(state["shared"]) == 1 and "decoder" not in state["frames"][0]
    maps = ImplicitMap.load_frames(path)
    a2, b2 = maps[0], maps[1]
    assert a2.decoder is b2.decoder and a2.ewc is b2.ewc and a2.frame_replay is b2.frame_replay
    assert a2.ewc.count == 1 and len(a2.frame_replay) == len(a.frame_replay)
    for m, m2 in ((a, a2), (b, b2)):
        x = m.feature_points().positions[:300] + np.float32(0.02)
        np.testing.assert_array_equal(m.sdf(x), m2.sdf(x))
        assert len(m2.replay) == len(m.replay) and m2.frame_count == m.frame_count
    # training a loaded frame goes on with the shared EWC and replay of the closed frame
    p, T = _frames(3)[2]
    r = b2.integrate_frame(p, T, train=True)
    assert r.train.n_replayed >= len(a2.frame_replay)
    # a single map's file keeps the closed frames' replay too
    a3 = ImplicitMap.load(a.save(tmp_path / "a.map"))
    assert len(a3.frame_replay) == len(a.frame_replay) and a3.ewc.count == 1
    with pytest.raises(MapFileError, match="set of local-frame maps"):
        ImplicitMap.load_frames(tmp_path / "a.map")
