"""Occlusion shadows (simn_sim.agents.shadow) against exact geometry: a plate seen by a
camera that looks along +x, and depth images of planes at known distances."""

import numpy as np
import pytest

from simn_sim.agents.shadow import OcclusionShadow, below_top_contour
from simn_sim.geometry.camera import Intrinsics

# 200 x 200 px, 127 deg field of view: every sample near the plate is in view
INTR = Intrinsics(200, 200, 50.0, 50.0, 99.5, 99.5)


def _cam_looking_along_x(height: float = 1.0) -> np.ndarray:
    """planning frame (z up) <- OpenCV camera (z forward, x right, y down) at (0, 0, height)."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    T[2, 3] = height
    return T


def _plate(x: float = 2.0) -> np.ndarray:
    """Points of a plate x = const, |y| <= 0.5, z in [0.5, 0.9] (a chair back)."""
    y, z = np.meshgrid(np.arange(-0.5, 0.501, 0.02), np.arange(0.5, 0.901, 0.05))
    return np.stack([np.full(y.size, x), y.ravel(), z.ravel()], 1)


def _cells(sh: OcclusionShadow) -> set[tuple[int, int]]:
    return {tuple(x) for x in np.floor(sh.centres() / sh.resolution).astype(int)}


def test_shadow_of_one_point_is_the_ray_segment_behind_it_below_the_ray():
    sh = OcclusionShadow(resolution=0.05, depth=0.3)
    T = _cam_looking_along_x()
    T[1, 3] = 0.025
    depth = np.zeros((200, 200))  # no returns: no free-space evidence
    new, cleared = sh.observe(np.array([[1.025, 0.025, 0.5]]), T, depth, INTR)
    # the point casts a shadow one cell wide (parallel rays at y = 0.025 -+ 0.025, the upper
    # one on the border of row 1) over x in [1.05, 1.35): columns 21-26 of rows 0 and 1
    assert cleared == 0 and len(new) == 12
    assert _cells(sh) == {(i, j) for i in range(21, 27) for j in (0, 1)}
    # the ray descends from 0.5 m by 0.5 / 1.025 per metre: at most 0.476 m over these cells,
    # so the columns are occluded at the sample heights 0.1 and 0.3, not at 0.5 and above
    assert np.all(sh.required == 0b00011)


def test_shadow_behind_a_plate_stays_until_the_space_behind_it_is_seen():
    res, depth = 0.05, 0.3
    sh = OcclusionShadow(res, depth)
    T = _cam_looking_along_x()
    sh.observe(_plate(2.0), T, np.full((200, 200), 2.0), INTR)
    c = sh.centres()
    assert len(c) > 0
    # exactly behind the plate: x in (2, 2 + depth + a cell], |y| within the widened plate
    assert np.all((c[:, 0] > 2.0) & (c[:, 0] <= 2.0 + depth + res))
    assert np.all(np.abs(c[:, 1]) <= 0.5 * (2.0 + depth + res) / 2.0 + res)
    # the occluded strip's interior is all shadow
    gx, gy = np.meshgrid(np.arange(2.05, 2.2, res) + res / 2, np.arange(-0.4, 0.4, res) + res / 2)
    inner = np.floor(np.stack([gx.ravel(), gy.ravel()], 1) / res).astype(int)
    assert set(map(tuple, inner)) <= _cells(sh)
    n = len(sh)
    # the plate is still there (depth 2.0 m on every pixel): nothing behind it is seen free
    _, cleared = sh.observe(np.zeros((0, 3)), T, np.full((200, 200), 2.0), INTR)
    assert cleared == 0 and len(sh) == n
    # the plate gone (6 m on every pixel): every occluded sample is seen free, all cells clear
    _, cleared = sh.observe(np.zeros((0, 3)), T, np.full((200, 200), 6.0), INTR)
    assert cleared == n and len(sh) == 0 and sh.cleared == n
    # seen free is known free: the plate seen again (a static scene) casts no shadow there
    new, _ = sh.observe(_plate(2.0), T, np.full((200, 200), 2.0), INTR)
    assert len(new) == 0 and len(sh) == 0


def test_a_column_clears_only_when_every_occluded_height_is_seen_free():
    """Seeing under the plate does not clear the space behind it: the depth image reads 6 m
    only in the rows below the plate's lower edge (the camera sees the floor under a chair
    back, not through it), so the 0.1 and 0.3 m samples are seen free and 0.5-0.9 m not."""
    sh = OcclusionShadow(0.05, 0.3)
    T = _cam_looking_along_x()
    sh.observe(_plate(2.0), T, np.zeros((200, 200)), INTR)
    n = len(sh)
    # image row v of a point at height h and depth z: v = cy + fy (1.0 - h) / z; rows below the
    # projection of height 0.4 at z = 2.0 (the plate's lower edge region) see 6 m
    d = np.full((200, 200), 2.0)
    v_lo = int(np.ceil(99.5 + 50.0 * (1.0 - 0.4) / 2.0))
    d[v_lo:, :] = 6.0
    _, cleared = sh.observe(np.zeros((0, 3)), T, d, INTR)
    assert cleared == 0 and len(sh) == n  # the 0.5-0.9 m samples are still hidden
    assert np.all(sh.seen & 0b00011 == 0b00011)  # ... while the 0.1, 0.3 m samples were seen


def test_traversed_cells_are_free_and_never_shadow():
    sh = OcclusionShadow(0.05, 0.3)
    T = _cam_looking_along_x()
    sh.observe(_plate(2.0), T, np.zeros((200, 200)), INTR)
    n = len(sh)
    cleared = sh.traverse(np.array([2.2, 0.0]), 0.1)
    assert 0 < cleared < n
    assert not (_cells(sh) & {(44, 0), (43, -1)})  # (2.2, 0.0) and (2.175, -0.025)
    sh.observe(_plate(2.0), T, np.zeros((200, 200)), INTR)  # the same view again
    assert len(sh) == n - cleared


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="depth"):
        OcclusionShadow(0.05, 0.01)
    with pytest.raises(ValueError, match="resolution"):
        OcclusionShadow(0.0, 0.3)
    with pytest.raises(ValueError, match="heights"):
        OcclusionShadow(0.05, 0.3, heights=tuple(np.linspace(0, 1, 9)))
    sh = OcclusionShadow(0.05, 0.3)
    T = _cam_looking_along_x()
    with pytest.raises(ValueError, match="obstacle_points"):
        sh.observe(np.array([[np.nan, 0.0, 0.5]]), T, np.zeros((200, 200)), INTR)
    with pytest.raises(ValueError, match="depth shape"):
        sh.observe(_plate(), T, np.zeros((100, 200)), INTR)
    with pytest.raises(ValueError, match="T_world_cam"):
        sh.observe(_plate(), np.eye(3), np.zeros((200, 200)), INTR)
    with pytest.raises(ValueError, match="xy"):
        sh.traverse(np.array([np.inf, 0.0]), 0.25)


def test_top_contour_marks_objects_with_a_visible_top_not_walls_or_slanted_edges():
    d = np.full((60, 80), 6.0)  # far background
    d[30:, 20:40] = 2.0  # a box whose top edge (row 30) is in view
    d[:, 60:] = 1.5  # a wall reaching the top of the image
    d[25:, 50:56] = 3.0  # a post whose top is in view, narrower than the window
    t = below_top_contour(d, 0.15, half_width=3)
    assert t[30:, 23:37].all()  # the box below its top, away from its sides
    assert not t[:, 60:].any()  # the wall: no top in view
    assert not t[:25].any()  # the background above: nothing nearer above it
    assert t[25:, 50:56].all()  # the row above the post's top is background throughout
    # a slanted edge (a door jamb seen with the camera pitched): each row's edge 1 px further
    s = np.full((40, 80), 6.0)
    for v in range(40):
        s[v, : 30 + v] = 1.0  # the wall occupies the left, its edge moves right going down
    assert not below_top_contour(s, 0.15, half_width=3)[:, :].any()
    # an object cut by the image's side cannot show a horizontal top there
    e = np.full((40, 80), 6.0)
    e[20:, :10] = 2.0
    te = below_top_contour(e, 0.15, half_width=3)
    assert not te[:, :3].any() and te[20:, 3:7].all()
    with pytest.raises(ValueError, match="jump"):
        below_top_contour(d, 0.0)
