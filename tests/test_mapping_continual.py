"""Continual learning: learn region A, then region B; forgetting of A with and without EWC + replay.

Region A is the half of the box room seen looking towards +x, region B the half seen looking
towards -x (no shared neural points), so forgetting A comes only through the shared decoder.
"""

import copy

import numpy as np
import pytest

from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import ImplicitMap, MapperConfig, rgbd_to_points
from simn_sim.mapping.synthetic import box_room_scene, look_at

SCENE = box_room_scene()
INTR = Intrinsics.from_fovy(128, 96)
ITERS_A, ITERS_B = 400, 300
# (growth of A's error with EWC + replay) / (growth without) must be at most this
MAX_FORGETTING_RATIO = 0.5


def _views(direction: float) -> list:
    out = []
    for a in np.linspace(-0.6, 0.6, 4):
        eye = np.array([-0.3 * direction, 0.0, 1.3])
        out.append(look_at(eye, eye + [3 * direction * np.cos(a), 3 * np.sin(a), -1.0]))
    return out


def _frames(poses):
    return [(rgbd_to_points(SCENE.render_depth(INTR, T), INTR).points, T) for T in poses]


def _queries(frames, rng):
    q = []
    for pts, T in frames:
        pw = pts @ T[:3, :3].T + T[:3, 3]
        p = pw[rng.choice(len(pw), 1000, replace=False)]
        u = (p - T[:3, 3]) / np.linalg.norm(p - T[:3, 3], axis=1, keepdims=True)
        q.append(p + rng.uniform(-0.1, 0.1, (len(p), 1)) * u)
    q = np.concatenate(q).astype(np.float32)
    t = SCENE.sdf(q)
    keep = np.abs(t) <= 0.1
    return q[keep], t[keep]


def _error(m, q, t):
    s = m.sdf(q)
    v = np.isfinite(s)
    assert v.mean() > 0.99
    return float(np.abs(s[v] - t[v]).mean())


@pytest.fixture(scope="module")
def experiment():
    rng = np.random.default_rng(7)
    fa, fb = _frames(_views(+1.0)), _frames(_views(-1.0))
    qa, ta = _queries(fa, rng)
    qb, tb = _queries(fb, rng)
    cfg = MapperConfig.from_dict(
        {
            "training": {"max_pending": 200_000, "loss_threshold": 0.0, "max_iters": ITERS_A},
            "seed": 1,
        }
    )
    m = ImplicitMap(cfg)
    for pts, T in fa:
        m.integrate_frame(pts, T, train=False)
    m.train()
    m.consolidate()  # local frame A closed: Fisher taken
    err_a0 = _error(m, qa, ta)
    out = {"err_a0": err_a0}
    for name, on in (("plain", False), ("ewc_replay", True)):
        mm = copy.deepcopy(m)
        tr = {**mm.cfg.training.to_dict(), "use_replay": on, "use_ewc": on}
        mm.cfg = mm.cfg.replace(training=tr)
        for pts, T in fb:
            mm.integrate_frame(pts, T, train=False)
        res = mm.train(max_iters=ITERS_B)
        assert res.iterations == ITERS_B and (res.n_replayed > 0) == on
        out[name] = (_error(mm, qa, ta), _error(mm, qb, tb))
    return out


def test_region_a_was_learned(experiment):
    assert experiment["err_a0"] < 0.015


def test_ewc_and_replay_reduce_forgetting(experiment):
    a0 = experiment["err_a0"]
    grow_plain = experiment["plain"][0] - a0
    grow_cl = experiment["ewc_replay"][0] - a0
    assert grow_plain > 0.005, f"no measurable forgetting without EWC/replay ({grow_plain:.4f} m)"
    ratio = grow_cl / grow_plain
    assert ratio <= MAX_FORGETTING_RATIO, f"forgetting ratio {ratio:.2f}"


def test_region_b_is_still_learned_with_ewc_and_replay(experiment):
    b_plain, b_cl = experiment["plain"][1], experiment["ewc_replay"][1]
    assert b_cl < 0.015 and b_cl < 2.0 * b_plain


def _fisher_case(decoding: str, seed: int = 0):
    import torch

    from simn_sim.mapping.config import DecoderConfig
    from simn_sim.mapping.decoder import Decoder
    from simn_sim.mapping.losses import bce_sdf_loss

    g = torch.Generator().manual_seed(seed)
    dec = Decoder(DecoderConfig(decoding=decoding), feature_dim=8, generator=g)
    n, lead = 600, ((600,) if decoding == "interpolated" else (600, 4))
    inputs = (
        torch.randn(*lead, 8, generator=g),
        torch.rand(*lead, 3, generator=g),
        0.3 * torch.randn(*lead, 3, generator=g),
    )
    if decoding != "interpolated":
        w = torch.rand(n, 4, generator=g)
        inputs = (*inputs, w / w.sum(1, keepdim=True))
    labels = 0.1 * torch.randn(n, generator=g)
    return dec, inputs, labels, lambda out, y: bce_sdf_loss(out, y, 0.05)


def test_fisher_from_outer_products_equals_the_per_sample_gradients():
    """The diagonal Fisher from per-layer outer products (one backward for all samples) is
    the mean of the squared per-sample gradients that vmap takes one sample at a time, for
    every parameter of the decoder, over several chunks."""
    import torch

    from simn_sim.mapping.losses import diagonal_fisher

    dec, inputs, labels, loss = _fisher_case("interpolated")
    ref = diagonal_fisher(dec, inputs, labels, loss, chunk=256, method="vmap")
    out = diagonal_fisher(dec, inputs, labels, loss, chunk=256, method="outer")
    auto = diagonal_fisher(dec, inputs, labels, loss, chunk=256)
    assert set(out) == set(ref) == {k for k, _ in dec.named_parameters()}
    for k in ref:
        assert ref[k].abs().max() > 0, k
        torch.testing.assert_close(out[k], ref[k], rtol=1e-5, atol=1e-12)
        assert torch.equal(auto[k], out[k])
    # a single sample: the squared gradient itself
    x1 = tuple(t[:1] for t in inputs)
    dec.zero_grad()
    loss(dec(*x1), labels[:1]).backward()
    one = diagonal_fisher(dec, x1, labels[:1], loss, method="outer")
    for k, p in dec.named_parameters():
        torch.testing.assert_close(one[k], p.grad**2, rtol=1e-5, atol=1e-12)


def test_fisher_falls_back_to_vmap_where_samples_are_not_rows():
    """Per-neighbour decoding applies the MLP to (N, k, in) tables (a sample's gradient is a
    sum over its k neighbours, not one outer product): ``auto`` takes the vmap path and
    ``outer`` says why it cannot."""
    import torch

    from simn_sim.mapping.losses import diagonal_fisher

    dec, inputs, labels, loss = _fisher_case("per_neighbor")
    ref = diagonal_fisher(dec, inputs, labels, loss, method="vmap")
    auto = diagonal_fisher(dec, inputs, labels, loss)
    for k in ref:
        assert torch.equal(auto[k], ref[k])
    with pytest.raises(ValueError, match="outer"):
        diagonal_fisher(dec, inputs, labels, loss, method="outer")
    with pytest.raises(ValueError, match="unknown method"):
        diagonal_fisher(dec, inputs, labels, loss, method="exact")
