"""simn agent pieces that can be checked exactly: free-space carving, the world models' planner
interface, shadows, config errors."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import simn_sim  # noqa: F401
from simn_sim.agents import make_agent
from simn_sim.agents.simn_config import SimnAgentConfig
from simn_sim.config import ConfigError
from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.planning import CollisionChecker
from simn_sim.world import OdometryWorld, SlamWorld
from simn_sim.world.transient import TransientConfig


@pytest.fixture(scope="module")
def env():
    # ideal sensing: the checks below compare against exact depth and poses
    e = gym.make("SimnOfficeIdeal-v0", config={"width": 160, "height": 120})
    yield e
    e.close()


def _centre_ray(frame) -> tuple[float, np.ndarray]:
    """(depth, unit-depth ray) of the strided image's centre pixel (camera frame)."""
    h, w = frame.depth.shape
    v, u = h // 2, w // 2
    z = float(frame.depth[v, u])
    assert z > 0.8
    k = int(
        np.flatnonzero(
            (frame.pixels[:, 0] == v * frame.stride) & (frame.pixels[:, 1] == u * frame.stride)
        )[0]
    )
    return z, frame.points[k] / z


def test_carving_removes_points_seen_through_and_keeps_visible_ones(env):
    obs, info = env.reset(seed=0)
    agent = make_agent("simn", env.unwrapped)
    agent.reset(obs, info)
    world = agent.world
    frames = world.frames
    frame = world.slam.perception(obs["rgb"], obs["depth"])
    T_wc = world.pose @ world.T_base_cam
    z, ray = _centre_ray(frame)
    T_anchor_cam = inv_T(frames.topo.anchor(frames.current_id)) @ T_wc
    ghost = transform_points(T_anchor_cam, (ray * (z - 0.5))[None].astype(np.float64))  # in front
    hidden = transform_points(T_anchor_cam, (ray * (z + 0.5))[None].astype(np.float64))  # behind
    for st in frames.states.values():  # only the two test points in the stores
        st.obstacles.remove(np.ones(len(st.obstacles), bool))
    frames.current.obstacles.add(np.concatenate([ghost, hidden]))
    assert frames.carve(frame, T_wc) == 1
    np.testing.assert_allclose(frames.current.obstacles.points, hidden, atol=1e-6)


@pytest.mark.parametrize("carve_frames, kept", [(2, True), (0, False)])
def test_carving_reaches_older_frames_when_told(env, carve_frames, kept):
    """A ghost in front of the seen wall, stored by the first of four local frames: carving the
    two most recent frames keeps it, carving every frame (``carve_frames`` 0) removes it; a
    point behind the wall stays either way, and a frame whose points all lie deeper than the
    view is left alone."""
    obs, info = env.reset(seed=0)
    agent = make_agent("simn", env.unwrapped, {"slam": {"stores": {"carve_frames": carve_frames}}})
    agent.reset(obs, info)
    frames = agent.world.frames
    frame = agent.world.slam.perception(obs["rgb"], obs["depth"])
    T_wc = agent.world.pose @ agent.world.T_base_cam
    for t in (1.0, 2.0, 3.0):  # three more local frames at the same pose
        frames.close(frames.current_id)
        frames.open(T_wc, t)
    assert len(frames) == 4
    z, ray = _centre_ray(frame)
    T_first_cam = inv_T(frames.topo.anchor(0)) @ T_wc
    ghost = transform_points(T_first_cam, (ray * (z - 0.5))[None].astype(np.float64))
    hidden = transform_points(T_first_cam, (ray * (z + 0.5))[None].astype(np.float64))
    far = transform_points(T_first_cam, (ray * (frame.depth.max() + 1.0))[None].astype(np.float64))
    for st in frames.states.values():
        st.obstacles.remove(np.ones(len(st.obstacles), bool))
    frames.states[0].obstacles.add(np.concatenate([ghost, hidden]))
    frames.states[1].obstacles.add(far)
    assert frames.carve(frame, T_wc) == (0 if kept else 1)
    expect = np.concatenate([ghost, hidden]) if kept else hidden
    np.testing.assert_allclose(frames.states[0].obstacles.points, expect, atol=1e-6)
    np.testing.assert_allclose(frames.states[1].obstacles.points, far, atol=1e-6)


@pytest.mark.parametrize(
    "pose_source,world_type", [("slam", SlamWorld), ("odometry", OdometryWorld)]
)
def test_each_world_model_feeds_the_same_planner_interface(env, pose_source, world_type):
    """Both world models give the agent a pose, a topological map and an ObstacleMap whose
    planning / safety models are CollisionCheckers holding the wall the camera sees."""
    obs, info = env.reset(seed=0)
    agent = make_agent("simn", env.unwrapped, {"pose_source": pose_source, "initial_scan_deg": 0.0})
    agent.reset(obs, info)
    world = agent.world
    assert isinstance(world, world_type)
    for _ in range(3):
        obs, *_ = env.step(agent.act(obs))
    assert world.pose.shape == (4, 4) and np.isfinite(world.pose).all()
    assert world.current_frame_id >= 0 and world.current_frame_id in world.topology.frame_ids
    for model in (world.obstacles.planning, world.obstacles.safety):
        assert isinstance(model, CollisionChecker)
    # the local frames' stored obstacle points are obstacles of the planning model (within the
    # occupancy grid's cell)
    obst = world.frames.obstacle_points_world()
    assert len(obst) > 100
    res = agent.cfg.obstacles.collision.resolution
    assert float(world.obstacles.planning.clearance(obst[:, :2]).max()) < res
    assert isinstance(world.obstacles.shadow_model(), CollisionChecker)
    assert set(agent.counters()) >= {"plan_failures", "fallback_plans", "bumps", "local_frames"}


def test_agent_slam_presets_learned_default_and_points_ablation(env):
    from simn_sim.slam.config import SlamConfig

    # the paper's method is the default: each local frame's map is learned and tracked against
    default = make_agent("simn", env.unwrapped, {}).cfg.slam
    assert default == SlamConfig.for_agent()
    assert default.map_kind == "implicit" and default.track_sdf == "implicit"
    agent = make_agent("simn", env.unwrapped, {"slam": {"seed": 7}})
    assert agent.cfg.slam == SlamConfig.for_agent(seed=7)
    # the point-store ablation: a preset, or the agent simn_points (same changes accepted)
    agent = make_agent("simn", env.unwrapped, {"slam": {"preset": "points_agent", "seed": 7}})
    assert agent.cfg.slam == SlamConfig.for_points_agent(seed=7)
    assert agent.cfg.slam.map_kind == "points" and agent.cfg.slam.track_sdf == "points"
    pts = make_agent("simn_points", env.unwrapped, {"slam": {"seed": 7}})
    assert pts.name == "simn_points" and pts.cfg.slam == SlamConfig.for_points_agent(seed=7)
    with pytest.raises(ConfigError, match="simn_points: slam.preset"):
        make_agent("simn_points", env.unwrapped, {"slam": {"preset": "agent"}})
    with pytest.raises(ConfigError, match="unknown preset 'learnd'"):
        make_agent("simn", env.unwrapped, {"slam": {"preset": "learnd"}})
    with pytest.raises(ConfigError, match="'learned_agent' was renamed"):
        make_agent("simn", env.unwrapped, {"slam": {"preset": "learned_agent"}})


def test_bad_agent_config_is_rejected(env):
    with pytest.raises(ConfigError, match="rebuild_every"):
        make_agent("simn", env.unwrapped, {"obstacles": {"rebuild_every": 0}})
    with pytest.raises(ConfigError, match="normal_smooth_px"):  # the front-end needs normals
        make_agent("simn", env.unwrapped, {"slam": {"perception": {"normal_smooth_px": -1}}})
    with pytest.raises(ConfigError, match="unknown config key"):
        make_agent("simn", env.unwrapped, {"plnner": "uniform"})
    with pytest.raises(ConfigError, match="planner"):
        make_agent("simn", env.unwrapped, {"planner": "astar"})


def test_a_nested_mapping_changes_only_its_keys():
    """A partial mapping for a nested config overrides the agent's defaults for it, not the
    nested class's: {"obstacles": {"transient": {"grow_share": 0.3}}} used to build
    TransientConfig() with keep_views 0 and turned transient cells off."""
    d = SimnAgentConfig()
    c = SimnAgentConfig.from_dict(
        {
            "obstacles": {"transient": {"grow_share": 0.3}, "collision": {"margin": 0.2}},
            "follower": {"lookahead": 0.7},
        }
    )
    assert c.obstacles.transient == d.obstacles.transient.replace(grow_share=0.3)
    assert d.obstacles.transient.keep_views == 30 != TransientConfig().keep_views
    assert c.obstacles.collision == d.obstacles.collision.replace(margin=0.2)
    assert c.follower == d.follower.replace(lookahead=0.7)
    assert c.rrt == d.rrt and c.slam == d.slam
    with pytest.raises(ConfigError, match="unknown config key"):
        SimnAgentConfig.from_dict({"obstacles": {"transient": {"keep_view": 3}}})


def test_old_agent_config_keys_fail_naming_their_new_place(env):
    with pytest.raises(ConfigError, match=r"'carve_margin' -> slam.stores.carve_margin"):
        make_agent("simn", env.unwrapped, {"carve_margin": 0.1})
    with pytest.raises(ConfigError, match=r"'shadow_depth' -> obstacles.shadow_depth"):
        make_agent("simn", env.unwrapped, {"shadow_depth": 0.3})
    with pytest.raises(ConfigError, match=r"'describe_max_points' -> 'descriptor.max_points'"):
        make_agent("simn", env.unwrapped, {"slam": {"describe_max_points": 10}})


def test_simn_act_is_within_bounds_and_never_reads_true_pose(env):
    obs, info = env.reset(seed=2)
    agent = make_agent("simn", env.unwrapped)
    agent.reset(obs, info)
    lo, hi = env.action_space.low, env.action_space.high
    for _ in range(15):
        a = agent.act(obs)  # no info: the agent must not need the true pose
        assert np.all(a >= lo - 1e-6) and np.all(a <= hi + 1e-6)
        obs, *_ = env.step(a)


def _room_with_box_behind_start():
    """A 12 x 8 m walled room; the robot starts at (6, 4) facing +x; a 0.6 m cube stands 1.8 m
    behind it, outside the camera's view until the robot turns."""
    from simn_sim.env.layout import Box, Layout, Room

    t, g = 0.075, (0.8, 0.8, 0.8, 1)
    boxes = [
        Box("s", "wall", -1, (6.0, 0.0, 1.3), (6.0 + t, t, 1.3), 0.0, g),
        Box("n", "wall", -1, (6.0, 8.0, 1.3), (6.0 + t, t, 1.3), 0.0, g),
        Box("w", "wall", -1, (0.0, 4.0, 1.3), (t, 4.0 + t, 1.3), 0.0, g),
        Box("e", "wall", -1, (12.0, 4.0, 1.3), (t, 4.0 + t, 1.3), 0.0, g),
        Box("cube", "box", 0, (4.2, 4.0, 0.3), (0.3, 0.3, 0.3), 0.0, (0.6, 0.3, 0.2, 1)),
    ]
    return Layout(98, (12.0, 8.0), [Room("r", 0, 0, 12, 8)], [], boxes)


@pytest.mark.parametrize("scan", [0.0, 360.0])
def test_initial_scan_maps_what_stands_behind_the_start(scan):
    from test_env import _env_with_layout  # the env on a hand-made layout

    e = _env_with_layout(_room_with_box_behind_start())
    ep = {"episode_id": "scan", "layout_seed": None, "start": [6.0, 4.0, 0.0], "goal": [10.0, 4.0]}
    obs, info = e.reset(options={"episode": ep})
    agent = make_agent("simn", e, {"initial_scan_deg": scan})
    agent.reset(obs, info)
    n_scan = int(np.ceil(np.radians(scan) / (agent.cfg.scan_rate * e.dt)))
    for _ in range(n_scan):
        a = agent.act(obs)
        assert a[0] == 0.0 and a[1] > 0  # turning in place only
        obs, _, _, _, info = e.step(a)
    # the cube's centre in the agent's (start) frame: 1.8 m behind the robot
    cube_xy = np.array([[-1.8, 0.0]])
    clearance = float(agent.obstacles.planning.clearance(cube_xy)[0])
    if scan:
        assert clearance < 0.1  # its faces (0.3 m from the centre) are in the collision model
        assert np.hypot(*(info["T_world_base"][:2, 3] - [6.0, 4.0])) < 0.02  # no translation
    else:
        assert clearance > 1.0  # never in view: unknown, so free
    e.close()


def _room_with_chair_ahead():
    """The room of ``_room_with_box_behind_start`` without the cube; 1.2 m ahead of the start
    a chair turned away from the robot: its back (a thin plate, z 0.47-0.93) hides its seat
    (0.44 m deep, top at z 0.5) from the camera at 1.0 m."""
    from simn_sim.env.layout import Box

    lay = _room_with_box_behind_start()
    lay.boxes = [b for b in lay.boxes if b.name != "cube"]
    c = (0.5, 0.5, 0.5, 1)
    lay.boxes += [
        Box("back", "chair", 1, (7.2, 4.0, 0.7), (0.0125, 0.22, 0.23), 0.0, c),
        Box("seat", "chair", 1, (7.4325, 4.0, 0.475), (0.22, 0.22, 0.025), 0.0, c),
    ]
    return lay


def _one_view(layout, agent_cfg: dict):
    """Env on ``layout`` (320x240), the robot at (6, 4) facing +x with the goal 5 m ahead, and
    a ``simn`` agent reset on the first view (no look-around)."""
    from test_env import _env_with_layout

    e = _env_with_layout(layout, width=320, height=240)
    ep = {"episode_id": "view", "layout_seed": None, "start": [6.0, 4.0, 0.0], "goal": [11.0, 4.0]}
    obs, info = e.reset(options={"episode": ep})
    agent = make_agent("simn", e, {"initial_scan_deg": 0.0, **agent_cfg})
    agent.reset(obs, info)
    return e, agent


@pytest.mark.parametrize("shadow_depth", [0.0, 0.3])
def test_occlusion_shadow_pushes_plans_off_a_seat_hidden_behind_its_back(shadow_depth):
    from simn_sim.planning.smoothing import push_from_obstacles

    # one view of the chair from 1.2 m
    e, agent = _one_view(_room_with_chair_ahead(), {"obstacles": {"shadow_depth": shadow_depth}})
    # agent (start) frame: the back's visible face at x = 1.1875, the seat x in [1.2125, 1.6525],
    # |y| <= 0.22; the back is mapped, the seat is not
    assert float(agent.obstacles.planning.clearance(np.array([[1.2, 0.0]]))[0]) < 0.06
    # a path across the room 0.15 m behind the seat: free under the seen obstacles (0.61 m
    # from the back) though a robot on it (radius 0.25) hits the seat
    path = np.array([[1.8, -1.5], [1.8, 1.5]])
    assert agent.obstacles.planning.path_free(path)
    pushed = push_from_obstacles(
        path,
        agent.obstacles.planning,
        agent.cfg.path_clearance,
        also_from=agent.obstacles.shadow_model(),
    )
    assert agent.obstacles.planning.path_free(pushed)  # shadows never make a plan unfree
    dx = np.maximum(np.abs(pushed[:, 0] - 1.4325) - 0.22, 0.0)
    dy = np.maximum(np.abs(pushed[:, 1]) - 0.22, 0.0)
    seat_dist = float(np.min(np.hypot(dx, dy)))  # exact distance to the seat's footprint
    if shadow_depth:
        assert len(agent.obstacles.shadow) > 0
        assert (
            seat_dist > agent.cfg.obstacles.collision.robot_radius
        )  # pushed clear of the hidden seat
    else:
        assert agent.obstacles.shadow is None and agent.obstacles.shadow_model() is None
        assert seat_dist < agent.cfg.obstacles.collision.robot_radius  # would hit the seat
    e.close()


def test_shadows_are_cast_only_within_shadow_range():
    # the back is 0.97 m from the camera: beyond 0.9 m
    e, agent = _one_view(_room_with_chair_ahead(), {"obstacles": {"shadow_range": 0.9}})
    assert float(agent.obstacles.planning.clearance(np.array([[1.2, 0.0]]))[0]) < 0.06
    assert len(agent.obstacles.shadow) == 0
    e.close()


def test_shadow_config_is_validated(env):
    with pytest.raises(ConfigError, match="shadow_depth"):
        make_agent("simn", env.unwrapped, {"obstacles": {"shadow_depth": 0.01}})
    with pytest.raises(ConfigError, match="blind_shadow_depth"):
        make_agent("simn", env.unwrapped, {"obstacles": {"blind_shadow_depth": 0.01}})
    # the SLAM preset's revisit settings, passed through the agent config
    for key, bad in [
        ("revisit_min_overlap", 1.5),
        ("revisit_registrations_per_frame", -1),
        ("descriptor", {"max_points": -1}),
    ]:
        with pytest.raises(ConfigError, match=key if key != "descriptor" else "max_points"):
            make_agent("simn", env.unwrapped, {"slam": {key: bad}}).reset(*env.reset(seed=0))


def _room_with_low_box_ahead():
    """The room of ``_room_with_box_behind_start`` without the cube; 0.55-1.0 m ahead of the
    start a 0.34 m box (the nav-ref-006 case): the camera (0.22 m ahead of the base centre, at
    1.0 m, lower border 45.25 deg down) sees its top only from x = 0.874 m in the start frame;
    the nearer part is below the view."""
    from simn_sim.env.layout import Box

    lay = _room_with_box_behind_start()
    lay.boxes = [b for b in lay.boxes if b.name != "cube"]
    lay.boxes.append(
        Box("low", "box", 2, (6.775, 4.0, 0.17), (0.225, 0.3, 0.17), 0.0, (0.6, 0.3, 0.2, 1))
    )
    return lay


@pytest.mark.parametrize("blind", [0.0, 0.6])
def test_blind_zone_shadow_covers_the_part_of_a_low_box_below_the_view(blind):
    e, agent = _one_view(_room_with_low_box_ahead(), {"obstacles": {"blind_shadow_depth": blind}})
    # start frame: the box x in [0.55, 1.0], |y| <= 0.3; only x >= 0.874 is in view
    assert float(agent.obstacles.planning.clearance(np.array([[0.95, 0.0]]))[0]) < 0.06
    assert float(agent.obstacles.planning.clearance(np.array([[0.6, 0.0]]))[0]) > 0.2  # unseen part
    gx, gy = np.meshgrid(np.arange(0.575, 0.85, 0.05), np.arange(-0.125, 0.13, 0.05))
    hidden = np.stack([gx.ravel(), gy.ravel()], 1)  # the hidden part, in the seen columns
    in_shadow = agent.obstacles.shadow_model().clearance(hidden) < 1e-6
    if blind:
        assert in_shadow.mean() > 0.9
        # the robot's own footprint is known free: no shadow there
        assert float(agent.obstacles.shadow_model().clearance(np.array([[0.0, 0.0]]))[0]) > 0.2
    else:
        assert not in_shadow.any()
    e.close()


@pytest.mark.parametrize(
    "agent_cfg,expected",
    [
        ({}, "learned"),
        ({"slam": {"preset": "points_agent"}}, "points"),
        ({"slam": {"map_kind": "points", "track_sdf": "points"}}, "points"),
        ({"pose_source": "odometry"}, None),
    ],
)
def test_tracking_map_is_reported(env, agent_cfg, expected):
    obs, info = env.reset(seed=0)
    agent = make_agent("simn", env.unwrapped, agent_cfg)
    agent.reset(obs, info)
    assert agent.debug()["tracking_map"] == expected


def test_episode_record_has_act_timing_and_tracking_map():
    from simn_sim.experiments.runner import run_episode

    rec = run_episode(
        "SimnOffice-v0", {"width": 160, "height": 120, "max_episode_steps": 5}, "simn", {}, seed=3
    )
    assert rec["error"] is None, rec["error"]
    assert rec["steps"] == 5 and rec["tracking_map"] == "learned"
    # one local frame in 5 steps: nothing to revisit, judged as such against the true poses
    assert rec["revisit_opportunities"] == 0 and rec["revisits_correct"] == 0
    assert rec["revisits_off_fine"] == 0
    assert rec["revisit_err_m_median"] is None
    assert 0 < rec["act_ms_mean"] <= rec["act_ms_p95"] * 5
    assert rec["act_ms_p95"] > 0
    rec = run_episode(
        "SimnOffice-v0", {"width": 160, "height": 120, "max_episode_steps": 5}, "simn_points", {},
        seed=3,
    )  # fmt: skip
    assert rec["error"] is None and rec["agent"] == "simn_points"
    assert rec["tracking_map"] == "points"


def test_revisit_events_name_the_observation_each_frame_opened_at(env):
    """Ideal sensing: each local frame's anchor (the estimated camera pose it opened at) is
    the true camera pose of the observation ``revisit_events`` names, within 3 cm / 1 deg, and
    closer to it than to the observations before and after it."""
    import math

    from simn_sim.geometry.se3 import inv_T, pose_error

    env = gym.make("SimnOffice-v0", config={"width": 160, "height": 120, "sensing": "ideal"})
    obs, info = env.reset(seed=3)
    agent = make_agent("simn", env.unwrapped, {})
    agent.reset(obs, info)
    T_ws = info["T_world_base"].copy()
    true_cam = []
    for _ in range(25):
        true_cam.append(np.asarray(info["T_world_cam"], float).copy())
        obs, _, term, trunc, info = env.step(agent.act(obs, info))
        assert not (term or trunc)
    ev = agent.revisit_events()
    frames = agent.world.frames
    assert len(ev["frame_obs"]) == len(frames) >= 3 and ev["frame_obs"][0] == 0
    for fid, i in enumerate(ev["frame_obs"]):
        anchor = frames.topo.anchor(fid)
        err = {
            j: pose_error(inv_T(T_ws) @ true_cam[j], anchor)
            for j in (i - 1, i, i + 1)
            if 0 <= j < len(true_cam)
        }
        dt, dr = err[i]
        assert dt < 0.03 and math.degrees(dr) < 1.0, (fid, i, dt, math.degrees(dr))
        for j, (dtj, drj) in err.items():
            assert j == i or dtj + drj > dt + dr, (fid, i, j)
    agent.close()
    env.close()
    odo = make_agent("simn", env.unwrapped, {"pose_source": "odometry"})
    assert odo.revisit_events() is None


def test_episode_ate_pairs_each_estimate_with_the_pose_it_was_made_at():
    """Exact odometry (ideal sensing) as the pose: the ATE is zero, not the step's motion."""
    from simn_sim.experiments.runner import run_episode

    rec = run_episode(
        "SimnOffice-v0",
        {"width": 160, "height": 120, "max_episode_steps": 12, "sensing": "ideal"},
        "simn",
        {"pose_source": "odometry", "initial_scan_deg": 0.0},
        seed=3,
    )
    assert rec["error"] is None, rec["error"]
    assert rec["path_length_m"] > 0.1, rec["path_length_m"]
    assert rec["ate_rmse_m"] < 1e-4, rec["ate_rmse_m"]


def _train_threads() -> set:
    import threading

    return {t for t in threading.enumerate() if t.name.startswith("simn-train")}


def test_closing_the_agent_stops_training_and_frees_the_episode_maps(env):
    """A batch worker runs many episodes in one process: an episode's training thread (the
    learned map's ``train_async``) must not outlive it and keep its maps alive (before the fix
    a worker grew ~0.45 GB per episode)."""
    import gc
    import weakref

    from simn_sim.experiments.runner import run_episode

    before = _train_threads()
    obs, info = env.reset(seed=1)
    agent = make_agent("simn", env.unwrapped, {})
    agent.reset(obs, info)
    for _ in range(3):
        obs, *_, info = env.step(agent.act(obs, info))
    maps = agent.world.frames.implicit_maps()
    assert maps and len(_train_threads() - before) == 1  # the learned map trains on a thread
    refs = [weakref.ref(m) for m in maps.values()]
    del maps
    agent.reset(*env.reset(seed=2))  # a new episode closes the previous world model
    gc.collect()
    assert all(r() is None for r in refs)
    assert len(_train_threads() - before) <= 1
    agent.close()
    agent.close()  # idempotent
    assert _train_threads() <= before
    rec = run_episode(
        "SimnOffice-v0", {"width": 160, "height": 120, "max_episode_steps": 4}, "simn", {}, seed=0
    )
    assert rec["error"] is None and rec["tracking_map"] == "learned"
    assert _train_threads() <= before  # the runner closed the episode's agent


def test_json_object_parses_a_command_line_config_and_names_bad_input():
    """``json_object`` (the benchmarks' ``--variant NAME JSON``): an object comes back as a
    dict; text that is not JSON, or JSON that is not an object, fails naming the option."""
    from simn_sim.config import json_object

    assert json_object('{"slam": {"train_every": 2}}', "--variant a") == {
        "slam": {"train_every": 2}
    }
    with pytest.raises(ConfigError, match=r"--variant b: not valid JSON"):
        json_object("{slam: 2}", "--variant b")
    with pytest.raises(ConfigError, match=r"--variant c: expected a JSON object, got '\[1\]'"):
        json_object("[1]", "--variant c")
