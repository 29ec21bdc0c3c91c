"""Revisit candidates ranked by the learned key points (``SlamConfig.revisit_features``) on a
synthetic loop: exact depth of an analytic room, the learned map trained in the loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from simn_sim.geometry.analytic import AnalyticScene, Box, Sphere
from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import transform_points
from simn_sim.slam import SimnSlam, SlamConfig
from simn_sim.slam.revisit import RANKINGS
from simn_sim.tracking.descriptors import DescriptorConfig, KeyPointIndex, standardized_features
from simn_sim.tracking.synthetic import look_at


def _scene() -> AnalyticScene:
    """An 8 x 4 m room with a different arrangement of boxes and spheres along each wall."""
    return AnalyticScene(
        room=Box((0.0, 0.0, 1.25), (4.0, 2.0, 1.25)),
        boxes=(
            Box((-2.8, -1.7, 0.5), (0.3, 0.3, 0.5)),
            Box((-0.9, -1.75, 0.2), (0.6, 0.25, 0.2)),
            Box((1.0, -1.6, 0.9), (0.25, 0.4, 0.9)),
            Box((2.9, -1.5, 0.3), (0.4, 0.5, 0.3)),
            Box((2.2, 1.7, 0.7), (0.5, 0.3, 0.7)),
            Box((-1.6, 1.6, 0.35), (0.3, 0.4, 0.35)),
            Box((3.7, 0.2, 0.4), (0.3, 0.6, 0.4)),
        ),
        spheres=(
            Sphere((0.2, 1.6, 0.4), 0.4),
            Sphere((-3.5, 0.6, 0.3), 0.3),
            Sphere((2.0, -1.6, 1.3), 0.25),
        ),
    )


def _loop(step: float = 0.25) -> list[np.ndarray]:
    """A rectangular loop around the room's centre driven one and a half times, the camera
    (0.6 m up) looking 50 deg to the right of the way it drives; the second lap runs 0.15 m
    further out and looks 8 deg further right, so its frames revisit the first lap's."""
    corners = [(-2.5, -0.6), (2.5, -0.6), (2.5, 0.6), (-2.5, 0.6)]
    out = []
    for lap, n_sides in ((0, 4), (1, 2)):
        grow, turn = 1.0 + 0.25 * lap, np.radians(50 + 8 * lap)
        cs = [(x * grow if abs(x) < 2 else x, y * grow) for x, y in corners]
        for k in range(n_sides):
            (x0, y0), (x1, y1) = cs[k], cs[(k + 1) % 4]
            n = max(1, round(np.hypot(x1 - x0, y1 - y0) / step))
            head = np.arctan2(y1 - y0, x1 - x0) - turn
            for i in range(n):
                e = np.array([x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n, 0.6])
                out.append(look_at(e, e + np.array([np.cos(head), np.sin(head), -0.25])))
    return out


def _precision(pairs: dict[int, list[int]], true: dict[int, set[int]]) -> tuple[float, float]:
    prop = sum(len(v) for v in pairs.values())
    tp = sum(len(set(v) & true[q]) for q, v in pairs.items())
    pos = [q for q, t in true.items() if t]
    hit = sum(1 for q in pos if set(pairs[q]) & true[q])
    return tp / max(prop, 1), hit / max(len(pos), 1)


def test_key_point_index_match_uses_features() -> None:
    rng = np.random.default_rng(0)
    P = rng.uniform(-1, 1, (400, 3))
    F = rng.standard_normal((400, 8))
    idx = KeyPointIndex(P, F)
    cfg = DescriptorConfig(match_radius=0.05, match_k=1)
    same = idx.match(P + 0.001, standardized_features(F), cfg)
    other = idx.match(P + 0.001, standardized_features(rng.standard_normal((400, 8))), cfg)
    geo = idx.match(P + 0.001, None, cfg)
    far = idx.match(P + 5.0, standardized_features(F), cfg)
    assert same[0] > 0.99 and same[1] == 1.0
    assert other[0] < 0.5 and other[1] == 1.0  # in reach, features disagree
    assert geo == (1.0, 1.0)  # without features: the share in reach
    assert far == (0.0, 0.0)


def test_learned_ranking_needs_implicit_map() -> None:
    from simn_sim.config import ConfigError

    with pytest.raises(ConfigError, match="revisit_features"):
        SlamConfig(map_kind="points", revisit_features="learned")
    intr = Intrinsics.from_fovy(80, 60)
    assert SimnSlam(SlamConfig(), intr).revisits.ranking == "learned"
    assert SimnSlam(SlamConfig(map_kind="points"), intr).revisits.ranking == "geometric"


def test_revisit_rankings_on_a_synthetic_loop() -> None:
    """All three rankings on the same state of a synthetic loop (the second lap revisits the
    first), candidates before verification against the true overlap.

    Measured (deterministic): recall 1.0 for all three; precision learned 0.78 (14 of 18
    candidates), keypoints 0.74 (14 of 19), geometric 0.82 (14 of 17). The learned features drop one false candidate that key points alone keep,
    but here they do not beat the pooled geometric descriptors, so that is not asserted (on the
    rendered loops, pooled over 3 sequences: 0.66 / 0.61 / 0.57; docs/slam.md)."""
    torch.manual_seed(0)
    scene, intr = _scene(), Intrinsics.from_fovy(80, 60, 60.0)
    poses = _loop()
    base = SlamConfig()
    training = {**base.mapper.training.to_dict(), "batch_size": 1024}
    cfg = SlamConfig(
        seed=0,
        open_train_iters=30,
        train_iters=10,
        max_track_points=1500,
        mapper={**base.mapper.to_dict(), "training": training},
    )
    slam = SimnSlam(cfg, intr)
    ranks: dict[int, dict[str, list[int]]] = {}
    observed: dict[int, np.ndarray] = {}
    orig = slam.revisits.on_open

    def hook(fid, pts, T_world_cam):
        observed[fid] = np.asarray(pts, np.float64)
        ranks[fid] = {
            r: [c for c, _ in slam.revisits.candidates(fid, pts, T_world_cam, r)] for r in RANKINGS
        }
        return orig(fid, pts, T_world_cam)

    slam.revisits.on_open = hook
    opened, obs = {0: 0}, {}
    for i, T in enumerate(poses):
        out = slam.process(0.1 * (i + 1), None, scene.render_depth(intr, T), T)
        if out.new_local_frame and out.frame_id > 0:
            opened[out.frame_id] = i
            if out.frame_id in observed:
                obs[out.frame_id] = transform_points(T, observed[out.frame_id])
    # true revisits: half of the checked observation within 5 cm of the frame's surface
    surf = {
        f: cKDTree(transform_points(poses[opened[f]], st.surface.surface.points.astype(np.float64)))
        for f, st in slam.frames.states.items()
    }
    true = {
        q: {
            c
            for c in surf
            if c <= q - cfg.loop.exclude_recent
            and np.isfinite(surf[c].query(P, distance_upper_bound=0.05)[0]).mean() >= 0.5
        }
        for q, P in obs.items()
    }
    assert sum(len(t) for t in true.values()) >= 10, true  # the second lap revisits the first
    res = {r: _precision({q: ranks[q][r] for q in true}, true) for r in RANKINGS}
    print(res)
    assert all(rec == 1.0 for _, rec in res.values()), res
    assert res["learned"][0] >= 0.75, res
    assert res["learned"][0] > res["keypoints"][0], res  # the features' own part
    assert res["learned"][0] >= res["geometric"][0] - 0.1, res
    assert slam.n_revisits >= 3  # the check (registration) accepts revisits on this loop
