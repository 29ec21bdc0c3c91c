"""Goal-vector and uniform RRT*: collision-free, near-shortest, ray sampling, rewiring, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.config import ConfigError
from simn_sim.planning import (
    CollisionChecker,
    GoalVectorConfig,
    GoalVectorSampler,
    RRTStarConfig,
    goal_vector_rrt_star,
    path_length,
    sample_goal_vector,
    shortcut_path,
    uniform_rrt_star,
)
from simn_sim.planning.synthetic_maps import box_field_map, doorway_map, u_trap_map
from simn_sim.planning.tree import NodeIndex, Tree

# Deterministic iteration budgets (no wall-clock budget, so results do not depend on the machine).
CFG = RRTStarConfig(time_budget_ms=0.0, max_iterations=2500, step_size=0.5, rewire_radius=1.0)
LENGTH_FACTOR = 1.10  # smoothed path length vs the exact shortest path (measured: 1.004-1.014)


def checker_for(m) -> CollisionChecker:
    c = CollisionChecker()
    c.update(m.points, m.labels)
    return c


@pytest.fixture(scope="module")
def doorway():
    m = doorway_map(door_width=1.0)
    return m, checker_for(m)


def around_corner_length(p, corner, q, r) -> float:
    """Exact length of the shortest path p -> q wrapping around a disk (corner, r) that blocks
    the straight line: two tangents plus the arc between the tangent points."""
    p, corner, q = (np.asarray(v, float) for v in (p, corner, q))
    d1, d2 = np.hypot(*(p - corner)), np.hypot(*(q - corner))
    a1, a2 = p - corner, q - corner
    between = math.acos(np.dot(a1, a2) / (d1 * d2))  # angle on the side the line crosses
    arc = (2 * math.pi - between) - math.acos(r / d1) - math.acos(r / d2)
    return math.sqrt(d1**2 - r**2) + math.sqrt(d2**2 - r**2) + r * arc


def exact_reference(m, c: CollisionChecker, start, goal) -> float:
    fs_mod = pytest.importorskip("simn_sim.geometry.freespace")
    fs = fs_mod.FreeSpace2D(m.footprints, robot_radius=c.cfg.inflation, bounds=m.bounds)
    d = fs.geodesic_distance(np.asarray(start, float), np.asarray(goal, float))
    assert math.isfinite(d)
    return d


def make(kind: str, c: CollisionChecker, bounds, seed: int, cfg: RRTStarConfig = CFG):
    rng = np.random.default_rng(seed)
    if kind == "goal_vector":
        return goal_vector_rrt_star(c, cfg, GoalVectorConfig(), bounds=bounds, rng=rng)
    return uniform_rrt_star(c, bounds, cfg, rng=rng)


@pytest.mark.parametrize("kind", ["goal_vector", "uniform"])
def test_doorway_plan_is_free_and_near_exact(doorway, kind: str) -> None:
    m, c = doorway
    start, goal = np.array([2.0, 2.0]), np.array([8.0, 2.0])
    # analytic: wrap around the top of the lower wall's end (5, 3.5), inflated by r
    exact = around_corner_length(start, (5.0, 3.5), goal, c.cfg.inflation)
    planner = make(kind, c, m.bounds, seed=1)
    path = planner.plan(start, goal)
    assert path is not None
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], goal)
    assert c.path_free(path) and c.path_free(planner.raw_path)
    L = path_length(path)
    # the checker quantises obstacles to 5 cm cells: it may be a few cm more permissive
    assert exact - 0.1 <= L <= LENGTH_FACTOR * exact
    assert planner.stats.smoothed_cost == pytest.approx(L)
    assert planner.stats.cost >= L - 1e-9  # smoothing never lengthens
    assert planner.stats.first_solution_time_s is not None
    assert planner.stats.first_solution_iteration <= planner.stats.iterations


@pytest.mark.parametrize("kind", ["goal_vector", "uniform"])
@pytest.mark.parametrize("which", ["u_trap", "box_field"])
def test_plans_free_and_within_factor_of_freespace(kind: str, which: str) -> None:
    if which == "u_trap":
        m = u_trap_map()
        start, goal = np.array([5.0, 3.0]), np.array([8.0, 3.0])  # inside the U, goal behind it
    else:
        m = box_field_map(np.random.default_rng(7))
        start, goal = np.array([0.8, 1.0]), np.array([9.2, 7.0])
    c = checker_for(m)
    exact = exact_reference(m, c, start, goal)
    planner = make(kind, c, m.bounds, seed=3, cfg=CFG.replace(max_iterations=4000))
    path = planner.plan(start, goal)
    assert path is not None, planner.stats
    assert c.path_free(path)
    assert exact - 0.1 <= path_length(path) <= LENGTH_FACTOR * exact


def test_goal_vector_samples_lie_on_rays() -> None:
    cfg = GoalVectorConfig(n_rays=3, alpha_deg=20.0, angular_spread_deg=4.0, lateral_spread=0.2)
    start, goal = np.array([1.0, -2.0]), np.array([4.0, 2.0])
    s = sample_goal_vector(np.random.default_rng(0), start, goal, cfg, 5000)
    theta0 = math.atan2(*(goal - start)[::-1])
    t_max = max(cfg.min_range, cfg.range_scale * np.hypot(*(goal - start)))
    assert set(np.unique(s.ray)) == set(range(-3, 4))
    nominal = theta0 + s.ray * math.radians(cfg.alpha_deg)
    u = np.stack([np.cos(nominal), np.sin(nominal)], axis=1)
    v = s.xy - start
    along = np.einsum("ij,ij->i", v, u)
    perp = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    # distance from the nominal ray <= lateral spread + t * sin(angular spread)
    bound = cfg.lateral_spread + s.t * math.sin(math.radians(cfg.angular_spread_deg))
    assert np.all(perp <= bound + 1e-9)
    assert np.all(along >= -cfg.lateral_spread - 1e-9)
    assert np.all(along <= t_max + cfg.lateral_spread + 1e-9)
    assert np.all((s.t >= 0) & (s.t <= t_max))
    # the goal ray is drawn most often, with the configured weight
    w = cfg.ray_decay ** np.abs(cfg.ray_offsets())
    assert np.mean(s.ray == 0) == pytest.approx(w[0] / w.sum(), abs=0.03)


def test_sampler_tree_anchors_and_uniform_window() -> None:
    cfg = GoalVectorConfig(
        tree_anchor_fraction=0.5,
        frontier_anchor_fraction=0.0,
        adaptive_rays=False,
        uniform_fraction=0.2,
        uniform_margin=1.0,
        window_stall=0,  # fixed window (the tree below never gets nearer the goal)
    )
    start, goal = np.array([0.0, 0.0]), np.array([5.0, 0.0])
    smp = GoalVectorSampler(cfg, record=True)
    smp.reset(start, goal, np.random.default_rng(1))
    tree = Tree(start)
    for x in np.random.default_rng(2).uniform(-1, 3, size=(30, 2)):
        tree.add(x, 0, float(np.hypot(*(x - start))))
    xs = np.array([smp.sample(tree) for _ in range(2000)])
    kinds = np.array([rec[1] for rec in smp.log])
    uni = kinds == GoalVectorSampler.UNIFORM_RAY
    assert 0.15 < uni.mean() < 0.25
    assert np.all((xs[uni] >= [-1, -1]) & (xs[uni] <= [6, 1]))  # window: bbox +- margin
    from_tree = 0
    ray_log = [r for r, u in zip(smp.log, uni, strict=True) if not u]
    for x, (anchor, k, t, lat, dth) in zip(xs[~uni], ray_log, strict=True):
        is_start = np.allclose(anchor, start)
        from_tree += not is_start
        assert is_start or np.any(np.all(np.isclose(tree.xy, anchor), axis=1))
        th = math.atan2(*(goal - anchor)[::-1]) + k * math.radians(cfg.alpha_deg) + dth
        expect = anchor + t * np.array([math.cos(th), math.sin(th)])
        expect += lat * np.array([-math.sin(th), math.cos(th)])
        np.testing.assert_allclose(x, expect, atol=1e-9)
        assert abs(dth) <= math.radians(cfg.angular_spread_deg) + 1e-12
        assert abs(lat) <= cfg.lateral_spread + 1e-12
    assert 0.4 < from_tree / (~uni).sum() < 0.6


def test_uniform_window_grows_while_the_tree_stalls_and_resets_on_progress() -> None:
    cfg = GoalVectorConfig(
        uniform_fraction=0.1, uniform_margin=1.0, window_stall=50, stall_uniform_fraction=0.4
    )
    start, goal = np.array([10.0, 10.0]), np.array([15.0, 10.0])
    bounds = (0.0, 0.0, 30.0, 20.0)
    smp = GoalVectorSampler(cfg, bounds=bounds, record=True)
    smp.reset(start, goal, np.random.default_rng(1))
    tree = Tree(start)

    def draw(n: int) -> tuple[np.ndarray, np.ndarray]:
        k0 = len(smp.log)
        xs = np.array([smp.sample(tree) for _ in range(n)])
        uni = np.array([r[1] == GoalVectorSampler.UNIFORM_RAY for r in smp.log[k0:]])
        return xs, uni

    xs, uni = draw(50)  # no progress yet, but not for window_stall samples: local window
    assert smp.stall < 50 and np.all((xs[uni] >= [9.0, 9.0]) & (xs[uni] <= [16.0, 11.0])), (
        "uniform samples outside the local window before the stall"
    )
    xs, uni = draw(3000)  # stalled: wider window (up to the bounds), more uniform samples
    assert 0.33 < uni.mean() < 0.47
    assert np.all((xs[uni] >= [0.0, 0.0]) & (xs[uni] <= [30.0, 20.0]))
    assert xs[uni][:, 0].min() < 2.0 and xs[uni][:, 1].max() > 18.0
    # progress (a node nearer the goal) resets the stall and the window
    tree.add(np.array([12.0, 10.0]), 0, 2.0)
    xs, uni = draw(40)
    assert smp.stall < 40
    assert np.all((xs[uni] >= [9.0, 9.0]) & (xs[uni] <= [16.0, 11.0]))


def test_rewiring_never_increases_any_cost(doorway, monkeypatch) -> None:
    m, c = doorway
    calls = {"n": 0}
    original = Tree.rewire

    def checked(self: Tree, child: int, new_parent: int, edge_cost: float) -> None:
        before = self.cost.copy()
        original(self, child, new_parent, edge_cost)
        after = self.cost
        assert np.all(after <= before + 1e-12), "a rewire increased a cost"
        assert after[child] < before[child]
        calls["n"] += 1

    monkeypatch.setattr(Tree, "rewire", checked)
    planner = make("goal_vector", c, m.bounds, seed=5, cfg=CFG.replace(max_iterations=1500))
    assert planner.plan([2.0, 2.0], [8.0, 2.0]) is not None
    assert calls["n"] > 50 and calls["n"] == planner.stats.n_rewires
    tree = planner.tree
    np.testing.assert_allclose(tree.cost, tree.recomputed_costs(), atol=1e-9)
    nonroot = np.arange(1, len(tree))
    assert np.all(tree.cost[nonroot] > tree.cost[tree.parent[nonroot]])
    # every tree edge is collision-free
    assert c.segments_free(tree.xy[tree.parent[nonroot]], tree.xy[nonroot]).all()


@pytest.mark.parametrize("kind", ["goal_vector", "uniform"])
def test_same_seed_same_plan(doorway, kind: str) -> None:
    m, c = doorway
    cfg = CFG.replace(max_iterations=800)
    a = make(kind, c, m.bounds, seed=11, cfg=cfg)
    b = make(kind, c, m.bounds, seed=11, cfg=cfg)
    pa, pb = a.plan([2.0, 2.0], [8.0, 2.0]), b.plan([2.0, 2.0], [8.0, 2.0])
    np.testing.assert_array_equal(pa, pb)
    np.testing.assert_array_equal(a.tree.xy, b.tree.xy)
    np.testing.assert_array_equal(a.tree.parent, b.tree.parent)
    other = make(kind, c, m.bounds, seed=12, cfg=cfg)
    other.plan([2.0, 2.0], [8.0, 2.0])
    assert len(other.tree) != len(a.tree) or not np.array_equal(other.tree.xy, a.tree.xy)


def test_bad_inputs_raise(doorway) -> None:
    m, c = doorway
    p = make("goal_vector", c, m.bounds, seed=0)
    with pytest.raises(ValueError, match="start.*finite"):
        p.plan([np.nan, 1.0], [8.0, 2.0])
    with pytest.raises(ValueError, match="start .* in collision"):
        p.plan([5.0, 1.0], [8.0, 2.0])
    with pytest.raises(ValueError, match="goal .* in collision"):
        p.plan([2.0, 2.0], [5.05, 2.0])
    with pytest.raises(ValueError, match="x-y pair"):
        p.plan([2.0, 2.0, 0.0], [8.0, 2.0])
    with pytest.raises(ValueError, match="bounds"):
        uniform_rrt_star(c, (0.0, 0.0, -1.0, 5.0))
    for kw in (
        dict(step_size=0.0),
        dict(step_size=1.0, rewire_radius=0.5),
        dict(goal_bias=1.0),
        dict(max_iterations=0),
        dict(time_budget_ms=float("nan")),
    ):
        with pytest.raises(ConfigError):
            RRTStarConfig(**kw)
    for kw in (
        dict(alpha_deg=0.0),
        dict(n_rays=-1),
        dict(ray_decay=0.0),
        dict(uniform_fraction=1.0),
        dict(tree_anchor_fraction=1.5),
    ):
        with pytest.raises(ConfigError):
            GoalVectorConfig(**kw)
    with pytest.raises(ConfigError, match="unknown"):
        RRTStarConfig.from_dict({"stepsize": 0.5})


def test_unreachable_goal_returns_none() -> None:
    m = doorway_map(door_width=0.3)  # narrower than the robot (2 * 0.25 m)
    c = checker_for(m)
    p = make("goal_vector", c, m.bounds, seed=0, cfg=CFG.replace(max_iterations=600))
    assert p.plan([2.0, 2.0], [8.0, 2.0]) is None
    assert p.path is None and p.stats.first_solution_time_s is None
    assert p.stats.iterations == 600 and len(p.tree) > 10


def test_shortcut_shortens_and_stays_free(doorway) -> None:
    m, c = doorway
    p = make("uniform", c, m.bounds, seed=4, cfg=CFG.replace(max_iterations=400, shortcut=False))
    raw = p.plan([2.0, 2.0], [8.0, 2.0])
    assert raw is not None
    sm = shortcut_path(raw, c, np.random.default_rng(0), iterations=100)
    assert c.path_free(sm)
    assert path_length(sm) <= path_length(raw) + 1e-9
    np.testing.assert_allclose(sm[[0, -1]], raw[[0, -1]])


def test_node_index_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, size=(3000, 2))
    store = np.zeros((4096, 2))
    idx = NodeIndex()
    idx.reset(store)
    for n, p in enumerate(pts, start=1):
        store[n - 1] = p
        idx.add(store, n)
        if n in (1, 7, 70, 500, 3000):
            for q in rng.uniform(-7, 7, size=(20, 2)):
                d = np.hypot(*(pts[:n] - q).T)
                i, di = idx.nearest(q)
                assert di == pytest.approx(d.min()) and d[i] == pytest.approx(d.min())
                got = np.sort(idx.within(q, 1.3))
                np.testing.assert_array_equal(got, np.nonzero(d <= 1.3)[0])
    assert 3 < idx.rebuilds < 40  # log-structured: geometric rebuilds


def test_tree_near_dist_and_mirrors_match_brute_force() -> None:
    """Tree.near_dist (3 x 3 cells; arrays in dense parts; the spatial index for radii beyond
    the cell) equals brute force, and the Python mirrors of positions and costs equal the
    arrays after rewires."""
    rng = np.random.default_rng(3)
    tree = Tree(np.zeros(2), capacity=8, cell_size=1.0)
    for n in range(1, 1500):
        # a dense cluster near the origin, sparse elsewhere
        p = rng.normal(scale=0.4, size=2) if n % 3 else rng.uniform(-8, 8, size=2)
        j = int(rng.integers(n))
        tree.add(p, j, float(np.hypot(*(p - tree.xy[j]))))
        if n in (1, 5, 60, 400, 1499):
            for q in np.vstack([rng.uniform(-8, 8, size=(15, 2)), rng.normal(0, 0.3, (5, 2))]):
                d = np.hypot(*(tree.xy - q).T)
                for radius in (0.7, 1.0, 2.5):
                    idx, dist = tree.near_dist(float(q[0]), float(q[1]), radius)
                    np.testing.assert_array_equal(np.asarray(idx), np.nonzero(d <= radius)[0])
                    np.testing.assert_allclose(np.asarray(dist), d[d <= radius], atol=1e-12)
    assert isinstance(tree.near_dist(0.0, 0.0, 1.0)[0], np.ndarray)  # the dense cluster
    assert isinstance(tree.near_dist(7.9, -7.9, 1.0)[0], list)  # sparse
    for _ in range(200):  # rewire to a cheaper parent (no cycles: a lower index)
        child = int(rng.integers(2, len(tree)))
        new_parent = int(rng.integers(child))
        sub, k = {child}, [child]
        while k:
            k = [c for i in k for c in tree.children[i]]
            sub.update(k)
        e = float(np.hypot(*(tree.xy[child] - tree.xy[new_parent])))
        if new_parent not in sub and tree.cost[new_parent] + e < tree.cost[child]:
            tree.rewire(child, new_parent, e)
    assert tree.n_rewires > 10
    np.testing.assert_array_equal(np.array(tree.costs), tree.cost)
    np.testing.assert_array_equal(np.column_stack([tree.xs, tree.ys]), tree.xy)
    np.testing.assert_allclose(tree.cost, tree.recomputed_costs(), atol=1e-9)


def test_adaptive_rays_widen_per_anchor_on_stall_and_reset_on_progress() -> None:
    cfg = GoalVectorConfig(
        n_rays=4,
        adaptive_rays=True,
        initial_rays=1,
        stall_samples=10,
        progress_min=0.05,
        uniform_fraction=0.0,
        tree_anchor_fraction=0.0,
        frontier_anchor_fraction=1.0,
    )
    start, goal = np.array([0.0, 0.0]), np.array([6.0, 0.0])
    smp = GoalVectorSampler(cfg, record=True)
    smp.reset(start, goal, np.random.default_rng(0))
    tree = Tree(start)
    levels = []
    for _ in range(60):  # the tree never grows: every sample from the start is fruitless
        smp.sample(tree)
        levels.append(smp.level)
    # sample i sees i fruitless samples before it: level 1 + i // 10, capped at n_rays
    assert levels == [min(4, 1 + i // 10) for i in range(60)]
    assert smp.visits == [59]  # the 60th sample is judged at the next call
    rays = np.array([rec[1] for rec in smp.log])
    assert np.all(np.abs(rays[:10]) <= 1) and np.any(np.abs(rays[30:]) >= 3)
    # progress: a new node nearer the goal than the anchor; it is the fresh frontier
    tree.add(np.array([1.0, 0.0]), 0, 1.0)
    smp.sample(tree)
    assert smp.visits == [59, 0]  # the anchor of the last sample was not charged
    assert smp.anchor_index == 1 and smp.level == 1
    assert smp.best_index == 1 and smp.best_distance == pytest.approx(5.0)
    np.testing.assert_allclose(smp.log[-1][0], [1.0, 0.0])
    # a node that does not get closer (sideways) charges the anchor a visit
    tree.add(np.array([1.0, 0.5]), 1, 0.5)
    smp.sample(tree)
    assert smp.visits[1] == 1 and smp.h[2] == pytest.approx(math.hypot(5.0, 0.5))


def test_best_first_frontier_hands_over_from_a_blocked_node() -> None:
    """The frontier is argmin h + visit_penalty * visits: a node nearest the goal that keeps
    failing hands over to the next one once its penalty exceeds the distance difference."""
    cfg = GoalVectorConfig(
        uniform_fraction=0.0,
        tree_anchor_fraction=0.0,
        frontier_anchor_fraction=1.0,
        visit_penalty=0.1,
        stall_samples=2,
    )
    start, goal = np.array([0.0, 0.0]), np.array([10.0, 0.0])
    tree = Tree(start)
    tree.add(np.array([5.0, 0.0]), 0, 5.0)  # h = 5 (stuck behind a wall, say)
    tree.add(np.array([4.0, 3.0]), 0, 5.0)  # h = sqrt(45) = 6.708
    smp = GoalVectorSampler(cfg, record=True)
    smp.reset(start, goal, np.random.default_rng(3))
    anchors = []
    for _ in range(40):  # the tree never grows: every sample is fruitless
        smp.sample(tree)
        anchors.append(smp.anchor_index)
    h1, h2 = 5.0, math.hypot(6.0, 3.0)
    n1 = math.ceil((h2 - h1) / cfg.visit_penalty)  # fruitless samples until node 2 takes over
    assert anchors[:n1] == [1] * n1 and anchors[n1] == 2
    assert set(anchors) == {1, 2}  # the start (h = 10) is never the frontier here
    # from then on the two alternate so that their scores stay within one penalty step
    s1 = h1 + cfg.visit_penalty * smp.visits[1]
    s2 = h2 + cfg.visit_penalty * smp.visits[2]
    assert abs(s1 - s2) <= cfg.visit_penalty + 1e-9
    # every ray sample lies on its anchor's ray k within the jitter, and the fan of each
    # anchor is the one its visits allow
    visits_before = {1: 0, 2: 0}
    for rec, a in zip(smp.log, anchors, strict=True):
        anchor, k, t, lat, dth = rec
        np.testing.assert_allclose(anchor, tree.xy[a])
        assert abs(k) <= min(cfg.n_rays, cfg.initial_rays + visits_before[a] // cfg.stall_samples)
        visits_before[a] += 1
    # visit_penalty = 0: always the node nearest the goal
    smp0 = GoalVectorSampler(cfg.replace(visit_penalty=0.0))
    smp0.reset(start, goal, np.random.default_rng(3))
    for _ in range(40):
        smp0.sample(tree)
        assert smp0.anchor_index == 1


def test_goal_vector_sampler_is_deterministic_per_generator() -> None:
    start, goal = np.array([0.0, 0.0]), np.array([6.0, 2.0])

    def draw(seed: int) -> np.ndarray:
        smp = GoalVectorSampler(GoalVectorConfig(), bounds=(-5.0, -5.0, 12.0, 8.0))
        smp.reset(start, goal, np.random.default_rng(seed))
        tree = Tree(start)
        out = []
        for i in range(700):  # crosses several batch refills (16, 32, ..., 256)
            x = smp.sample(tree)
            out.append(x)
            if i % 3 == 0:  # grow the tree a little, deterministically
                tree.add(0.5 * (x + tree.xy[i % tree.n]), i % tree.n, 0.1)
        return np.array(out)

    a, b, c = draw(5), draw(5), draw(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.all(np.isfinite(a))
    # reset() restarts the stream state (same generator seed -> same samples)
    smp = GoalVectorSampler(GoalVectorConfig())
    smp.reset(start, goal, np.random.default_rng(1))
    first = [smp.sample(Tree(start)).copy() for _ in range(5)]
    smp.reset(start, goal, np.random.default_rng(1))
    again = [smp.sample(Tree(start)).copy() for _ in range(5)]
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize(
    "field, value",
    [
        ("visit_penalty", -0.1),
        ("visit_penalty", float("nan")),
        ("stall_samples", 0),
        ("initial_rays", 7),
        ("progress_min", -1.0),
        ("open_step", 0.0),
        ("open_step", float("inf")),
        ("open_initial_rays", 7),
        ("open_visits", -1),
        ("ray_overshoot", -0.5),
        ("ray_overshoot", float("nan")),
        ("window_stall", -1),
        ("stall_uniform_fraction", 1.0),
        ("stall_uniform_fraction", -0.1),
    ],
)
def test_goal_vector_config_errors_name_the_field(field: str, value) -> None:
    with pytest.raises(ConfigError, match=field):
        GoalVectorConfig(**{field: value})


# Checker-aware sampling: from (4.4, 1.5) beside the doorway map's wall (x = 5, inflated to
# x >= 4.75), rays towards the goal at 0 and +-30 deg hit the wall within 0.5 m (end points at
# x = 4.9, 4.83), while +-60 deg (x = 4.65) and wider are open by at least two grid cells.
WALL_START, WALL_GOAL = np.array([4.4, 1.5]), np.array([6.0, 1.5])
OPEN_CFG = GoalVectorConfig(
    alpha_deg=30.0,
    open_rays=True,
    open_visits=10**6,
    stall_samples=20,
    uniform_fraction=0.0,
    window_stall=0,  # ray samples only, however long the start's samples keep failing
)


def first_step_free(c: CollisionChecker, anchor, goal, k: int, alpha_deg: float, step: float):
    th = math.atan2(goal[1] - anchor[1], goal[0] - anchor[0]) + math.radians(k * alpha_deg)
    return c.segment_free(anchor, anchor + step * np.array([math.cos(th), math.sin(th)]))


def test_open_rays_skip_rays_whose_first_step_is_blocked(doorway) -> None:
    _, c = doorway
    free = {k: first_step_free(c, WALL_START, WALL_GOAL, k, 30.0, 0.5) for k in range(-6, 7)}
    assert not free[0] and not free[1] and not free[-1]  # the goal ray and +-1 are blocked
    assert free[2] and free[-2]
    smp = GoalVectorSampler(OPEN_CFG, checker=c, record=True)
    smp.reset(WALL_START, WALL_GOAL, np.random.default_rng(3))
    rays = []
    for _ in range(400):
        smp.sample(None)  # no tree: every sample is cast from the start and fails
        rays.append(smp.log[-1][1])
    assert all(free[k] for k in rays)
    # the fan starts at the open ray nearest the goal direction (-2 is tested before +2) ...
    assert set(rays[:20]) == {-2}
    # ... and widens over the open rays only as the start's samples keep failing
    assert {2, -3, 3} <= set(rays)
    # samples reach at most ray_overshoot beyond each ray's free extent
    smp2 = GoalVectorSampler(OPEN_CFG.replace(ray_overshoot=0.3), checker=c, record=True)
    smp2.reset(WALL_START, WALL_GOAL, np.random.default_rng(4))
    for _ in range(200):
        smp2.sample(None)
    pos, ext, _ = smp2._rays[0]
    extent = {smp2._ks[p]: e for p, e in zip(pos, ext, strict=True)}
    for _, k, t, _, _ in smp2.log:
        assert t <= extent[k] + 0.3 + 1e-9
    # without a checker (or with open_rays=False) the same sampler draws the blocked rays
    blind = GoalVectorSampler(OPEN_CFG, record=True)
    blind.reset(WALL_START, WALL_GOAL, np.random.default_rng(3))
    for _ in range(400):
        blind.sample(None)
    assert {0, 1, -1} <= {r[1] for r in blind.log}


def test_open_rays_from_a_growing_tree_and_planner(doorway) -> None:
    m, c = doorway
    start, goal = np.array([2.0, 1.5]), np.array([8.0, 1.5])  # goal behind the wall

    def draw(seed: int) -> np.ndarray:
        smp = GoalVectorSampler(OPEN_CFG.replace(open_visits=4), bounds=m.bounds, checker=c)
        smp.reset(start, goal, np.random.default_rng(seed))
        tree = Tree(start)
        out = []
        for i in range(600):
            x = smp.sample(tree)
            out.append(x)
            if i % 3 == 0:
                y = 0.5 * (x + tree.xy[i % tree.n])
                if c.segment_free(tree.xy[i % tree.n], y):
                    tree.add(y, i % tree.n, 0.1)
        return np.array(out)

    a, b, d = draw(5), draw(5), draw(6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, d)
    cfg = CFG.replace(stop_at_first_solution=True, max_iterations=4000)
    gv = GoalVectorConfig(open_rays=True)
    p = goal_vector_rrt_star(c, cfg, gv, bounds=m.bounds, rng=np.random.default_rng(0))
    assert p.sampler.checker is c
    path = p.plan(start, goal)
    assert path is not None and c.path_free(path)
    assert p.sampler.n_ray_tests > 0
    q = goal_vector_rrt_star(c, cfg, gv, bounds=m.bounds, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(q.plan(start, goal), path)
    np.testing.assert_array_equal(q.tree.xy[: q.tree.n], p.tree.xy[: p.tree.n])
