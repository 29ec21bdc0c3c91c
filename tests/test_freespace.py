"""FreeSpace2D against analytic shortest paths and a brute-force polygon visibility graph."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
import shapely

from simn_sim.geometry.freespace import FreeSpace2D

R = 0.25


def square(cx: float, cy: float, half: float) -> np.ndarray:
    return np.array(
        [
            [cx - half, cy - half],
            [cx + half, cy - half],
            [cx + half, cy + half],
            [cx - half, cy + half],
        ]
    )


def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def around_corner(s: np.ndarray, c: np.ndarray, r: float, heading: float, left: bool) -> float:
    """Length from s, tangent to the circle (c, r), then along it until travelling at `heading`.

    left=True: the circle is on the robot's left (counter-clockwise turn around it).
    """
    q = c - s
    dist = float(np.linalg.norm(q))
    a = math.atan2(q[1], q[0])
    psi = a - math.asin(r / dist) if left else a + math.asin(r / dist)
    turn = heading - psi if left else psi - heading
    assert turn >= 0
    return math.sqrt(dist**2 - r**2) + r * turn


def polyline_length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


# ----------------------------------------------------------------------------- analytic


def test_square_between_start_and_goal_matches_tangent_arc_formula():
    fs = FreeSpace2D([square(0, 0, 0.5)], R)
    s, g = np.array([-3.0, 0.2]), np.array([3.0, -0.1])
    # Goes over the top (start is above the axis): two corners, the offset edge in between.
    top = (
        around_corner(s, np.array([-0.5, 0.5]), R, 0.0, left=False)
        + 1.0
        + around_corner(g, np.array([0.5, 0.5]), R, math.pi, left=True)
    )
    d = fs.geodesic_distance(s, g)
    assert d == pytest.approx(top, abs=1e-6)
    path = fs.shortest_path(s, g)
    assert path is not None
    np.testing.assert_allclose(path[0], s)
    np.testing.assert_allclose(path[-1], g)
    assert d <= polyline_length(path) <= d * 1.001
    assert path[:, 1].max() > 0.5  # over the top
    assert all(fs.segment_free(a, b) for a, b in zip(path[:-1], path[1:], strict=True))


def test_single_corner_wrap():
    # L-turn around one corner of a large block: start below-left, goal up-right of corner (1, 1).
    fs = FreeSpace2D([box(-5, -5, 1, 1)], R)
    s, g = np.array([2.0, -3.0]), np.array([-3.0, 2.0])
    c = np.array([1.0, 1.0])
    # Tangent from s to c's circle, arc, tangent to g; the circle is on the robot's left.
    qs, qg = c - s, g - c
    ds, dg = np.linalg.norm(qs), np.linalg.norm(qg)
    psi_in = math.atan2(qs[1], qs[0]) - math.asin(R / ds)  # heading of the tangent into c
    psi_out = math.atan2(qg[1], qg[0]) + math.asin(R / dg)  # heading of the tangent out of c
    expected = math.sqrt(ds**2 - R**2) + R * (psi_out - psi_in) + math.sqrt(dg**2 - R**2)
    assert fs.geodesic_distance(s, g) == pytest.approx(expected, abs=1e-6)
    assert fs.geodesic_distance(g, s) == pytest.approx(expected, abs=1e-6)


def test_straight_line_when_visible():
    fs = FreeSpace2D([square(0, 0, 0.5)], R)
    s, g = np.array([-3.0, 1.0]), np.array([3.0, 1.2])
    path = fs.shortest_path(s, g)
    assert path is not None and len(path) == 2
    assert fs.geodesic_distance(s, g) == pytest.approx(float(np.linalg.norm(g - s)), abs=1e-12)
    assert fs.geodesic_distance(s, s) == 0.0


def wall_with_door(door_x0: float, door_x1: float, t: float = 0.2) -> list[np.ndarray]:
    return [box(-5.5, -t / 2, door_x0, t / 2), box(door_x1, -t / 2, 5.5, t / 2)]


def test_wall_with_doorway_path_goes_through_door():
    bounds = (-5.0, -5.0, 5.0, 5.0)
    fs = FreeSpace2D(wall_with_door(1.0, 2.0), R, bounds=bounds)
    # Straight through the door centre.
    assert fs.geodesic_distance([1.5, -3.0], [1.5, 3.0]) == pytest.approx(6.0, abs=1e-9)
    # From the left: around the door's left jamb (corners (1, -0.1) and (1, 0.1)).
    s, g = np.array([-1.0, -2.0]), np.array([-1.0, 2.0])
    leg = around_corner(s, np.array([1.0, -0.1]), R, math.pi / 2, left=True)
    expected = 2 * leg + 0.2
    d = fs.geodesic_distance(s, g)
    assert d == pytest.approx(expected, abs=1e-6)
    path = fs.shortest_path(s, g)
    assert path is not None
    assert np.all((path[:, 0] >= -5) & (path[:, 0] <= 5))
    k = int(np.nonzero((path[:-1, 1] < 0) & (path[1:, 1] >= 0))[0][0])
    x_cross = np.interp(0.0, path[k : k + 2, 1], path[k : k + 2, 0])
    assert 1.0 + R - 1e-6 <= x_cross <= 2.0 - R


def test_door_narrower_than_robot_is_unreachable():
    fs = FreeSpace2D(wall_with_door(1.0, 1.45), R, bounds=(-5.0, -5.0, 5.0, 5.0))
    s, g = np.array([1.2, -2.0]), np.array([1.2, 2.0])
    assert fs.is_free(np.stack([s, g])).all()
    assert fs.geodesic_distance(s, g) == math.inf
    assert fs.shortest_path(s, g) is None
    assert fs.distance_field_to(g).distance(s) == math.inf
    # Same side still reachable.
    assert fs.geodesic_distance(s, [-2.0, -2.0]) == pytest.approx(3.2, abs=1e-9)


def test_gap_of_exactly_two_radii_is_passable():
    s, g = np.array([1.25, -2.0]), np.array([1.25, 2.0])
    exact = FreeSpace2D(wall_with_door(1.0, 1.0 + 2 * R), R, bounds=(-5.0, -5.0, 5.0, 5.0))
    assert exact.geodesic_distance(s, g) == pytest.approx(4.0, abs=1e-9)
    narrow = FreeSpace2D(wall_with_door(1.0, 1.0 + 2 * R - 1e-4), R, bounds=(-5.0, -5.0, 5.0, 5.0))
    assert narrow.geodesic_distance(s, g) == math.inf


def test_bounds_force_the_other_way_round():
    s, g = np.array([-3.0, 0.3]), np.array([3.0, 0.3])
    free = FreeSpace2D([square(0, 0, 0.5)], R)
    bounded = FreeSpace2D([square(0, 0, 0.5)], R, bounds=(-5.0, -5.0, 5.0, 0.6))
    # Mirror image: going below from y=0.3 is going above from y=-0.3.
    s_m, g_m = s * [1, -1], g * [1, -1]
    over = lambda a, b: (  # noqa: E731
        around_corner(a, np.array([-0.5, 0.5]), R, 0.0, left=False)
        + 1.0
        + around_corner(b, np.array([0.5, 0.5]), R, math.pi, left=True)
    )
    assert free.geodesic_distance(s, g) == pytest.approx(over(s, g), abs=1e-6)
    assert bounded.geodesic_distance(s, g) == pytest.approx(over(s_m, g_m), abs=1e-6)
    path = bounded.shortest_path(s, g)
    assert path is not None and path[:, 1].max() <= 0.6 + 1e-9
    assert not bounded.is_free(np.array([0.0, 0.7]))
    assert free.is_free(np.array([0.0, 0.76]))


def test_start_or_goal_inside_inflated_obstacle():
    fs = FreeSpace2D([square(0, 0, 0.5)], R)
    inside = np.array([0.6, 0.0])  # clearance 0.1 < r
    ok = np.array([3.0, 0.0])
    assert fs.shortest_path(inside, ok) is None
    assert fs.shortest_path(ok, inside) is None
    assert fs.geodesic_distance(inside, ok) == math.inf
    with pytest.raises(ValueError, match="not in free space"):
        fs.distance_field_to(inside)
    assert fs.distance_field_to(ok).distance(inside) == math.inf


def test_is_free_and_clearance_analytic():
    fs = FreeSpace2D([square(0, 0, 0.5)], R)
    pts = np.array(
        [[1.0, 0.0], [0.9, 0.9], [0.6, 0.6], [0.0, 0.0], [0.5, 0.5], [-2.0, 0.3], [0.0, -0.76]]
    )
    expected = np.array([0.5, math.hypot(0.4, 0.4), math.hypot(0.1, 0.1), 0.0, 0.0, 1.5, 0.26])
    np.testing.assert_allclose(fs.clearance(pts), expected, atol=1e-12)
    np.testing.assert_array_equal(fs.is_free(pts), expected >= R)
    # Near the inflated boundary: +-1 mm along a face and around a corner.
    ang = np.linspace(0.0, math.pi / 2, 7)
    corner = np.array([0.5, 0.5])
    for dr, want in [(1e-3, True), (-1e-3, False)]:
        ring = corner + (R + dr) * np.stack([np.cos(ang), np.sin(ang)], 1)
        face = np.array([[0.5 + R + dr, y] for y in np.linspace(-0.5, 0.5, 5)])
        assert np.all(fs.is_free(np.concatenate([ring, face])) == want)
    assert fs.is_free(np.zeros((0, 2))).shape == (0,)
    assert fs.is_free(np.array([3.0, 3.0])).shape == ()
    assert np.isinf(FreeSpace2D([], R).clearance(np.array([[0.0, 0.0]]))).all()


def test_segment_free():
    fs = FreeSpace2D([square(0, 0, 0.5)], R)
    assert fs.segment_free([-2, 0.76], [2, 0.76])
    assert not fs.segment_free([-2, 0.74], [2, 0.74])
    assert not fs.segment_free([-2, 0.0], [2, 0.0])
    assert fs.segment_free([2, 2], [2, 2])


def test_goal_field_matches_geodesic_and_path():
    obs = [*wall_with_door(1.0, 2.0), square(-2.0, 2.0, 0.4), square(3.0, -2.0, 0.3)]
    fs = FreeSpace2D(obs, R, bounds=(-5.0, -5.0, 5.0, 5.0))
    rng = np.random.default_rng(3)
    goal = fs.sample_free(rng, 1)[0]
    field = fs.distance_field_to(goal)
    pts = fs.sample_free(rng, 20)
    batch = field.distance(pts)
    assert batch.shape == (20,)
    for p, d in zip(pts, batch, strict=True):
        fresh = FreeSpace2D(obs, R, bounds=(-5.0, -5.0, 5.0, 5.0))
        assert fresh.geodesic_distance(p, goal) == pytest.approx(d, abs=1e-9)
        path = field.path(p)
        assert path is not None
        assert d - 1e-9 <= polyline_length(path) <= d * 1.001 + 1e-9
        assert d >= np.linalg.norm(p - goal) - 1e-9
        assert all(fs.segment_free(a, b) for a, b in zip(path[:-1], path[1:], strict=True))


def test_shapely_geometries_and_overlaps_accepted():
    obs = [shapely.Point(0, 0).buffer(0.3, quad_segs=8), shapely.LineString([(1, -1), (1, 1)])]
    fs = FreeSpace2D(obs, R)
    assert fs.clearance(np.array([[1.5, 0.0]]))[0] == pytest.approx(0.5, abs=1e-5)
    s, g = np.array([1.0, -2.0]), np.array([1.0, 2.0])
    # Around the end of a line: two quarter-ish turns around (1, +-1) with the offset in between.
    leg = around_corner(s, np.array([1.0, -1.0]), R, math.pi / 2, left=False)
    assert fs.geodesic_distance(s, g) == pytest.approx(2 * leg + 2.0, abs=1e-4)


# ----------------------------------------------------------------------------- brute force


def reference_lengths(obstacles, r, pairs, radius_scale: float, quad_segs: int = 16) -> list[float]:
    """Shortest paths through the polygon visibility graph of buffer(r * radius_scale).

    radius_scale = 1 gives an inscribed polygon (free space too large: a lower bound);
    1 / cos(pi / (4 quad_segs)) gives a circumscribed one (an upper bound).
    """
    polys = [shapely.Polygon(o) for o in obstacles]
    infl = shapely.union_all([p.buffer(r * radius_scale, quad_segs=quad_segs) for p in polys])
    rings = []
    for poly in shapely.get_parts(infl):
        rings += [poly.exterior, *poly.interiors]
    ends = np.array([p for pair in pairs for p in pair])
    verts = np.concatenate([np.asarray(rg.coords)[:-1] for rg in rings] + [ends])
    n = len(verts)
    i, j = np.triu_indices(n, 1)
    lines = shapely.linestrings(np.stack([verts[i], verts[j]], axis=1))
    # Segment interior and endpoints must not touch the polygon interior.
    ok = shapely.relate_pattern(lines, infl, "F**F*****")
    graph = nx.Graph()
    graph.add_nodes_from(range(n))
    w = np.linalg.norm(verts[i] - verts[j], axis=1)
    graph.add_weighted_edges_from(zip(i[ok].tolist(), j[ok].tolist(), w[ok].tolist(), strict=True))
    out = []
    first = n - len(ends)
    for k in range(len(pairs)):
        try:
            out.append(nx.dijkstra_path_length(graph, first + 2 * k, first + 2 * k + 1))
        except nx.NetworkXNoPath:
            out.append(math.inf)
    return out


def random_scene(rng: np.random.Generator, k: int) -> list[np.ndarray]:
    obs = []
    for _ in range(k):
        c = rng.uniform(-2.5, 2.5, 2)
        w, h = rng.uniform(0.1, 1.2, 2)
        yaw = rng.uniform(0, math.pi)
        rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
        obs.append((np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2) @ rot.T + c)
    return obs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_brute_force_visibility_graph(seed):
    rng = np.random.default_rng(seed)
    obs = random_scene(rng, 10)
    fs = FreeSpace2D(obs, R, bounds=(-4.5, -4.5, 4.5, 4.5))  # never binding: obstacles within 3.1
    q = 16
    pts = fs.sample_free(rng, 200, min_clearance=R + 0.01)
    pts = pts[np.abs(pts).max(axis=1) < 3.2]
    left, right = pts[pts[:, 0] < -1.0][:6], pts[pts[:, 0] > 1.0][:6]
    pairs = list(zip(left, right, strict=False))
    assert len(pairs) == 6
    lo = reference_lengths(obs, R, pairs, 1.0, q)
    hi = reference_lengths(obs, R, pairs, 1.0 / math.cos(math.pi / (4 * q)), q)
    detours = 0
    for (s, g), a, b in zip(pairs, lo, hi, strict=True):
        d = fs.geodesic_distance(s, g)
        assert a - 1e-3 <= d <= b + 1e-3, (s, g, a, d, b)
        detours += d > np.linalg.norm(g - s) + 1e-3
    assert detours >= 2  # the scene actually forces non-straight paths


# ----------------------------------------------------------------------------- misc


def test_sample_free_respects_clearance_and_is_deterministic():
    obs = [*wall_with_door(1.0, 2.0), square(-2.0, 2.0, 0.4)]
    fs = FreeSpace2D(obs, R, bounds=(-5.0, -5.0, 5.0, 5.0))
    a = fs.sample_free(np.random.default_rng(7), 200, min_clearance=0.5)
    b = fs.sample_free(np.random.default_rng(7), 200, min_clearance=0.5)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (200, 2)
    assert fs.is_free(a).all() and (fs.clearance(a) >= 0.5).all()
    assert np.all((a >= -5) & (a <= 5))


def test_bad_input_raises_value_error():
    sq = square(0, 0, 0.5)
    with pytest.raises(ValueError, match="robot_radius"):
        FreeSpace2D([sq], -0.1)
    with pytest.raises(ValueError, match="robot_radius"):
        FreeSpace2D([sq], float("nan"))
    with pytest.raises(ValueError, match=r"obstacles\[1\]"):
        FreeSpace2D([sq, np.zeros((3, 3))], R)
    with pytest.raises(ValueError, match=r"obstacles\[0\].*finite"):
        FreeSpace2D([np.array([[0, 0], [1, np.nan], [1, 1]])], R)
    with pytest.raises(ValueError, match="invalid"):
        FreeSpace2D([np.array([[0, 0], [1, 1], [1, 0], [0, 1]])], R)  # bow-tie
    with pytest.raises(ValueError, match="bounds"):
        FreeSpace2D([sq], R, bounds=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="quad_segs"):
        FreeSpace2D([sq], R, quad_segs=0)
    fs = FreeSpace2D([sq], R)
    with pytest.raises(ValueError, match="shape"):
        fs.is_free(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="finite"):
        fs.clearance(np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="start"):
        fs.geodesic_distance([0.0, 0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="goal"):
        fs.shortest_path([3.0, 0.0], [np.inf, 1.0])


def test_nearest_free_projects_penetrating_points():
    fs = FreeSpace2D([square(0, 0, 0.5)], R, bounds=(-5.0, -5.0, 5.0, 5.0))
    pts = np.array([[0.74, 0.1], [3.0, 3.0], [0.0, -0.7], [6.0, 0.0]])
    out = fs.nearest_free(pts)
    assert fs.is_free(out).all()
    np.testing.assert_allclose(out[1], pts[1])
    np.testing.assert_allclose(out[0], [0.75 + 1e-4, 0.1], atol=2e-5)
    np.testing.assert_allclose(out[2], [0.0, -0.75 - 1e-4], atol=2e-5)
    np.testing.assert_allclose(out[3], [5.0, 0.0])
    field = fs.distance_field_to([-3.0, 0.0])
    assert np.isfinite(field.distance(out[0]))
    # Snapped distance of a point 1 cm inside the inflated face: offset + distance from there.
    inside = np.array([0.74, 0.0])
    assert field.distance(inside) == math.inf
    want = 0.01 + field.distance(np.array([0.75, 0.0]))
    assert field.distance(inside, snap=0.02) == pytest.approx(want, abs=2e-4)
    assert field.distance(inside[None], snap=0.005)[0] == math.inf  # too deep for this snap
