"""RRT*'s anytime interface: a plan grown over several control steps (begin / iterate / finish)
is the same plan as one ``plan()`` call with the same rng."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.planning import (
    CollisionChecker,
    GoalVectorConfig,
    RRTStarConfig,
    goal_vector_rrt_star,
    uniform_rrt_star,
)
from simn_sim.planning.synthetic_maps import doorway_map

CFG = RRTStarConfig(time_budget_ms=0.0, max_iterations=600)


@pytest.fixture(scope="module")
def doorway():
    m = doorway_map(door_width=1.0)
    c = CollisionChecker()
    c.update(m.points, m.labels)
    return m, c


def _planner(kind, c, bounds, seed):
    rng = np.random.default_rng(seed)
    if kind == "goal_vector":
        return goal_vector_rrt_star(c, CFG, GoalVectorConfig(), bounds=bounds, rng=rng)
    return uniform_rrt_star(c, bounds, CFG, rng=rng)


@pytest.mark.parametrize("kind", ["goal_vector", "uniform"])
def test_sliced_plan_equals_one_call(doorway, kind) -> None:
    m, c = doorway
    start, goal = np.array([2.0, 2.0]), np.array([8.0, 2.5])
    one = _planner(kind, c, m.bounds, 7)
    path_one = one.plan(start, goal)
    assert path_one is not None and c.path_free(path_one)
    sliced = _planner(kind, c, m.bounds, 7)
    sliced.begin(start, goal)
    steps = 0
    while not sliced.iterate(150):
        steps += 1
    assert steps == 3  # 600 iterations in slices of 150: done on the fourth call
    path_sliced = sliced.finish()
    np.testing.assert_array_equal(path_sliced, path_one)
    np.testing.assert_array_equal(sliced.tree.xy[: len(sliced.tree)], one.tree.xy[: len(one.tree)])
    assert sliced.stats.iterations == one.stats.iterations == 600
    assert sliced.stats.first_solution_iteration == one.stats.first_solution_iteration


def test_iterate_before_begin_raises(doorway) -> None:
    m, c = doorway
    p = _planner("uniform", c, m.bounds, 0)
    with pytest.raises(RuntimeError, match="begin"):
        p.iterate(10)
    with pytest.raises(RuntimeError, match="begin"):
        p.finish()
