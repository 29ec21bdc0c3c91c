"""Occlusion shadows (simn_sim.world.shadow) against exact geometry: a plate seen by a
camera that looks along +x, and depth images of planes at known distances."""

import numpy as np
import pytest

from simn_sim.geometry.camera import Intrinsics
from simn_sim.world.shadow import OcclusionShadow, below_top_contour, may_continue_below_view

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


# ---------------------------------------------------------------- blind-zone shadows
# the robot's camera: 320 x 240, fovy 42.5 deg, at 1.0 m pitched down 24 deg, looking along +x;
# its lower image border descends at 45.25 deg, so a surface at height h is out of view nearer
# than (1 - h) / tan(45.25 deg) (0.654 m for a 0.34 m box top)
_FY = 120 / np.tan(np.radians(21.25))
D435_INTR = Intrinsics(320, 240, _FY, _FY, 159.5, 119.5)
LOW_RAY = np.radians(24 + 21.25)


def _pitched_cam() -> np.ndarray:
    T = _cam_looking_along_x()
    a = np.radians(-24.0)  # pitch down: about the camera x axis (its y points down)
    Rp = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    T[:3, :3] = T[:3, :3] @ Rp
    return T


def _raycast(T: np.ndarray, intr: Intrinsics, boxes: list) -> np.ndarray:
    """Exact depth (along the optical axis) of the floor z = 0 and axis-aligned boxes
    ((lo xyz), (hi xyz)) seen by camera T (slab intersection)."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    rays_c = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)
    d = rays_c.reshape(-1, 3) @ T[:3, :3].T  # world direction per unit optical depth
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_best = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)  # floor
        for lo, hi in boxes:
            t1 = (np.asarray(lo) - o) / d
            t2 = (np.asarray(hi) - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tn <= tf) & (tn > 0)
            t_best = np.where(hit & (tn < t_best), tn, t_best)
    return np.where(np.isfinite(t_best), t_best, 0.0).reshape(intr.height, intr.width)


def _bottom_points(T, intr, depth, rows=5):
    """Back-projected points of the bottom ``rows`` rows above the floor (obstacle points)."""
    v, u = np.mgrid[intr.height - rows : intr.height, 0 : intr.width]
    z = depth[v, u]
    P = np.stack([(u - intr.cx) / intr.fx * z, (v - intr.cy) / intr.fy * z, z], -1).reshape(-1, 3)
    Pw = P @ T[:3, :3].T + T[:3, 3]
    keep = (z.ravel() > 0) & (Pw[:, 2] > 0.05)
    return Pw[keep], np.stack([v.ravel(), u.ravel()], 1)[keep]


def test_a_low_box_top_at_the_lower_border_shadows_its_hidden_part_towards_the_camera():
    T = _pitched_cam()
    near_edge = (1.0 - 0.34) / np.tan(LOW_RAY)  # 0.654 m: the top is out of view nearer
    box = ((0.4, -0.3, 0.0), (1.0, 0.3, 0.34))  # its near 0.25 m is hidden under the view
    depth = _raycast(T, D435_INTR, [box])
    P, pix = _bottom_points(T, D435_INTR, depth)
    assert len(P) and np.allclose(P[:, 2], 0.34, atol=1e-6)  # the top, at the lower border
    assert P[:, 0].min() == pytest.approx(near_edge, abs=0.01)
    cont = may_continue_below_view(depth, D435_INTR, T, rows=5, step=2, jump=0.15)
    assert cont[pix[:, 0], pix[:, 1]].all()
    sh = OcclusionShadow(0.05, 0.3)
    new = sh.cast_below_view(P, T, D435_INTR, depth=0.6)
    c = sh.centres()
    assert len(new) == len(sh) > 0
    # towards the camera only: between the camera and the seen edge, up to 0.6 m before it
    assert np.all(c[:, 0] < near_edge + 0.05) and np.all(c[:, 0] > near_edge - 0.6 - 0.05)
    # the hidden part of the box top (x in [0.4, 0.654), |y| <= 0.3), as far as it lies in
    # the image columns that saw the top (the shadow continues each column below the view:
    # along the ray towards the point under the camera), is all shadow
    gx, gy = np.meshgrid(np.arange(0.425, near_edge - 0.05, 0.05), np.arange(-0.275, 0.28, 0.05))
    g = np.stack([gx.ravel(), gy.ravel()], 1)
    bearing = np.abs(np.arctan2(g[:, 1], g[:, 0] - T[0, 3]))
    seen = np.abs(np.arctan2(P[:, 1], P[:, 0] - T[0, 3])).max()
    g = g[bearing < seen - np.radians(3.0)]
    assert len(g) >= 20
    assert set(map(tuple, np.floor(g / 0.05).astype(int))) <= _cells(sh)
    # required: the sample heights up to the top's (0.1 and 0.3 m), hidden below the view
    assert np.all(sh.required == 0b00011)
    # the same view again sees none of it (it is below the view): nothing clears
    _, cleared = sh.observe(np.zeros((0, 3)), T, depth, D435_INTR)
    assert cleared == 0
    # from 1 m farther back the whole column is in view and the box gone: all seen free
    T_back = T.copy()
    T_back[0, 3] -= 1.0
    _, cleared = sh.observe(np.zeros((0, 3)), T_back, _raycast(T_back, D435_INTR, []), D435_INTR)
    assert cleared == len(new) and len(sh) == 0


def test_a_wall_at_the_lower_border_does_not_continue_below_the_view():
    T = _pitched_cam()
    wall = ((0.8, -2.0, 0.0), (0.9, 2.0, 2.0))  # its face at x = 0.8 fills the bottom rows
    depth = _raycast(T, D435_INTR, [wall])
    P, pix = _bottom_points(T, D435_INTR, depth)
    assert len(P) and np.allclose(P[:, 0], 0.8, atol=1e-6)
    cont = may_continue_below_view(depth, D435_INTR, T, rows=5, step=2, jump=0.15)
    assert not cont[pix[:, 0], pix[:, 1]].any()
    assert not cont[: 240 - 5].any()  # only the bottom rows are ever marked


def test_blind_shadow_bad_input_is_named():
    T = _pitched_cam()
    sh = OcclusionShadow(0.05, 0.3)
    with pytest.raises(ValueError, match="depth"):
        sh.cast_below_view(np.zeros((1, 3)), T, D435_INTR, depth=0.01)
    with pytest.raises(ValueError, match="points"):
        sh.cast_below_view(np.array([[np.nan, 0.0, 0.3]]), T, D435_INTR, depth=0.6)
    with pytest.raises(ValueError, match="T_world_cam"):
        sh.cast_below_view(np.zeros((1, 3)), np.eye(3), D435_INTR, depth=0.6)
    with pytest.raises(ValueError, match="depth shape"):
        may_continue_below_view(np.zeros((10, 10)), D435_INTR, T, 5, 2, 0.15)
    with pytest.raises(ValueError, match="rows"):
        may_continue_below_view(np.zeros((240, 320)), D435_INTR, T, 0, 2, 0.15)


def test_top_contour_matches_a_sliding_window_reference_on_random_depth():
    # the running minimum over shifted copies must give what a min over a sliding-window
    # view of the row above gives (the definition), holes and image sides included
    rng = np.random.default_rng(7)
    d = rng.uniform(0.5, 4.0, (48, 64))
    d[rng.random(d.shape) < 0.1] = 0.0
    d[:6] = np.nan
    for hw in (0, 1, 3):
        dd = np.where(np.isfinite(d) & (d > 0), d, np.inf)
        pad = np.pad(dd[:-1], ((0, 0), (hw, hw)), constant_values=0.0)
        above = np.lib.stride_tricks.sliding_window_view(pad, 2 * hw + 1, axis=1).min(-1)
        with np.errstate(invalid="ignore"):
            brk = np.zeros(d.shape, bool)
            brk[1:] = np.abs(dd[1:] - dd[:-1]) > 0.3
            top = np.zeros(d.shape, bool)
            top[1:] = brk[1:] & (above - dd[1:] > 0.3)
        start = np.maximum.accumulate(np.where(brk, np.arange(48)[:, None], 0), axis=0)
        ref = np.isfinite(d) & (d > 0) & np.take_along_axis(top, start, axis=0)
        got = below_top_contour(d, 0.3, half_width=hw)
        np.testing.assert_array_equal(got, ref)
        assert ref.any() and not ref.all()
