"""The cost-to-go map around the RRT* (simn_sim.planning.costmap) against exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.planning.collision import CollisionChecker
from simn_sim.planning.collision_config import CollisionConfig
from simn_sim.planning.costmap import CostMap, CostMapConfig

R = 0.25  # robot radius
CC = CollisionConfig(robot_radius=R, margin=0.1, z_min=0.06, z_max=1.0)


def checkers(points: np.ndarray) -> tuple[CollisionChecker, CollisionChecker]:
    planning = CollisionChecker(CC)
    safety = CollisionChecker(CC.replace(margin=0.03))
    lab = np.full(len(points), 2, np.int8)
    for ch in (planning, safety):
        ch.update(points, lab)
    return planning, safety


def wall_x0(gaps: list[tuple[float, float]], y_lo=-6.0, y_hi=6.0) -> np.ndarray:
    """Points on the wall x = 0 from y_lo to y_hi, minus the gaps."""
    ys = np.arange(y_lo, y_hi, 0.01)
    keep = np.ones(len(ys), bool)
    for a, b in gaps:
        keep &= ~((ys > a) & (ys < b))
    ys = ys[keep]
    return np.c_[np.zeros_like(ys), ys, np.full_like(ys, 0.5)]


def known_everywhere(lo=-8.0, hi=8.0) -> np.ndarray:
    g = np.arange(lo, hi, 0.1)
    X, Y = np.meshgrid(g, g)
    return np.c_[X.ravel(), Y.ravel()]


def test_open_space_cost_is_the_grid_geodesic_of_the_straight_line():
    planning, safety = checkers(np.array([[10.0, 10.0, 0.5]]))  # one far obstacle
    cm = CostMap(
        CostMapConfig(), safety, planning, np.array([3.0, 1.0]), np.zeros(2), known_everywhere()
    )
    c = cm.cost_to_go(np.zeros(2))
    euclid = math.hypot(3.0, 1.0)
    octile = 3.0 + (math.sqrt(2) - 1) * 1.0
    assert euclid - 1e-9 <= c <= octile + 0.2


def test_wall_with_a_door_gives_the_exact_detour():
    # wall x=0 with a 1.2 m door y in (1, 2.2); the robot centre must keep R + 3 cm from the
    # jambs, so the shortest route from (-2, 0) to (2, 0) bends at (0, 1 + R + 0.03)
    planning, safety = checkers(wall_x0([(1.0, 2.2)]))
    goal, start = np.array([2.0, 0.0]), np.array([-2.0, 0.0])
    cm = CostMap(
        CostMapConfig(margin_weight=1.0), safety, planning, goal, start, known_everywhere()
    )
    y_star = 1.0 + R + 0.03
    exact = 2 * math.hypot(2.0, y_star)
    # an 8-connected grid measures each straight leg (dx, dy) as dx + (sqrt 2 - 1) dy
    octile = 2 * (2.0 + (math.sqrt(2) - 1) * y_star)
    c = cm.cost_to_go(start)
    assert exact - 0.05 <= c <= octile + 0.1
    p = cm.path(start)
    assert p is not None and np.allclose(p[0], start) and np.allclose(p[-1], goal)
    # the route crosses the wall inside the door
    k = np.flatnonzero(np.diff(np.sign(p[:, 0])) != 0)[0]
    assert 1.0 + R <= p[k, 1] <= 2.2 - R
    assert cm.path_cost(p) >= c - 1e-6
    # a straight line through the wall is blocked
    assert math.isinf(cm.path_cost(np.array([start, goal])))


def test_unknown_space_costs_unknown_weight_per_metre():
    planning, safety = checkers(np.array([[10.0, 10.0, 0.5]]))
    goal, start = np.array([4.0, 0.0]), np.zeros(2)
    known = CostMap(CostMapConfig(), safety, planning, goal, start, known_everywhere())
    unknown = CostMap(CostMapConfig(unknown_weight=3.0), safety, planning, goal, start, None)
    assert unknown.cost_to_go(start) == pytest.approx(3.0 * known.cost_to_go(start), rel=0.03)


def test_a_door_narrower_than_the_planning_margin_is_passable_at_a_price():
    # 0.62 m door: blocked for the planning margin (2 x 0.35 m), free for the safety margin
    # (2 x 0.28 m)
    planning, safety = checkers(wall_x0([(1.0, 1.62)]))
    goal, start = np.array([2.0, 1.31]), np.array([-2.0, 1.31])
    assert not planning.is_free(np.array([[0.0, 1.31]]))[0]
    assert safety.is_free(np.array([[0.0, 1.31]]))[0]
    cheap = CostMap(CostMapConfig(margin_weight=1.0), safety, planning, goal, start, None)
    dear = CostMap(CostMapConfig(margin_weight=4.0), safety, planning, goal, start, None)
    assert math.isfinite(cheap.cost_to_go(start))
    assert dear.cost_to_go(start) > cheap.cost_to_go(start) + 0.5


def test_enclosed_goal_is_unreachable():
    # a closed 2 m box around the goal
    s = np.arange(-1.0, 1.0, 0.01)
    box = np.r_[
        np.c_[s, np.full_like(s, -1.0)],
        np.c_[s, np.full_like(s, 1.0)],
        np.c_[np.full_like(s, -1.0), s],
        np.c_[np.full_like(s, 1.0), s],
    ]
    planning, safety = checkers(np.c_[box, np.full(len(box), 0.5)])
    cm = CostMap(CostMapConfig(), safety, planning, np.zeros(2), np.array([-4.0, 0.0]), None)
    assert math.isinf(cm.cost_to_go(np.array([-4.0, 0.0])))
    assert cm.path(np.array([-4.0, 0.0])) is None


@pytest.mark.parametrize(
    "field, value",
    [("unknown_weight", 0.5), ("margin_weight", 0.0), ("resolution", 0.0), ("pad", -1.0)],
)
def test_bad_config_is_named(field, value):
    with pytest.raises(ConfigError, match=field):
        CostMapConfig(**{field: value})


def test_path_cost_with_exact_segments_applies_the_followers_test():
    """A diagonal 0.1 m step (the cost map's grid step) near an obstacle's inflated disc can
    pass a blocked cell between path_cost's 5 cm samples. The follower's exact traversal
    (segments_free) refuses such a step; with ``exact_segments`` path_cost calls it blocked
    too, by default (samples only) it is priced."""
    planning, safety = checkers(np.array([[0.0, 0.0, 0.5]]))
    goal, start, known = np.array([3.0, 0.0]), np.array([-3.0, 0.0]), known_everywhere()
    exact_cm = CostMap(CostMapConfig(exact_segments=True), safety, planning, goal, start, known)
    sampled_cm = CostMap(CostMapConfig(), safety, planning, goal, start, known)
    rng = np.random.default_rng(1)
    grazing = free = 0
    for _ in range(3000):
        ang, r = rng.uniform(0, 2 * math.pi), rng.uniform(0.25, 0.32)
        m = r * np.array([math.cos(ang), math.sin(ang)])
        d = np.array([0.1, 0.1 if rng.random() < 0.5 else -0.1])
        a, b = m - d / 2, m + d / 2
        q = a + ((np.arange(3) + 0.5) / 3)[:, None] * (b - a)  # path_cost's samples of a step
        exact = bool(safety.segments_free(a[None], b[None])[0])
        assert math.isfinite(exact_cm.path_cost(np.stack([a, b]))) == exact
        sampled_free = bool(safety.is_free(np.vstack([a, b, q])).all())
        if not exact and sampled_free:
            grazing += 1
            assert math.isfinite(sampled_cm.path_cost(np.stack([a, b])))
        free += int(exact)
    assert grazing > 0 and free > 0  # both kinds of step were judged


def test_a_person_in_the_doorway_is_priced_not_a_wall():
    """A wall x = 0 with two doors, (1.0, 2.2) and (4.0, 5.2), and a person (a 0.2 m disc) in
    the near one. Without transient pricing the near door is closed and the route takes the far
    door. With ``transient_weight`` w and a static model that holds the wall alone, the near
    door is passable at w per metre inside the person's blocked disc: the cost lies between the
    free door's geodesic and that plus (w - 1) x the disc's diameter (plus the grid's slack),
    the route crosses the wall in the near door, and a line through the wall stays blocked."""
    wall = wall_x0([(1.0, 2.2), (4.0, 5.2)])
    a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rr = np.linspace(0.0, 0.2, 5)
    person = np.c_[np.outer(rr, np.cos(a)).ravel(), 1.6 + np.outer(rr, np.sin(a)).ravel()]
    person = np.c_[person, np.full(len(person), 0.5)]
    planning, safety = checkers(np.vstack([wall, person]))
    _, static = checkers(wall)
    goal, start = np.array([2.0, 0.0]), np.array([-2.0, 0.0])
    known = known_everywhere()
    cfg = CostMapConfig(margin_weight=1.0)
    closed = CostMap(cfg, safety, planning, goal, start, known)
    free_door = CostMap(cfg, static, planning, goal, start, known).cost_to_go(start)
    far_door = 2 * math.hypot(2.0, 4.0 + R + 0.03)  # the far door's exact detour
    assert closed.cost_to_go(start) >= far_door - 0.05
    w = 5.0
    soft = CostMap(cfg.replace(transient_weight=w), safety, planning, goal, start, known, static)
    c = soft.cost_to_go(start)
    disc = 2 * (0.2 + R + 0.03)
    assert free_door < c <= free_door + (w - 1) * disc + 0.3
    assert c < closed.cost_to_go(start)
    p = soft.path(start)
    k = np.flatnonzero(np.diff(np.sign(p[:, 0])) != 0)[0]
    assert 1.0 + R <= p[k, 1] <= 2.2 - R  # through the near door, past the person
    assert math.isfinite(soft.path_cost(p)) and soft.path_cost(p) >= c - 1e-6
    assert math.isinf(soft.path_cost(np.array([start, goal])))  # the wall is still a wall
    # the static model is ignored while transient_weight is 0 (off)
    off = CostMap(cfg, safety, planning, goal, start, known, static)
    assert off.cost_to_go(start) == pytest.approx(closed.cost_to_go(start))
    with pytest.raises(ConfigError, match="transient_weight"):
        CostMapConfig(transient_weight=0.5)
