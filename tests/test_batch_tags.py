"""``simn-sim batch --tag``: run only the episodes of a file that carry a tag."""

from __future__ import annotations

import pytest

from simn_sim.env.episodes import EpisodeSet
from simn_sim.experiments.batch import BatchConfig, BatchError, _episode_source
from simn_sim.paths import envs_dir

V2 = envs_dir() / "episodes" / "office_nav_v2.json"


def test_tag_selects_the_tagged_episodes(tmp_path):
    env_id, eps = _episode_source(
        BatchConfig(out=tmp_path, agent="oracle", episode_file=V2, tag="trap")
    )
    want = [e.episode_id for e in EpisodeSet.load(V2).episodes if "trap" in e.tags]
    assert env_id == "SimnOffice-v0"
    assert [e["episode_id"] for e in eps] == want and len(want) >= 10


def test_unknown_tag_and_tag_without_file_are_errors(tmp_path):
    with pytest.raises(BatchError, match="no episode carries the tag 'nope'"):
        _episode_source(BatchConfig(out=tmp_path, agent="oracle", episode_file=V2, tag="nope"))
    with pytest.raises(BatchError, match="--tag selects from an episode file"):
        BatchConfig(out=tmp_path, agent="oracle", n_episodes=2, tag="trap")
