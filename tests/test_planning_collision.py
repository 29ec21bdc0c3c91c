"""Collision model: exact answers for walls, incremental updates, frames, bounds of error."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from simn_sim.config import ConfigError
from simn_sim.geometry.se3 import inv_T, planar_T, transform_points
from simn_sim.planning.collision import CollisionChecker, CollisionConfig
from simn_sim.planning.synthetic_maps import FLOOR, OBSTACLE, box_field_map


def wall_points(x: float, y0: float, y1: float, z: float = 0.5, step: float = 0.02) -> np.ndarray:
    y = np.arange(y0, y1 + 1e-9, step)
    return np.column_stack([np.full_like(y, x), y, np.full_like(y, z)])


def test_wall_inflated_by_robot_radius() -> None:
    c = CollisionChecker(CollisionConfig(resolution=0.05, robot_radius=0.25))
    c.update(wall_points(2.0, 0.0, 4.0))
    # is_free is per cell: query and obstacle are each quantised to a cell centre
    tol = 0.05 * np.sqrt(2) + 1e-9
    xs = np.linspace(1.4, 2.6, 241)
    q = np.column_stack([xs, np.full_like(xs, 2.0)])
    free = c.is_free(q)
    expect_free = np.abs(xs - 2.0) > 0.25 + tol
    expect_blocked = np.abs(xs - 2.0) < 0.25 - tol
    assert expect_free.sum() > 50 and expect_blocked.sum() > 50
    assert np.all(free[expect_free]) and not np.any(free[expect_blocked])
    assert [c.is_free_point(x, 2.0) for x in xs] == free.tolist()
    # clearance (point-based) equals the distance to the wall up to obstacle quantisation
    qq = np.column_stack([np.linspace(0.5, 3.5, 13), np.full(13, 2.0)])
    np.testing.assert_allclose(
        c.clearance(qq), np.minimum(np.abs(qq[:, 0] - 2.0), 2.0), atol=0.05 / np.sqrt(2) + 1e-6
    )
    # beyond the wall's end (y > 4.25 + tol) the robot passes
    assert c.is_free(np.array([[2.0, 4.35]]))[0]
    # unknown space (outside the grid) is free
    assert c.is_free(np.array([[50.0, -40.0]]))[0] and c.is_free_point(50.0, -40.0)
    assert not c.is_free_point(float("nan"), 0.0)
    assert c.clearance(np.array([[50.0, -40.0]]))[0] == c.cfg.max_clearance


def test_height_band_and_labels_filter_points() -> None:
    c = CollisionChecker(CollisionConfig(z_min=0.1, z_max=1.2))
    pts = np.concatenate(
        [
            wall_points(1.0, 0.0, 2.0, z=0.02),  # below the band
            wall_points(2.0, 0.0, 2.0, z=1.5),  # above the band
            wall_points(3.0, 0.0, 2.0, z=0.5),  # labelled floor
            wall_points(4.0, 0.0, 2.0, z=0.5),  # obstacle
        ]
    )
    labels = np.repeat([OBSTACLE, OBSTACLE, FLOOR, OBSTACLE], len(pts) // 4)
    c.update(pts, labels)
    q = np.array([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [4.0, 1.0]])
    np.testing.assert_array_equal(c.is_free(q), [True, True, True, False])
    with pytest.raises(ValueError, match="labels"):
        c.update(pts, labels[:-1])


def test_incremental_update_equals_batch_build_and_grid_grows() -> None:
    m = box_field_map(np.random.default_rng(3))
    obst = m.points[m.labels == OBSTACLE]
    cfg = CollisionConfig(max_clearance=1.0, grow_padding=0.5)
    batch = CollisionChecker(cfg)
    batch.update(obst)
    inc = CollisionChecker(cfg)
    # chunks sorted by x descending: the grid must grow towards -x and +y on later updates
    order = np.argsort(-obst[:, 0] + 0.3 * obst[:, 1])
    shapes = []
    for chunk in np.array_split(obst[order], 5):
        inc.update(chunk)
        shapes.append(inc.shape)
    assert len(set(shapes)) > 1, "the grid never grew"
    rng = np.random.default_rng(0)
    q = rng.uniform([-1, -1], [11, 9], size=(4000, 2))
    # same cells, same cell-centre distances; the nearest cell may differ only between ties
    lo = batch.cell_offset - inc.cell_offset
    sl = np.s_[lo[0] : lo[0] + batch.shape[0], lo[1] : lo[1] + batch.shape[1]]
    assert np.all(lo >= 0) and inc.occupied.sum() == batch.occupied.sum()
    np.testing.assert_array_equal(inc.occupied[sl], batch.occupied)
    np.testing.assert_allclose(inc.dist[sl], batch.dist, atol=1e-6)
    assert np.mean(inc.is_free(q) == batch.is_free(q)) > 0.995
    # reset + rebuild (after anchors moved) gives the batch map again
    inc.reset()
    assert inc.is_free(q).all() and inc.n_points == 0 and inc.shape == (0, 0)
    inc.update(obst)
    np.testing.assert_array_equal(inc.is_free(q), batch.is_free(q))
    # clearance is the distance to the occupied cell centre nearest to q's cell centre: never
    # below the true nearest distance, and above it by at most 2 |q - cell centre| = res sqrt(2)
    centres = inc.occupied_centres()
    true = np.minimum(cKDTree(centres).query(q)[0], cfg.max_clearance)
    ours = inc.clearance(q)
    assert np.all(ours >= true - 1e-9)
    assert np.all(ours <= true + cfg.resolution * np.sqrt(2) + 1e-9)


def test_points_from_several_frames_in_common_frame() -> None:
    # off the cell boundaries, so float round-off of the frame round trip cannot flip a cell
    world = np.concatenate([wall_points(2.013, 0.011, 3.0), wall_points(5.012, 1.011, 4.0)])
    T_world_f1 = planar_T(1.0, -2.0, 0.7)
    T_world_f2 = planar_T(-3.0, 0.5, -2.0)
    a = CollisionChecker()
    a.update(world)
    b = CollisionChecker()
    half = len(world) // 2
    b.update(transform_points(inv_T(T_world_f1), world[:half]), T_common_frame=T_world_f1)
    b.update(transform_points(inv_T(T_world_f2), world[half:]), T_common_frame=T_world_f2)
    q = np.random.default_rng(1).uniform([0, -1], [7, 5], size=(2000, 2))
    np.testing.assert_array_equal(a.is_free(q), b.is_free(q))


def test_segments_free_matches_dense_point_checks() -> None:
    c = CollisionChecker()
    c.update(wall_points(2.0, 0.0, 4.0))
    rng = np.random.default_rng(2)
    A = rng.uniform([0, -1], [4, 5], size=(300, 2))
    B = A + rng.normal(scale=1.0, size=(300, 2))
    got = c.segments_free(A, B)
    t = np.linspace(0, 1, 400)
    dense = np.array([c.is_free(a + (b - a) * t[:, None]).all() for a, b in zip(A, B, strict=True)])
    # sampling at res/2 can only miss a sliver thinner than that; with a 0.5 m inflated wall none
    np.testing.assert_array_equal(got, dense)
    assert got.any() and not got.all()
    # the scalar grid walk visits the same cells
    assert [c.segment_free(a, b) for a, b in zip(A, B, strict=True)] == got.tolist()
    # direction-independent, and every sub-segment of a free segment is free
    np.testing.assert_array_equal(c.segments_free(B, A), got)
    t0, t1 = np.sort(rng.uniform(0, 1, size=(2, 300)), axis=0)
    sa, sb = A + (B - A) * t0[:, None], A + (B - A) * t1[:, None]
    assert np.all(c.segments_free(sa, sb)[got])
    assert not c.segment_free([1.0, 2.0], [3.0, 2.0])  # crosses the wall
    assert c.segment_free([1.0, 4.5], [3.0, 4.5])  # passes above its end
    assert not c.segments_free(np.array([[np.nan, 0.0]]), np.array([[0.0, 0.0]]))[0]
    assert not c.is_free(np.array([[np.nan, 1.0]]))[0]


@pytest.mark.parametrize("margin", [0.0, 0.1])
def test_scalar_walk_with_distance_shortcuts_equals_vectorised(margin: float) -> None:
    """segment_free accepts a segment from the distance transform at its midpoint and jumps
    through open space during the walk; both shortcuts must keep the exact cell walk's answer
    (box field: open space, narrow gaps and segments ending outside the grid)."""
    m = box_field_map(np.random.default_rng(4))
    c = CollisionChecker(CollisionConfig(margin=margin))
    c.update(m.points, m.labels)
    rng = np.random.default_rng(5)
    lo, hi = np.array(m.bounds[:2]) - 3.0, np.array(m.bounds[2:]) + 3.0
    n_free = 0
    for scale in (0.3, 1.0, 4.0, 15.0):
        A = rng.uniform(lo, hi, size=(400, 2))
        ang = rng.uniform(0, 2 * np.pi, 400)
        B = A + scale * rng.uniform(0, 1, (400, 1)) * np.column_stack([np.cos(ang), np.sin(ang)])
        want = c.segments_free(A, B)
        assert [c.segment_free(a, b) for a, b in zip(A, B, strict=True)] == want.tolist()
        assert [c.segment_free(b, a) for a, b in zip(A, B, strict=True)] == want.tolist()
        n_free += int(want.sum())
        assert not want.all()
    assert n_free > 400


def test_obstacle_polygons_cover_occupied_cells() -> None:
    c = CollisionChecker()
    c.update(wall_points(2.0, 0.0, 1.0))
    polys = c.obstacle_polygons()
    area = sum(p.area for p in polys)
    n = int(c.occupied.sum())
    assert area == pytest.approx(n * c.cfg.resolution**2)
    from shapely.geometry import Point

    for xy in c.occupied_centres():
        assert any(p.contains(Point(*xy)) for p in polys)


@pytest.mark.parametrize(
    "kw",
    [
        dict(resolution=0.0),
        dict(resolution=float("nan")),
        dict(robot_radius=-0.1),
        dict(z_min=1.0, z_max=0.5),
        dict(max_clearance=0.1),
    ],
)
def test_bad_config_raises(kw: dict) -> None:
    with pytest.raises(ConfigError):
        CollisionConfig(**kw)


def test_bad_points_raise() -> None:
    c = CollisionChecker()
    with pytest.raises(ValueError, match="points"):
        c.update(np.zeros((5, 4)))
    with pytest.raises(ValueError, match="T_common_frame"):
        c.update(np.zeros((5, 2)), T_common_frame=np.eye(4))


def test_obstacle_polygons_give_freespace_reference() -> None:
    fs_mod = pytest.importorskip("simn_sim.geometry.freespace")
    from simn_sim.planning.synthetic_maps import doorway_map

    m = doorway_map()
    c = CollisionChecker()
    c.update(m.points, m.labels)
    fs = fs_mod.FreeSpace2D(c.obstacle_polygons(), robot_radius=c.cfg.inflation, bounds=m.bounds)
    d = fs.geodesic_distance(np.array([2.0, 2.0]), np.array([8.0, 2.0]))
    # analytic on the true walls: 6.959 m (tangents + arc around the door jamb); the cell
    # footprints are up to one cell bigger
    assert 6.959 - 0.01 <= d <= 6.959 + 0.1
    path = fs.shortest_path(np.array([2.0, 2.0]), np.array([8.0, 2.0]))
    assert path is not None and path[:, 1].max() > 3.5  # through the doorway
