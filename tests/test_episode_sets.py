"""Fixed episode sets in envs/episodes/: the trap predicate on a hand-built office, the tags
field, and the committed office_nav_v2 / office_dynamic_v1 files recomputed from the geometry."""

from __future__ import annotations

import collections
import json
import math
from pathlib import Path

import numpy as np
import pytest

from simn_sim.env.episode_sets import TRAP_TAG, layout_free_space, people_at_reset, select
from simn_sim.env.episodes import EpisodeSet, EpisodeSpec
from simn_sim.env.layout import Door, Layout, Room, _wall_with_doors
from simn_sim.env.office import load_layout
from simn_sim.env.scene import ROBOT_RADIUS
from simn_sim.env.traps import door_opening, opening_visible, trap_info, wall_segments
from simn_sim.paths import envs_dir

EPISODES = envs_dir() / "episodes"
START_CLEARANCE = 0.15  # EnvConfig.start_clearance: the env sampler's margin beyond the radius
GEO_TOL = 1e-6


# ---- the trap predicate on a hand-built office --------------------------------------------


def _two_rooms(partition_door: float | None = None) -> Layout:
    """12 x 8 m: a corridor y in [0, 2] below rooms A (x in [0, 6]) and B (x in [6, 12]).

    A's corridor door is at x = 1.5, B's at x = 10.5 (1.2 m wide); the partition x = 6 has a
    door centred at y = ``partition_door`` (1.1 m wide) or none.
    """
    W, H, rgba = 12.0, 8.0, (0.9, 0.9, 0.9, 1.0)
    doors = [Door((1.5, 2.0), 1.2, "x"), Door((10.5, 2.0), 1.2, "x")]
    boxes = []
    boxes += _wall_with_doors("x", 0.0, 0.0, W, [], rgba, "outer_s")
    boxes += _wall_with_doors("x", H, 0.0, W, [], rgba, "outer_n")
    boxes += _wall_with_doors("y", 0.0, 0.0, H, [], rgba, "outer_w")
    boxes += _wall_with_doors("y", W, 0.0, H, [], rgba, "outer_e")
    boxes += _wall_with_doors("x", 2.0, 0.0, W, [(0.9, 2.1), (9.9, 11.1)], rgba, "corr")
    gaps = []
    if partition_door is not None:
        gaps = [(partition_door - 0.55, partition_door + 0.55)]
        doors.append(Door((6.0, partition_door), 1.1, "y"))
    boxes += _wall_with_doors("y", 6.0, 2.0, H, gaps, rgba, "part")
    rooms = [Room("A", 0, 2, 6, H), Room("B", 6, 2, W, H), Room("corridor", 0, 0, W, 2)]
    return Layout(0, (W, H), rooms, doors, boxes)


def test_door_openings_and_visibility_on_the_hand_built_office() -> None:
    lay = _two_rooms()
    walls = wall_segments(lay)
    a, b = (door_opening(d) for d in lay.doors)
    np.testing.assert_allclose(a, [[0.975, 2.0], [2.025, 2.0]])  # 1.2 m gap less the jambs
    # from inside room A its own door is in sight, B's door is behind the partition
    assert opening_visible((5.0, 5.0), a, walls)
    assert not opening_visible((5.0, 5.0), b, walls)
    # from the corridor both are in sight, also at a grazing angle (walls are centre lines)
    assert opening_visible((4.0, 1.0), a, walls) and opening_visible((4.0, 1.0), b, walls)
    assert opening_visible((0.5, 1.5), b, walls)
    # from room B's far corner, room A's door is hidden
    assert not opening_visible((11.0, 7.0), a, walls)
    # a wall crossing the opening hides only the part behind it (seen from (9, 1), the
    # directions 26-34 deg of the 26-46 deg the opening spans); a stub hides 31-50 deg
    cross, stub = [[[10.5, 1.5], [10.5, 2.5]]], [[[9.5, 1.3], [9.5, 1.6]]]
    assert opening_visible((9.0, 1.0), b, np.concatenate([walls, cross]))
    assert opening_visible((9.0, 1.0), b, np.concatenate([walls, stub]))
    assert not opening_visible((9.0, 1.0), b, np.concatenate([walls, cross, stub]))
    # edge-on (on the wall's line) counts as hidden
    assert not opening_visible((5.0, 2.0), b, walls[:0])


def test_trap_predicate_true_and_false_cases() -> None:
    lay = _two_rooms()
    fs = layout_free_space(lay)
    # neighbouring rooms without a door between them: the textbook trap
    t = trap_info(lay, fs, (5.0, 5.0), (7.0, 5.0))
    assert t.doors_on_path == (0, 1) and t.hidden_doors == (1,)
    assert t.detour_ratio > 5 and t.greedy_stop is not None
    np.testing.assert_allclose(t.greedy_stop, (6.0 - 0.075 - ROBOT_RADIUS, 5.0), atol=2e-3)
    assert t.greedy_geodesic_m > t.geodesic_m
    assert t.is_trap
    # (c) fails: driving straight at the goal gets closer to room A's door (down and right)
    t = trap_info(lay, fs, (5.0, 7.0), (7.0, 3.0))
    assert t.detour and t.hidden_doorway and not t.greedy_loses and not t.is_trap
    # (b) fails: from the corridor room B's door is in sight
    t = trap_info(lay, fs, (4.0, 1.0), (7.0, 5.0))
    assert t.detour and not t.hidden_doorway and not t.is_trap
    # (a) fails: same room, straight line free
    t = trap_info(lay, fs, (2.0, 4.0), (5.0, 6.0))
    assert t.detour_ratio == pytest.approx(1.0) and t.greedy_stop is None and not t.is_trap
    # a door in the partition: the only doorway on the route is in sight; greedy still
    # loses ground (it heads up the partition, away from the door near its bottom)
    lay2 = _two_rooms(partition_door=2.9)
    t = trap_info(lay2, layout_free_space(lay2), (5.5, 6.0), (7.0, 7.5))
    assert t.doors_on_path == (2,) and t.hidden_doors == ()
    assert t.detour and t.greedy_loses and not t.is_trap


def test_door_openings_meet_the_wall_pieces_in_generated_layouts() -> None:
    """The opening of every doorway ends exactly where the wall pieces beside it end, and its
    middle is on no wall (what :func:`door_opening` assumes of the layout generator)."""
    for seed in (None, 1, 2, 3, 4, 5):
        lay = load_layout(seed)
        walls = wall_segments(lay)
        ends = walls.reshape(-1, 2)
        for d in lay.doors:
            op = door_opening(d)
            for p in op:
                assert np.min(np.hypot(*(ends - p).T)) < 1e-9, (seed, d)
            normal = np.array([0.0, 0.3]) if d.axis == "x" else np.array([0.3, 0.0])
            mid = op.mean(0)
            assert opening_visible(mid + normal, op, walls)  # no wall across the opening
            assert opening_visible(mid - normal, op, walls)


def test_select_spreads_over_bins_and_takes_traps_first() -> None:
    from simn_sim.env.episode_sets import Candidate

    cands = [Candidate((0, 0, 0), (1, 1), g, trap) for g, trap in [(3.5, False)] * 6]
    cands += [Candidate((0, 0, 0), (1, 1), 18.0, False), Candidate((0, 0, 0), (1, 1), 19, True)]
    cands += [Candidate((0, 0, 0), (1, 1), 10.0, False)] * 3
    idx = select(cands, 4, 1, 3.0, 20.0, 4)
    assert 7 in idx  # the trap
    # the trap fills the top bin, then one per bin from the emptiest (the third bin is empty)
    assert sorted(cands[i].geodesic_m for i in idx) == [3.5, 3.5, 10.0, 19.0]
    assert idx == sorted(idx)


# ---- tags -------------------------------------------------------------------------------------


def test_tags_round_trip_and_old_files_load_unchanged(tmp_path: Path) -> None:
    v1 = EPISODES / "office_nav_v1.json"
    es = EpisodeSet.load(v1)
    assert all(e.tags == () for e in es.episodes)
    es.save(tmp_path / "v1.json")
    assert (tmp_path / "v1.json").read_bytes() == v1.read_bytes()  # no "tags" key written
    e = EpisodeSpec("t", None, (1.0, 2.0, 0.0), (3.0, 4.0), 5, tags=("trap",))
    assert e.to_dict()["tags"] == ["trap"]
    assert EpisodeSpec.from_dict(e.to_dict()) == e
    assert EpisodeSpec("t", None, (1, 2, 0), (3, 4), tags=["a"]).tags == ("a",)


@pytest.mark.parametrize("bad", ["trap", None, {"trap": 1}, [1], [""], 3])
def test_bad_tags_are_a_clear_error(bad, tmp_path: Path) -> None:
    d = {"episode_id": "x", "layout_seed": None, "start": [1, 2, 0], "goal": [3, 4], "tags": bad}
    with pytest.raises(ValueError, match="tags"):
        EpisodeSpec.from_dict(d)
    f = tmp_path / "e.json"
    f.write_text(json.dumps({"format": "simn-sim-episodes/1", "episodes": [d]}))
    with pytest.raises(ValueError, match="tags"):
        EpisodeSet.load(f)


# ---- the committed sets -----------------------------------------------------------------------


def _check_set(name: str, min_geo: float, max_geo: float) -> tuple[EpisodeSet, list]:
    """Loads a committed set and checks every episode against the geometry; returns the set and
    each episode's TrapInfo (recomputed, not read from the tags)."""
    es = EpisodeSet.load(EPISODES / name)
    by = collections.defaultdict(list)
    for e in es.episodes:
        by[e.layout_seed].append(e)
    infos = {}
    for lay_seed, eps in by.items():
        lay = load_layout(lay_seed)
        fs = layout_free_space(lay)
        walls = wall_segments(lay)
        pts = np.array([p for e in eps for p in (e.start[:2], e.goal)])
        assert fs.is_free(pts).all(), (name, lay_seed)
        # the env sampler's clearance rule for starts and goals
        assert (fs.clearance(pts) >= ROBOT_RADIUS + START_CLEARANCE - 1e-9).all()
        for e in eps:
            t = trap_info(lay, fs, e.start, e.goal, walls)  # raises when unreachable
            assert math.isfinite(t.geodesic_m)
            assert min_geo - GEO_TOL <= t.geodesic_m <= max_geo + GEO_TOL, e.episode_id
            assert (TRAP_TAG in e.tags) == t.is_trap, e.episode_id
            infos[e.episode_id] = t
    assert len({e.seed for e in es.episodes}) == len(es.episodes)
    return es, [infos[e.episode_id] for e in es.episodes]


def test_office_nav_v2() -> None:
    es, infos = _check_set("office_nav_v2.json", 3.0, 20.0)
    assert es.env_id == "SimnOffice-v0"
    assert len(es.episodes) >= 60
    layouts = collections.Counter(e.layout_seed for e in es.episodes)
    assert None in layouts and len(layouts) >= 6 and min(layouts.values()) >= 10
    assert sum(t.is_trap for t in infos) >= 10
    geo = np.array([t.geodesic_m for t in infos])
    counts = np.histogram(geo, bins=np.linspace(3.0, 20.0, 5))[0]
    assert counts.min() >= 0.15 * len(geo), counts  # spread over the range, not all short


def test_office_dynamic_v1() -> None:
    es, infos = _check_set("office_dynamic_v1.json", 3.0, 15.0)
    assert es.env_id == "SimnOfficeDynamic-v0"
    assert len(es.episodes) >= 30
    layouts = collections.Counter(e.layout_seed for e in es.episodes)
    assert None in layouts and len(layouts) >= 6
    geo = np.array([t.geodesic_m for t in infos])
    assert np.median(geo) > 6.0 and geo.max() > 12.0


def test_dynamic_set_people_start_clear_of_the_robot() -> None:
    """The env spawns people from the episode seed at reset: reset twice gives the same people,
    and nobody starts within 1 m of the robot (the seeds were chosen for that)."""
    import gymnasium as gym

    es = EpisodeSet.load(EPISODES / "office_dynamic_v1.json")
    env = gym.make(es.env_id, config={"width": 32, "height": 24})
    try:
        for e in es.episodes:
            pos = people_at_reset(env, e)
            assert len(pos) == 4
            d = np.hypot(*(pos - np.asarray(e.start[:2])).T)
            assert d.min() >= 1.0, (e.episode_id, d.min())
        np.testing.assert_array_equal(people_at_reset(env, es.episodes[-1]), pos)
    finally:
        env.close()


def test_batch_runs_the_file_env_id(tmp_path: Path) -> None:
    """``simn-sim batch --episode-file`` runs the file's env id (people and all) with the
    episode's seed, unless --env overrides it."""
    from simn_sim.experiments.batch import BatchConfig, run_batch

    es = EpisodeSet.load(EPISODES / "office_dynamic_v1.json")
    f = tmp_path / "one.json"
    EpisodeSet(es.env_id, es.episodes[:1]).save(f)
    res = run_batch(
        BatchConfig(
            out=tmp_path / "out",
            agent="oracle",
            episode_file=f,
            workers=0,
            env_config={"width": 32, "height": 24, "max_episode_steps": 2},
        )
    )
    (rec,) = res.records
    assert rec["error"] is None and rec["env_id"] == "SimnOfficeDynamic-v0"
    assert rec["seed"] == es.episodes[0].seed and rec["steps"] == 2
    conf = json.loads((tmp_path / "out" / "config.json").read_text())
    assert conf["env_id"] == "SimnOfficeDynamic-v0" and conf["env"]["n_people"] == 4
    assert EpisodeSet.load(tmp_path / "out" / "episode_set.json").env_id == es.env_id


# ---- the CLI ------------------------------------------------------------------------------------


def test_episodes_cli_pool_is_deterministic_and_checked(tmp_path: Path, capsys) -> None:
    from simn_sim.cli import main

    argv = ["episodes", "--n", "3", "--layouts", "-1", "--pool", "8", "--max-geodesic", "20"]
    assert main([*argv, "--out", str(tmp_path / "a.json")]) == 0
    assert main([*argv, "--out", str(tmp_path / "b.json")]) == 0
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert len(EpisodeSet.load(tmp_path / "a.json").episodes) == 3
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "c.json"), "--min-traps", "9"]) == 2
    assert "fewer than --min-traps 9" in capsys.readouterr().err
    rc = main(["episodes", "--out", str(tmp_path / "d.json"), "--min-traps", "1"])
    assert rc == 2 and "need --pool" in capsys.readouterr().err


def test_demo_runs_the_episode_file_env_id(tmp_path: Path) -> None:
    from simn_sim.cli import main

    f = tmp_path / "one.json"
    es = EpisodeSet.load(EPISODES / "office_dynamic_v1.json")
    EpisodeSet(es.env_id, es.episodes[:1]).save(f)
    argv = ["demo", "--out", str(tmp_path / "d"), "--agent", "oracle", "--episode-file", str(f)]
    argv += ["--width", "32", "--height", "24", "--max-episode-steps", "2", "--no-rerun"]
    assert main(argv) == 0
    conf = json.loads((tmp_path / "d" / "config.json").read_text())
    assert conf["env_id"] == "SimnOfficeDynamic-v0" and conf["env"]["n_people"] == 4
