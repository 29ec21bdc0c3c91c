"""A recorded oracle episode read back: entity paths, one row per step, poses equal the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simn_sim.env.episodes import EpisodeSet
from simn_sim.experiments.batch import make_env, regression_episode_file, resolve_env_config
from simn_sim.experiments.rrd import entity_translations, main, read_recording
from simn_sim.experiments.runner import run_episode

EXPECTED = (
    "world/robot",
    "world/camera",
    "world/camera/image",
    "world/camera/image/rgb",
    "world/camera/image/depth",
    "world/trajectory/true",
    "world/planner/path",
    "world/floorplan",
    "world/goal",
)
PER_STEP = (
    "world/robot",
    "world/camera",
    "world/camera/image/rgb",
    "world/camera/image/depth",
    "world/trajectory/true",
)


def test_oracle_recording_has_entities_and_steps(tmp_path: Path) -> None:
    spec = next(
        e
        for e in EpisodeSet.load(regression_episode_file()).episodes
        if e.episode_id == "reg-ref-000"
    )
    env_cfg = resolve_env_config("SimnOffice-v0", {"width": 160, "height": 120})
    env = make_env("SimnOffice-v0", env_cfg)
    rrd = tmp_path / "rec" / "reg-ref-000.rrd"
    try:
        rec = run_episode(
            "SimnOffice-v0", env_cfg, "oracle", {}, episode=spec.to_dict(), rerun_path=rrd, env=env
        )
    finally:
        env.close()
    assert rec["error"] is None and rec["success"] is True
    n = rec["steps"]
    assert 20 < n < 200

    s = read_recording(rrd)
    assert s.recording_id == "reg-ref-000"
    missing = [e for e in EXPECTED if e not in s.entity_paths]
    assert not missing, f"missing entities {missing}; have {s.entity_paths}"
    assert {"world/floorplan", "world/goal"} <= set(s.static_entities)
    assert s.steps == list(range(n + 1))  # the reset frame plus one per env step
    for e in PER_STEP:
        assert s.steps_per_entity[e] == list(range(n + 1)), e
    assert "world/trajectory/estimated" not in s.entity_paths  # the oracle has no estimate

    steps, t = entity_translations(rrd, "world/robot")
    assert list(steps) == list(range(n + 1))
    np.testing.assert_allclose(t[0, :2], spec.start[:2], atol=1e-4)
    assert np.linalg.norm(t[-1, :2] - np.asarray(spec.goal)) <= 0.36 + 1e-3
    path = float(np.sum(np.linalg.norm(np.diff(t[:, :2], axis=0), axis=1)))
    assert path == pytest.approx(rec["path_length_m"], rel=0.01)
    assert "world/robot" in s.format()
    assert main([str(rrd)]) == 0


def test_unreadable_recording(tmp_path: Path) -> None:
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording")
    with pytest.raises(ValueError, match="not a readable rerun recording"):
        read_recording(bad)
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "none.rrd")
    assert main([str(bad)]) == 2
