"""Perception: back-projection, invalid-depth handling, voxel down-sampling, bad input."""

import numpy as np
import pytest

from simn_sim.geometry.camera import Intrinsics
from simn_sim.mapping import EmptyFrameError, PerceptionConfig, rgbd_to_points, voxel_downsample
from simn_sim.mapping.synthetic import box_room_scene, look_at

INTR = Intrinsics.from_fovy(40, 30)


def test_wall_at_known_distance_backprojects_onto_plane():
    depth = np.full((30, 40), 2.5, np.float32)
    rgb = np.zeros((30, 40, 3), np.uint8)
    rgb[..., 0] = 255
    pc = rgbd_to_points(depth, INTR, rgb)
    assert pc.points.dtype == np.float32 and pc.points.shape == (1200, 3)
    np.testing.assert_allclose(pc.points[:, 2], 2.5)
    # pixel (u, v) -> x = (u - cx) z / fx
    np.testing.assert_allclose(
        pc.points[0, :2], [-INTR.cx * 2.5 / INTR.fx, -INTR.cy * 2.5 / INTR.fy], rtol=1e-6
    )
    np.testing.assert_allclose(pc.colors, np.tile([1.0, 0.0, 0.0], (1200, 1)))
    assert pc.n_invalid == 0


def test_invalid_depth_is_dropped_and_counted():
    depth = np.full((30, 40), 2.0, np.float32)
    depth[0, :10] = 0.0
    depth[1, :5] = np.nan
    depth[2, :3] = np.inf
    depth[3, :2] = 0.1  # below min_depth
    depth[4, :4] = 50.0  # above max_depth
    pc = rgbd_to_points(depth, INTR, cfg=PerceptionConfig(min_depth=0.28, max_depth=10.0))
    assert pc.n_invalid == 10 + 5 + 3 + 2 + 4
    assert len(pc) == 1200 - pc.n_invalid
    assert np.isfinite(pc.points).all()


def test_uint16_millimetre_depth_and_labels():
    depth = np.full((30, 40), 1500, np.uint16)
    labels = np.ones((30, 40), np.int32)
    pc = rgbd_to_points(depth, INTR, labels=labels, cfg=PerceptionConfig(depth_scale=0.001))
    np.testing.assert_allclose(pc.points[:, 2], 1.5, rtol=1e-6)
    assert pc.labels is not None and (pc.labels == 1).all()


def test_backprojection_of_rendered_scene_lies_on_surfaces():
    scene = box_room_scene()
    intr = Intrinsics.from_fovy(80, 60)
    T = look_at([0.2, 0.1, 1.3], [2.0, 1.0, 0.4])
    pc = rgbd_to_points(scene.render_depth(intr, T), intr)
    pw = pc.points @ T[:3, :3].T + T[:3, 3]
    assert np.abs(scene.sdf(pw)).max() < 1e-4


def test_all_invalid_depth_raises():
    with pytest.raises(EmptyFrameError, match="all 1200 depth values are invalid"):
        rgbd_to_points(np.zeros((30, 40), np.float32), INTR)
    with pytest.raises(EmptyFrameError):
        rgbd_to_points(np.full((30, 40), np.nan, np.float32), INTR)


@pytest.mark.parametrize(
    ("depth", "rgb", "exc", "msg"),
    [
        (np.ones((30, 40, 1), np.float32), None, ValueError, r"\(H, W\)"),
        (np.ones((20, 40), np.float32), None, ValueError, "intrinsics"),
        (np.ones((30, 40), np.int32), None, TypeError, "dtype"),
        (np.ones((30, 40), np.float32), np.zeros((30, 40), np.uint8), ValueError, "rgb has shape"),
        (np.ones((30, 40), np.float32), np.zeros((30, 40, 3), np.int64), TypeError, "rgb must be"),
        ([[1.0]], None, TypeError, "numpy array"),
    ],
)
def test_bad_input_gets_clear_error(depth, rgb, exc, msg):
    with pytest.raises(exc, match=msg):
        rgbd_to_points(depth, INTR, rgb)


def test_empty_depth_raises():
    with pytest.raises(EmptyFrameError):
        rgbd_to_points(np.zeros((0, 0), np.float32), INTR)


def test_voxel_downsample_one_point_per_voxel_with_means():
    pts = np.array(
        [[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.11, 0.0, 0.0], [-0.01, 0.0, 0.0]], np.float32
    )
    cols = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], np.float32)
    labs = np.array([2, 1, 1, 0], np.int16)
    p, c, lab = voxel_downsample(pts, 0.05, cols, labs)
    assert p.shape == (3, 3)
    np.testing.assert_allclose(p[0], [0.02, 0.02, 0.02], atol=1e-7)  # first voxel: mean of two
    np.testing.assert_allclose(c[0], [0.5, 0.5, 0.0])
    assert lab.tolist() == [2, 1, 0]  # label of the first point in each voxel, first-seen order
    keys = np.floor(p / 0.05).astype(int)
    assert len({tuple(k) for k in keys}) == len(keys)


def test_perception_config_rejects_bad_values():
    from simn_sim.config import ConfigError

    with pytest.raises(ConfigError, match="PerceptionConfig.max_depth"):
        PerceptionConfig(min_depth=2.0, max_depth=1.0)
    with pytest.raises(ConfigError, match="unknown config key"):
        PerceptionConfig.from_dict({"min_dept": 0.3})
