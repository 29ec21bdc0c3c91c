"""Closed-loop behaviour of the default ``simn`` agent under realistic sensing: a trap episode
and determinism of the episode record."""

from __future__ import annotations

import numpy as np
import pytest

from simn_sim.agents.recovery import BumpDetector
from simn_sim.env.episodes import EpisodeSet
from simn_sim.env.noise import ActuationNoise, odometry_step
from simn_sim.env.office import load_layout
from simn_sim.env.office_config import EnvConfig
from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND
from simn_sim.env.traps import trap_info
from simn_sim.experiments.runner import run_episode
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.geometry.se3 import inv_T, planar_T
from simn_sim.paths import envs_dir
from simn_sim.semantics import OBSTACLE

# per-step timings differ between runs; everything else in the record must not
TIMING_FIELDS = {
    "wall_time_s",
    "plan_ms_median",
    "plan_ms_p95",
    "map_ms_median",
    "control_ms_median",
    "act_ms_mean",
    "act_ms_p95",
}


def _episode(eid: str):
    es = EpisodeSet.load(envs_dir() / "episodes" / "office_nav_v2.json")
    return {e.episode_id: e for e in es.episodes}[eid]


@pytest.mark.slow
@pytest.mark.parametrize("agent, eid", [("simn", "nav2-L4-009"), ("simn_points", "nav2-ref-009")])
def test_trap_episode_reaches_the_goal_within_1_5x_the_geodesic(agent, eid):
    """A trap episode of office_nav_v2 (the goal room's doorway is hidden from the start and the
    straight line at the goal ends farther from it: a closed region), realistic sensing,
    320x240. The default (the learned map) on nav2-L4-009 (1.19x in the main run of
    2026-12-02); the point store on nav2-ref-009 (1.12x). The learned map did not reach
    nav2-ref-009 in that run (a timeout), so the default is gated on another trap; it reaches it
    in every ``simn`` record of office_nav_v2 in docs/results/ (the current default's,
    bumpyaw02_52e6cf1: 1.05x, 1 collision event)."""
    ep = _episode(eid)
    layout = load_layout(ep.layout_seed)
    fs = FreeSpace2D(
        layout.footprints(ROBOT_Z_BAND), robot_radius=ROBOT_RADIUS, bounds=layout.bounds
    )
    info = trap_info(layout, fs, ep.start, ep.goal)
    assert info.is_trap, info
    rec = run_episode(
        "SimnOffice-v0", {"width": 320, "height": 240}, agent, {}, episode=ep.to_dict()
    )
    assert rec["error"] is None, rec["error"]
    assert rec["success"], rec
    assert rec["path_length_m"] <= 1.5 * rec["geodesic_distance_m"], rec


def test_same_seed_same_episode_record_under_realistic_sensing():
    """Two runs of one episode (D435i depth, odometry drift and actuation noise, the default
    sensing) give identical records apart from timings."""
    ep = _episode("nav2-ref-003").to_dict()
    cfg = {"width": 160, "height": 120, "max_episode_steps": 60}
    a, b = (run_episode("SimnOffice-v0", cfg, "simn", {}, episode=ep) for _ in range(2))
    assert a["error"] is None and b["error"] is None
    assert a["steps"] == 60
    for k in a:
        if k not in TIMING_FIELDS:
            assert a[k] == b[k], k


def _step(dx: float, dy: float, dyaw: float = 0.0) -> np.ndarray:
    return planar_T(dx, dy, dyaw)


def _free_drive_bumps(min_progress: float, episodes: int, steps: int, rel: float = 0.0) -> int:
    """Bumps a detector fires over free driving at 0.8 m/s under the env's realistic actuation
    noise (its own model: a per-episode gain error and an AR(1) error over 0.5 s), with a
    little sideways motion while turning."""
    rng = np.random.default_rng(0)
    noise = ActuationNoise(EnvConfig().actuation_noise, 0.1)
    fired = 0
    for _ in range(episodes):
        noise.reset(rng)
        det = BumpDetector(0.1, min_progress=min_progress, rel_progress=rel)
        for _ in range(steps):
            v, _w = noise.apply(0.8, 0.5, rng)
            fired += det.update(0.8, _step(0.1 * v, float(rng.uniform(-0.004, 0.004))))
    return fired


def test_bump_detector_ignores_actuation_noise_and_catches_sliding_contact():
    """Free driving under the env's realistic actuation noise is no bump at the default
    ``min_progress`` (the old 0.5 did fire on it); sliding along a box on the left (progress
    30-60 %, pushed right by 2.3-2.5 cm per step) is one, on the left."""
    assert EnvConfig().actuation_noise.model == "gaussian"  # the default is realistic
    assert _free_drive_bumps(0.3, 100, 300) == 0
    assert _free_drive_bumps(0.5, 100, 300) > 0
    hit = BumpDetector(0.1)
    fired = [hit.update(0.8, _step(0.08 * p, -s)) for p, s in ((0.8, 0.023), (0.6, 0.025))]
    assert fired == [False, True]
    assert 0 < hit.contact_angle < np.pi / 2  # left-front
    # a blocked step (progress 0.1, no slip) twice is a bump straight ahead
    blocked = BumpDetector(0.1)
    assert [blocked.update(0.5, _step(0.005, 0.0)) for _ in range(2)] == [False, True]
    assert blocked.contact_angle == pytest.approx(0.0)
    # a step commanded at standstill or backwards is never a contact sign
    still = BumpDetector(0.1)
    assert not any(still.update(0.0, _step(0.0, 0.0)) for _ in range(10))


def test_relative_progress_catches_a_drop_the_noise_does_not_make():
    """A turn past a low box after free driving (nav2-ref-009, replayed: progress 1.06 of the
    command, then 0.44 and 0.43 with little slip) is a bump with ``rel_progress`` 0.5 and none
    without; the env's actuation noise alone never fires it."""
    assert _free_drive_bumps(0.3, 100, 300, rel=0.5) == 0
    seq = [1.04, 1.17, 1.09, 1.12, 1.06, 0.44, 0.43]
    for rel, want in ((0.0, [False] * 7), (0.5, [False] * 6 + [True])):
        det = BumpDetector(0.1, rel_progress=rel)
        assert [det.update(0.7, _step(0.07 * p, -0.007)) for p in seq] == want


def _free_turning_bumps(yaw_tol: float, episodes: int, steps: int) -> int:
    """Bumps a detector with the turning test fires over free driving with turns: commands
    held for 10 steps at 0.2-0.8 m/s and -1.5 to 1.5 rad/s (the follower's limits), executed
    through the env's realistic actuation noise and read back through its wheel odometry (both
    the env's own models, seeded)."""
    rng = np.random.default_rng(1)
    cfg = EnvConfig()
    noise = ActuationNoise(cfg.actuation_noise, 0.1)
    fired = 0
    for _ in range(episodes):
        noise.reset(rng)
        det = BumpDetector(0.1, rel_progress=0.5, yaw_tol=yaw_tol)
        pose, odom = np.zeros(3), np.zeros(3)
        for k in range(steps):
            if k % 10 == 0:
                v_cmd, w_cmd = rng.uniform(0.2, 0.8), rng.uniform(-1.5, 1.5)
            v, w = noise.apply(v_cmd, w_cmd, rng)
            mid = pose[2] + 0.05 * w
            new = pose + np.array([0.1 * v * np.cos(mid), 0.1 * v * np.sin(mid), 0.1 * w])
            o = odometry_step(odom, pose, new, cfg.odom_noise_trans, cfg.odom_noise_rot, rng)
            fired += det.update(v_cmd, inv_T(planar_T(*odom)) @ planar_T(*o), w_cmd)
            pose, odom = new, o
    return fired


# dyn-L5-002, steps 231-239 (office_dynamic_v1 at 05bb03c): the command (v, w) and the wheel
# odometry's increment (dx, dy, dyaw) of each step; the base slides past a person standing at
# its left from the 5th step on (the env's contact flag), and the friction turns it left while
# it is commanded right
L5_002 = [
    (0.36, -0.86, 0.0427, -0.0010, -0.0805),
    (0.37, -0.59, 0.0369, -0.0010, -0.0737),
    (0.38, -0.48, 0.0365, -0.0007, -0.0526),
    (0.39, -0.41, 0.0378, -0.0006, -0.0429),
    (0.39, -0.35, 0.0298, -0.0030, -0.0012),
    (0.39, -0.33, 0.0299, -0.0058, 0.1024),
    (0.38, -0.45, 0.0299, -0.0071, 0.1209),
    (0.37, -0.59, 0.0325, -0.0095, 0.1320),
    (0.35, -0.68, 0.0342, -0.0121, 0.1438),
]


def test_turning_test_catches_a_person_dragging_the_base():
    """The replayed dyn-L5-002 contact is no bump for the progress tests (0.77 of the command,
    slip under 1.2 cm) and is one with the turning test at ``yaw_tol`` 0.2, two steps after
    the first contact, on the left (and again two steps later, the count restarted); free driving with turns under the env's actuation noise
    and odometry drift never fires it (nor at 0.1), while a tolerance with no margin does."""
    for tol, want in ((0.0, [False] * 9), (0.2, [False] * 6 + [True, False, True])):
        det = BumpDetector(0.1, rel_progress=0.5, yaw_tol=tol)
        got, angles = [], []
        for v, w, dx, dy, dth in L5_002:
            got.append(det.update(v, _step(dx, dy, dth), w))
            angles += [det.contact_angle] if got[-1] else []
        assert got == want
    # the first by the turning test alone (60 deg left), the second by the 1.21 cm slide
    # to the right as well (the bearing of the motion that did not happen: left)
    assert angles[0] == pytest.approx(np.radians(60.0))
    assert np.radians(60.0) < angles[1] < np.radians(90.0)
    assert _free_turning_bumps(0.2, 50, 300) == 0
    assert _free_turning_bumps(0.1, 50, 300) == 0
    assert _free_turning_bumps(0.01, 50, 300) > 0


# ---- map clearing: bumps expire, and a goal closed off on the map clears it ------------------
def _occupied(checker) -> set[tuple[int, int]]:
    res = checker.cfg.resolution
    return {tuple(c) for c in np.round(checker.occupied_centres()[:, :2] / res).astype(int)}


@pytest.fixture(scope="module")
def ideal_env():
    import gymnasium as gym

    e = gym.make("SimnOfficeIdeal-v0", config={"width": 160, "height": 120})
    yield e
    e.close()


def _ring(agent, centre_xy: np.ndarray, radius: float) -> None:
    """A closed ring of bump arcs (9 arcs of 80 deg) of ``radius`` around ``centre_xy``."""
    T = np.eye(4)
    T[:2, 3] = centre_xy
    for a in np.radians(np.arange(0, 360, 40)):
        agent.obstacles.add_bump(T, radius - 0.03, float(a))


def test_bump_points_leave_the_map_after_bump_ttl_views(ideal_env):
    from simn_sim.agents import make_agent
    from simn_sim.planning import CollisionChecker

    obs, info = ideal_env.reset(seed=0)
    cfg = {"initial_scan_deg": 0.0, "obstacles": {"bump_ttl": 4, "rebuild_every": 1}}
    agent = make_agent("simn", ideal_env.unwrapped, cfg)
    agent.reset(obs, info)
    obs, *_ = ideal_env.step(agent.act(obs))
    agent.obstacles.add_bump(agent.world.pose, 0.25, 0.0)
    arc = agent.obstacles.bump_points[0]
    for k in range(6):
        obs, *_ = ideal_env.step(np.zeros(2, np.float32))  # the robot stays: the same map
        agent.act(obs)
        # the planning model is exactly the local frames' obstacle points plus live bumps
        ref = CollisionChecker(agent.obstacles.planning.cfg)
        pts = agent.world.frames.obstacle_points_world()
        live = agent.obstacles.bump_points
        allp = np.concatenate([pts, *live]) if live else pts
        ref.update(allp, np.full(len(allp), OBSTACLE, np.int8))
        assert _occupied(agent.obstacles.planning) == _occupied(ref)
        assert (len(live) == 1) == (k < 4), f"view {k} after the bump: {len(live)} bumps"
    assert len(agent.obstacles.bump_points) == 0
    free_of_walls = agent.obstacles.planning.clearance(arc[:, :2]) > 0.0
    assert free_of_walls.all()  # nothing else occupies the arc: it left the map


def test_goal_closed_off_on_the_map_clears_it_and_a_route_follows(ideal_env):
    """A ring of bump points around the goal closes it off (no route under the safety margin);
    after ``clear_after`` steps without a route the agent clears the map (bumps and the local
    frames before the current one leave the obstacle model) and plans a route again."""
    from simn_sim.agents import make_agent

    obs, info = ideal_env.reset(seed=0)
    cfg = {"initial_scan_deg": 0.0, "clear_after": 5, "obstacles": {"bump_ttl": 0}}
    agent = make_agent("simn", ideal_env.unwrapped, cfg)
    agent.reset(obs, info)
    obs, *_ = ideal_env.step(agent.act(obs))
    assert agent.path is not None  # the goal is reachable on the map
    _ring(agent, agent.goal, 0.6)
    agent.path = None
    states = []
    for _ in range(5):
        obs, *_ = ideal_env.step(agent.act(obs))
        states.append(agent.state())
    assert states == ["no_plan"] * 5 and agent.counters()["map_clears"] == 1
    assert agent.obstacles.bump_points == []
    assert agent.obstacles.min_frame == agent.world.frames.current_id
    # it looks all the way round, then plans: a route to the goal exists again
    for _ in range(agent._full_scan_steps + 2):
        obs, *_ = ideal_env.step(agent.act(obs))
    assert agent.path is not None and agent.state() == "following"
    assert np.hypot(*(agent.path[-1] - agent.goal)) < 0.2


def test_map_clearing_config_is_validated(ideal_env):
    from simn_sim.agents import make_agent
    from simn_sim.config import ConfigError

    with pytest.raises(ConfigError, match="clear_after"):
        make_agent("simn", ideal_env.unwrapped, {"clear_after": -1})
    with pytest.raises(ConfigError, match="bump_ttl"):
        make_agent("simn", ideal_env.unwrapped, {"obstacles": {"bump_ttl": -2}})
    for bad in (0.0, 1.0, float("nan")):
        with pytest.raises(ConfigError, match="bump_min_progress"):
            make_agent("simn", ideal_env.unwrapped, {"bump_min_progress": bad})
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ConfigError, match="bump_rel_progress"):
            make_agent("simn", ideal_env.unwrapped, {"bump_rel_progress": bad})
    for bad in (-0.1, float("nan")):
        with pytest.raises(ConfigError, match="bump_yaw_tol"):
            make_agent("simn", ideal_env.unwrapped, {"bump_yaw_tol": bad})


def test_a_plan_the_follower_refuses_is_no_route_not_a_standstill(ideal_env, monkeypatch):
    """With ``refused_plan_no_route``: when the follower refuses even the fresh plan (its next
    metre cuts the safety model: on nav2-L1-005 a cost-map route squeezed diagonally between
    two blocked cells and the robot stood still for 369 steps), the agent looks around like
    with no route and clears the map after ``clear_after`` such steps, instead of commanding
    zero velocity."""
    from simn_sim.agents import make_agent
    from simn_sim.planning.follower import FollowerCommand, PathFollower

    obs, info = ideal_env.reset(seed=0)
    cfg = {
        "initial_scan_deg": 0.0,
        "clear_after": 5,
        "obstacles": {"bump_ttl": 0},
        "refused_plan_no_route": True,
    }
    agent = make_agent("simn", ideal_env.unwrapped, cfg)
    agent.reset(obs, info)
    obs, *_ = ideal_env.step(agent.act(obs))
    assert agent.path is not None and agent.state() == "following"

    def refuse(self, pose):
        return FollowerCommand(0.0, 0.0, "blocked", np.asarray(pose[:2]), 0.0, 1.0)

    monkeypatch.setattr(PathFollower, "step", refuse)
    actions = []
    for _ in range(5):
        a = agent.act(obs)
        actions.append(a)
        obs, *_ = ideal_env.step(a)
    assert all(a[0] == 0.0 and a[1] > 0.5 for a in actions)  # turning in place, not standing
    assert agent.counters()["map_clears"] == 1
