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
