"""A training chunk prepares only the samples its batches draw: the same numbers as preparing
every sample (``train_chunk(..., prepare_all=True)``, the reference path).

The map is the closed-loop agent's (geometric prior, learned residual, replay, EWC and the
closed frames' replay). Two local frames of the box room: the first is closed, so the second
trains on its own new samples, its replay and the first frame's frozen samples.
"""

import copy

import numpy as np
import pytest
import torch

from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import ImplicitMap, rgbd_to_points
from simn_sim.mapping.results import flush_denormals
from simn_sim.mapping.synthetic import box_room_scene, look_at
from simn_sim.mapping.training import train_chunk
from simn_sim.slam.presets import agent_preset

SCENE = box_room_scene()
INTR = Intrinsics.from_fovy(96, 72)


def _frame(yaw: float, x: float):
    eye = np.array([x, 0.0, 1.2])
    T = look_at(eye, eye + [3 * np.cos(yaw), 3 * np.sin(yaw), -0.8])
    return rgbd_to_points(SCENE.render_depth(INTR, T), INTR).points, T


@pytest.fixture(scope="module")
def second_frame() -> ImplicitMap:
    """The second local frame's map with training pending (and a trained past)."""
    cfg = agent_preset().mapper
    cfg = cfg.replace(seed=3, training={**cfg.training.to_dict(), "max_pending": 3000})
    first = ImplicitMap(cfg)
    for yaw in (0.0, 0.3, 0.6):
        first.integrate_frame(*_frame(yaw, -0.5), train=False)
        first.train(max_iters=6)
    first.close()
    m = first.new_map(share_decoder=True)
    for yaw in (2.6, 2.9):
        m.integrate_frame(*_frame(yaw, 0.5), train=False)
        m.train(max_iters=6)
    m.integrate_frame(*_frame(3.2, 0.4), train=False)
    assert len(m.frame_replay) > 0 and len(m.replay) > 0 and m.ewc.active and m.n_pending > 0
    return m


def _outcome(m: ImplicitMap, max_iters: int, prepare_all: bool):
    m = copy.deepcopy(m)
    with flush_denormals():
        res, apply = train_chunk(m, max_iters, prepare_all=prepare_all)
    apply()
    return res, m


@pytest.mark.parametrize(
    ("training", "max_iters"),
    [
        ({}, 3),  # the agent's chunk
        ({"min_iters": 2, "loss_window": 1, "loss_threshold": 1.0}, 12),  # stops early
        ({"frame_replay_share": 1.0}, 3),  # both kinds, but no replay of this frame drawn
        ({"use_replay": False}, 3),  # new samples only
    ],
)
def test_drawn_rows_only_match_every_row(second_frame, training, max_iters):
    m = copy.deepcopy(second_frame)
    m.cfg = m.cfg.replace(training={**m.cfg.training.to_dict(), **training})
    ra, a = _outcome(m, max_iters, prepare_all=False)
    rb, b = _outcome(m, max_iters, prepare_all=True)
    assert ra.iterations >= 1
    if training.get("loss_threshold"):
        assert ra.iterations < max_iters  # the early stop is exercised
    assert (ra.iterations, ra.final_loss, ra.n_samples, ra.n_replayed) == (
        rb.iterations,
        rb.final_loss,
        rb.n_samples,
        rb.n_replayed,
    )
    assert torch.equal(a.points.features, b.points.features)
    assert not torch.equal(a.points.features, second_frame.points.features)  # it trained
    for p, q in zip(a.decoder.parameters(), b.decoder.parameters(), strict=True):
        assert torch.equal(p, q)
    # the generator is where the iterations run left it, whatever was drawn up front
    assert torch.equal(a.generator.get_state(), b.generator.get_state())
    assert torch.equal(a.replay.points, b.replay.points)


def test_replayed_samples_keep_their_neighbours(second_frame):
    """Why replayed samples need no validity search: each was valid when stored, and neural
    points are only added."""
    m = copy.deepcopy(second_frame)
    m.integrate_frame(*_frame(3.5, 0.3), train=False)
    m.train(max_iters=3)
    idx, _ = m.points.knn(m.replay.points)
    assert len(m.replay) > 1000 and bool((idx[:, 0] >= 0).all())


def test_early_stop_leaves_the_generator_as_a_shorter_chunk_would(second_frame):
    """Batches are drawn up front; a chunk that stops after n iterations leaves the map's
    generator (and the map) where a chunk capped at n leaves them."""
    m = copy.deepcopy(second_frame)
    m.cfg = m.cfg.replace(
        training={
            **m.cfg.training.to_dict(),
            "min_iters": 2,
            "loss_window": 1,
            "loss_threshold": 1.0,
        }
    )
    ra, a = _outcome(m, 12, prepare_all=False)
    assert ra.iterations < 12
    rb, b = _outcome(m, ra.iterations, prepare_all=False)
    assert rb.iterations == ra.iterations
    assert torch.equal(a.generator.get_state(), b.generator.get_state())
    assert torch.equal(a.points.features, b.points.features)


def test_zero_iterations_is_an_error(second_frame):
    m = copy.deepcopy(second_frame)
    with pytest.raises(ValueError, match="max_iters must be >= 1, got 0"):
        m.train(max_iters=0)
    assert m.n_pending == second_frame.n_pending  # nothing consumed


@pytest.mark.parametrize("prepare_all", [False, True])
def test_every_batch_sample_decodes_with_its_own_nearest_neural_points(second_frame, prepare_all):
    """The neighbour tables a chunk gathers belong to the samples they are used with: for every
    sample of every batch (new and replayed), the neural points its decoder inputs carry are
    its k nearest within ``search_radius``, nearest first, by brute force over all neural
    points. (The outcome checks above would pass with the tables shifted by one sample:
    consecutive samples lie close together.)"""
    m = copy.deepcopy(second_frame)
    seen: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
    inner = m._decoder_inputs

    def capture(x, nb_pos, nbv, *rest):
        seen.append((x.detach().clone(), nb_pos.detach().clone(), nbv.clone()))
        return inner(x, nb_pos, nbv, *rest)

    m._decoder_inputs = capture
    with flush_denormals():
        res, _ = train_chunk(m, 3, prepare_all=prepare_all)
    assert res.iterations == 3 and len(seen) == 3
    k, r = m.cfg.points.k_neighbors, m.cfg.points.search_radius
    P = m.points.positions
    for x, nb_pos, nbv in seen:
        d2 = torch.cdist(x.double(), P.double()).pow(2)
        d2s, order = torch.sort(d2, dim=1)
        want = (d2s[:, :k] <= r * r).cpu()
        assert torch.equal(nbv.cpu(), want)
        rows, cols = torch.nonzero(want, as_tuple=True)
        np.testing.assert_array_equal(
            nb_pos[rows, cols].cpu().numpy(), P[order[rows, cols]].cpu().numpy()
        )
