"""perception.Frame: one back-projection of a rendered wall, exact to 1 mm; validity and errors."""

from __future__ import annotations

import numpy as np
import pytest
from test_env import _env_with_layout, _wall_layout

from simn_sim.geometry.camera import Intrinsics
from simn_sim.geometry.se3 import transform_points
from simn_sim.perception import Perception, PerceptionConfig


@pytest.mark.parametrize("stride", [1, 3])
def test_frame_backprojects_a_rendered_wall_within_1mm(stride):
    e = _env_with_layout(_wall_layout(), width=320, height=240)
    # facing the east wall (inner face x = 19.925) from 3 m away
    ep = {"episode_id": "w", "layout_seed": None, "start": [16.9, 7.0, 0.0], "goal": [3.0, 3.0]}
    obs, info = e.reset(options={"episode": ep})
    intr = e.camera_info.intrinsics
    frame = Perception(intr, PerceptionConfig(stride=stride, max_depth=10.0))(
        obs["rgb"], obs["depth"]
    )
    e.close()
    n_px = len(range(0, 240, stride)) * len(range(0, 320, stride))
    assert len(frame) + frame.n_invalid == n_px and frame.depth.shape == frame.valid.shape
    for arr, cols in ((frame.points, 3), (frame.normals, 3), (frame.colors, 3), (frame.pixels, 2)):
        assert arr.shape == (len(frame), cols)
    # each point is its pixel's depth along its pixel's ray
    r, c = frame.pixels[:, 0], frame.pixels[:, 1]
    np.testing.assert_allclose(frame.points[:, 2], obs["depth"][r, c], rtol=0, atol=1e-6)
    np.testing.assert_allclose(
        frame.points[:, 0], (c - intr.cx) / intr.fx * frame.points[:, 2], rtol=1e-6, atol=1e-6
    )
    pw = transform_points(info["T_world_cam"], frame.points.astype(np.float64))
    on_wall = pw[:, 2] > 1e-3
    assert on_wall.sum() > 1000 // stride**2
    err = np.abs(pw[on_wall, 0] - 19.925)
    assert err.max() < 1e-3, f"max wall error {err.max() * 1000:.2f} mm"
    assert np.abs(pw[~on_wall, 2]).max() < 1e-3  # the rest is floor
    # wall normals point back towards the camera (-x in the world) where they are defined
    nw = frame.normals[on_wall] @ info["T_world_cam"][:3, :3].T
    ok = np.isfinite(nw).all(axis=1)
    assert ok.mean() > 0.8
    assert np.median(nw[ok, 0]) < -0.99


def test_frame_drops_invalid_depth_and_counts_it():
    intr = Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)
    depth = np.full((6, 8), 2.0, np.float32)
    depth[0, 0], depth[1, 1], depth[2, 2], depth[3, 3] = 0.0, np.nan, 0.1, 20.0
    frame = Perception(intr, PerceptionConfig(stride=1, min_depth=0.28, max_depth=6.0))(None, depth)
    assert frame.n_invalid == 4 and len(frame) == 44
    assert np.isfinite(frame.points).all() and (frame.colors == 0.5).all()


def test_frame_rejects_wrong_shape_and_dtype():
    intr = Intrinsics(8, 6, 5.0, 5.0, 3.5, 2.5)
    p = Perception(intr, PerceptionConfig(stride=1))
    with pytest.raises(ValueError, match="depth is"):
        p(None, np.ones((5, 8), np.float32))
    with pytest.raises(ValueError, match="dtype"):
        p(None, np.ones((6, 8), np.uint16))
    with pytest.raises(ValueError, match="rgb is"):
        p(np.zeros((6, 8), np.uint8), np.ones((6, 8), np.float32))
    frame = p(None, np.ones((6, 8), np.float32))
    with pytest.raises(ValueError, match="labels must be"):
        frame.with_labels(np.zeros(3, np.int8))
