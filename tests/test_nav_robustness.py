"""Closed-loop behaviour of the default ``simn`` agent under realistic sensing: a trap episode
and determinism of the episode record."""

from __future__ import annotations

import pytest

from simn_sim.env.episodes import EpisodeSet
from simn_sim.env.office import load_layout
from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND
from simn_sim.env.traps import trap_info
from simn_sim.experiments.runner import run_episode
from simn_sim.geometry.freespace import FreeSpace2D
from simn_sim.paths import envs_dir

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
def test_trap_episode_reaches_the_goal_within_1_5x_the_geodesic():
    """nav2-ref-009: the goal room's doorway is hidden from the start and the straight line
    at the goal ends farther from it (a closed region); realistic sensing, 320x240."""
    ep = _episode("nav2-ref-009")
    layout = load_layout(ep.layout_seed)
    fs = FreeSpace2D(
        layout.footprints(ROBOT_Z_BAND), robot_radius=ROBOT_RADIUS, bounds=layout.bounds
    )
    info = trap_info(layout, fs, ep.start, ep.goal)
    assert info.is_trap, info
    rec = run_episode(
        "SimnOffice-v0", {"width": 320, "height": 240}, "simn", {}, episode=ep.to_dict()
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
