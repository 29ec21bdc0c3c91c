"""Geometric floor / obstacle classifier on synthetic scenes with known labels."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import make_T, se3_exp, transform_points
from simn_sim.semantics import (
    FLOOR,
    OBSTACLE,
    OVERHEAD,
    UNKNOWN,
    FloorClassifierConfig,
    FloorNotFoundError,
    base_labels,
    classify_depth,
    classify_points,
    fit_floor_plane,
    precision_recall,
)
from simn_sim.tracking.synthetic import look_at, loop_scene, ray_cast


def _box_surface(rng, c, h, n):
    """Points on the 5 visible faces (not the bottom) of a box on the floor; label obstacle."""
    pts = []
    for axis in range(3):
        for sgn in (-1, 1):
            if axis == 2 and sgn == -1:
                continue
            u = rng.uniform(-1, 1, size=(n, 3)) * h
            u[:, axis] = sgn * h[axis]
            pts.append(c + u)
    return np.concatenate(pts)


def _ramp(rng, x0, y0, slope_deg, length, width, n):
    """A sloped strip rising from the floor along +x (points and their heights)."""
    s = rng.uniform(0, length, n)
    y = rng.uniform(y0, y0 + width, n)
    z = s * np.tan(np.radians(slope_deg))
    return np.stack([x0 + s, y, z], axis=1)


def synthetic_scene(rng: np.random.Generator):
    """Floor + two boxes + a table top + an overhead shelf + two ramps; returns points, labels,
    and the index ranges of the ramps."""
    parts, labels = [], []
    floor = np.stack([rng.uniform(-3, 3, 6000), rng.uniform(-3, 3, 6000), np.zeros(6000)], axis=1)
    # keep the floor out from under the solids
    keep = ~(
        ((np.abs(floor[:, 0] - 1.0) < 0.3) & (np.abs(floor[:, 1] - 1.0) < 0.3))
        | ((np.abs(floor[:, 0] + 1.5) < 0.4) & (np.abs(floor[:, 1] - 0.5) < 0.2))
        | ((floor[:, 0] > -2.5) & (floor[:, 0] < 0.5) & (floor[:, 1] > -2.5) & (floor[:, 1] < -1.5))
    )
    parts.append(floor[keep])
    labels.append(np.full(keep.sum(), FLOOR))
    for c, h in (((1.0, 1.0, 0.25), (0.3, 0.3, 0.25)), ((-1.5, 0.5, 0.5), (0.4, 0.2, 0.5))):
        b = _box_surface(rng, np.array(c), np.array(h), 500)
        parts.append(b)
        labels.append(np.full(len(b), OBSTACLE))
    table = np.stack([rng.uniform(1.5, 2.5, 800), rng.uniform(-1, 0, 800), np.full(800, 0.75)], 1)
    shelf = np.stack([rng.uniform(-2, -1, 800), rng.uniform(2, 2.4, 800), np.full(800, 1.8)], 1)
    parts += [table, shelf]
    labels += [np.full(800, OBSTACLE), np.full(800, OVERHEAD)]
    i0 = sum(len(p) for p in parts)
    gentle = _ramp(rng, -2.5, -2.5, 8.0, 2.8, 0.4, 1500)  # rises to 0.39 m
    steep = _ramp(rng, -2.5, -1.9, 35.0, 0.7, 0.4, 1500)  # rises to 0.49 m
    parts += [gentle, steep]
    labels += [np.where(gentle[:, 2] < 0.05, FLOOR, OBSTACLE), np.full(1500, OBSTACLE)]
    P = np.concatenate(parts)
    L = np.concatenate(labels)
    P += rng.normal(scale=0.003, size=P.shape)
    return P, L, (i0, i0 + 1500, i0 + 3000)


def test_labels_on_synthetic_scene_in_a_tilted_base_frame() -> None:
    rng = np.random.default_rng(0)
    P, L, (g0, s0, s1) = synthetic_scene(rng)
    # express the scene in a frame where the floor is tilted by 3 deg and 0.4 m lower
    T = make_T(se3_exp(np.array([np.radians(3.0), np.radians(-2.0), 0.3, 0, 0, 0]))[:3, :3],
               np.array([0.2, -0.1, -0.4]))  # fmt: skip
    Pb = transform_points(T, P)
    res = classify_points(Pb, cfg=FloorClassifierConfig(), rng=np.random.default_rng(1))
    up = T[:3, :3] @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(res.plane_normal @ up)) < 0.5
    assert abs(res.plane_offset - up @ T[:3, 3]) < 0.01
    for cls in (FLOOR, OBSTACLE, OVERHEAD):
        p, r = precision_recall(res.labels, L, cls)
        assert p > 0.97 and r > 0.97, (cls, p, r)
    # the gentle ramp: floor at its foot, obstacle once above the tolerance (documented rule)
    g = res.labels[g0:s0]
    gh = P[g0:s0, 2]
    assert np.mean(g[gh < 0.03] == FLOOR) > 0.95 and np.mean(g[gh > 0.08] == OBSTACLE) > 0.98
    # the steep ramp is an obstacle even at floor level: its normal is far from up
    s = res.labels[s0:s1]
    assert np.mean(s[P[s0:s1, 2] < 0.04] == OBSTACLE) > 0.9
    assert np.mean(s == OBSTACLE) > 0.95
    # points below the floor and non-finite points are unknown
    extra = np.array([[0.0, 0.0, -0.3], [np.nan, 0.0, 0.0]])
    r2 = classify_points(
        extra, np.array([[0, 0, 1.0], [0, 0, 1.0]]), plane=(np.array([0, 0, 1.0]), 0.0)
    )
    assert list(r2.labels) == [UNKNOWN, UNKNOWN]
    assert set(np.unique(base_labels(res.labels))) <= {UNKNOWN, FLOOR, OBSTACLE}


def test_known_floor_height_prior() -> None:
    rng = np.random.default_rng(2)
    P, L, _ = synthetic_scene(rng)
    P[:, 2] += 0.25  # the floor is at z = 0.25 in this frame
    res = classify_points(P, cfg=FloorClassifierConfig(floor_height=0.25))
    assert res.plane_offset == 0.25
    assert precision_recall(res.labels, L, FLOOR)[1] > 0.97
    # a wrong prior (floor assumed 20 cm too high) breaks it: the prior is really used
    bad = classify_points(P, cfg=FloorClassifierConfig(floor_height=0.45))
    assert precision_recall(bad.labels, L, FLOOR)[1] < 0.1


def test_organised_depth_of_a_rendered_scene() -> None:
    scene = loop_scene()
    intr = Intrinsics.from_fovy(160, 120)
    T_world_cam = look_at(np.array([-2.0, -2.0, 1.0]), np.array([1.0, -0.5, 0.3]))
    u, v = np.meshgrid(np.arange(intr.width), np.arange(intr.height))
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], -1)
    d = d.reshape(-1, 3)
    t = ray_cast(
        scene,
        T_world_cam[:3, 3],
        (d / np.linalg.norm(d, axis=1, keepdims=True)) @ T_world_cam[:3, :3].T,
    )
    depth = (t / np.linalg.norm(d, axis=1)).reshape(intr.height, intr.width).astype(np.float32)
    depth[~np.isfinite(depth) | (depth > 10)] = 0.0
    img, res = classify_depth(depth, intr, T_world_cam, rng=np.random.default_rng(3))
    z = (T_world_cam[:3, :3] @ (d * depth.reshape(-1, 1)).T).T[:, 2] + T_world_cam[2, 3]
    z = z.reshape(depth.shape)
    truth = np.where(z < 1e-4, FLOOR, np.where(z <= 1.2, OBSTACLE, OVERHEAD))
    truth[depth == 0] = UNKNOWN
    assert abs(res.plane_offset) < 0.01 and res.plane_normal[2] > 0.9999
    for cls in (FLOOR, OBSTACLE):
        p, r = precision_recall(img, truth, cls)
        assert p > 0.97 and r > 0.93, (cls, p, r)  # border pixels have no normal -> unknown


def test_precision_recall_and_errors() -> None:
    pred = np.array([1, 1, 2, 2, 0, 1])
    true = np.array([1, 2, 2, 2, 1, 1])
    assert precision_recall(pred, true, 1) == pytest.approx((2 / 3, 2 / 3))
    assert precision_recall(pred, true, 2) == pytest.approx((1.0, 2 / 3))
    assert np.isnan(precision_recall(pred, true, 3)[0])
    with pytest.raises(ValueError, match="differ"):
        precision_recall(pred, true[:3], 1)
    with pytest.raises(ValueError, match="shape"):
        classify_points(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="floating"):
        classify_points(np.zeros((5, 3), dtype=np.int32))
    wall = np.stack([np.zeros(500), np.random.default_rng(0).uniform(0, 2, 500),
                     np.random.default_rng(1).uniform(0, 2, 500)], 1)  # fmt: skip
    with pytest.raises(FloorNotFoundError):
        fit_floor_plane(wall)
    with pytest.raises(ConfigError, match="robot_height"):
        FloorClassifierConfig(robot_height=0.01)


def test_range_dependent_floor_band_under_stereo_noise() -> None:
    """Floor points with depth noise growing as range^2 (sigma = 0.004 r^2, like a D435i at
    320x240) and a 0.3 m box at 2 m: with the ranges, the noisy far floor is no longer an
    obstacle, the box still is, and nothing beyond max_obstacle_range is an obstacle."""
    rng = np.random.default_rng(3)
    cam = np.array([0.0, 0.0, 1.0])
    xy = rng.uniform([0.5, -3.0], [6.0, 3.0], size=(20000, 2))
    floor = np.c_[xy, np.zeros(len(xy))]
    bx = rng.uniform([2.0, -0.2], [2.05, 0.2], size=(500, 2))
    box = np.c_[bx, rng.uniform(0.0, 0.3, size=len(bx))]
    P = np.vstack([floor, box])
    rays = P - cam
    r = np.linalg.norm(rays, axis=1)
    P = P + rays / r[:, None] * (rng.normal(size=len(P)) * 0.004 * r**2)[:, None]
    # normals from noisy depth are noisy too: the error grows with range
    N = np.tile([0.0, 0.0, 1.0], (len(P), 1))
    N[len(floor) :] = [-1.0, 0.0, 0.0]  # the box face looks back at the camera
    N = N + rng.normal(size=N.shape) * 0.05 * r[:, None] ** 2
    is_floor = np.arange(len(P)) < len(floor)
    cfg = FloorClassifierConfig(floor_height=0.0, floor_tol_per_m2=0.01, max_obstacle_range=3.5)
    plain = classify_points(P, N, cfg).labels
    ranged = classify_points(P, N, cfg, ranges=r).labels
    false_plain = np.mean(plain[is_floor] == OBSTACLE)
    false_ranged = np.mean(ranged[is_floor] == OBSTACLE)
    # without ranges the far floor is strewn with obstacles (each inflates to a robot-sized
    # disc in the collision model); with them, next to none
    assert false_plain > 0.1
    assert false_ranged < 0.002
    # the box (ranges ~2.2 m) is kept: all of it above the widened band (0.09 m there)
    tall = ~is_floor & (np.r_[np.zeros(len(floor)), box[:, 2]] > 0.15)
    assert tall.sum() > 200 and np.mean(ranged[tall] == OBSTACLE) > 0.95
    assert not np.any((ranged == OBSTACLE) & (r > 3.5))
    with pytest.raises(ValueError, match="ranges"):
        classify_points(P, N, cfg, ranges=r[:-1])
    with pytest.raises(ConfigError, match="floor_tol_per_m2"):
        FloorClassifierConfig(floor_tol_per_m2=-1.0)
