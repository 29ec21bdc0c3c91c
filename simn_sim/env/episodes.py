"""Episode specifications: fixed, seeded start/goal sets stored as JSON data in ``envs/``.

File format ``simn-sim-episodes/1``::

    {"format": "simn-sim-episodes/1", "env_id": "SimnOffice-v0",
     "episodes": [{"episode_id": "ref-000", "layout_seed": null, "seed": 0,
                   "start": [x, y, yaw], "goal": [x, y], "tags": ["trap"]}, ...]}

``layout_seed`` null means the reference office. ``tags`` is optional (a list of strings, e.g.
``"trap"``: :mod:`simn_sim.env.traps`); an episode without tags is written without the key, so
files from before tags existed load and re-save unchanged. A corrupt or foreign file gives a
ValueError naming the file and the offending episode.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

EPISODES_FORMAT = "simn-sim-episodes/1"


@dataclasses.dataclass(frozen=True)
class EpisodeSpec:
    episode_id: str
    layout_seed: int | None
    start: tuple[float, float, float]  # world x, y (m), yaw (rad)
    goal: tuple[float, float]  # world x, y (m)
    seed: int = 0  # seeds the env's noise streams (and the people) for this episode
    tags: tuple[str, ...] = ()  # labels such as "trap" (simn_sim.env.traps)

    def __post_init__(self) -> None:
        if not isinstance(self.episode_id, str) or not self.episode_id:
            raise ValueError(f"episode_id must be a non-empty string, got {self.episode_id!r}")
        if len(self.start) != 3 or len(self.goal) != 2:
            raise ValueError(
                f"episode {self.episode_id}: start must be [x, y, yaw] and goal [x, y]"
            )
        if not all(math.isfinite(float(v)) for v in (*self.start, *self.goal)):
            raise ValueError(f"episode {self.episode_id}: start/goal contain NaN or inf")
        if self.layout_seed is not None and (
            not isinstance(self.layout_seed, int) or self.layout_seed < 0
        ):
            raise ValueError(
                f"episode {self.episode_id}: layout_seed must be a non-negative int or null"
            )
        if isinstance(self.tags, list):
            object.__setattr__(self, "tags", tuple(self.tags))
        if not isinstance(self.tags, tuple) or not all(isinstance(t, str) and t for t in self.tags):
            raise ValueError(
                f"episode {self.episode_id}: tags must be a tuple of non-empty strings, "
                f"got {self.tags!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "episode_id": self.episode_id,
            "layout_seed": self.layout_seed,
            "seed": self.seed,
            "start": [float(v) for v in self.start],
            "goal": [float(v) for v in self.goal],
            **({"tags": list(self.tags)} if self.tags else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<dict>") -> EpisodeSpec:
        tags = d.get("tags", []) if isinstance(d, dict) else []
        if not isinstance(tags, list) or not all(isinstance(t, str) and t for t in tags):
            raise ValueError(
                f"{source}: episode {d.get('episode_id')!r}: 'tags' must be a list of "
                f"non-empty strings, got {tags!r}"
            )
        try:
            return cls(
                episode_id=str(d["episode_id"]),
                layout_seed=None if d.get("layout_seed") is None else int(d["layout_seed"]),
                start=tuple(float(v) for v in d["start"]),
                goal=tuple(float(v) for v in d["goal"]),
                seed=int(d.get("seed", 0)),
                tags=tuple(tags),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{source}: bad episode entry {d!r}: {e}") from e


@dataclasses.dataclass
class EpisodeSet:
    env_id: str
    episodes: list[EpisodeSpec]

    def save(self, path: str | Path) -> None:
        Path(path).write_text(
            json.dumps(
                {
                    "format": EPISODES_FORMAT,
                    "env_id": self.env_id,
                    "episodes": [e.to_dict() for e in self.episodes],
                },
                indent=1,
            )
        )

    @classmethod
    def load(cls, path: str | Path) -> EpisodeSet:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"episode file {p} does not exist")
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{p}: corrupt episode file (invalid JSON: {e})") from e
        if not isinstance(d, dict) or d.get("format") != EPISODES_FORMAT:
            raise ValueError(
                f"{p}: not a simn-sim episode file (expected format '{EPISODES_FORMAT}')"
            )
        if not isinstance(d.get("episodes"), list) or not d["episodes"]:
            raise ValueError(f"{p}: 'episodes' must be a non-empty list")
        eps = [
            EpisodeSpec.from_dict(e, source=f"{p} episode #{i}")
            for i, e in enumerate(d["episodes"])
        ]
        ids = [e.episode_id for e in eps]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"{p}: duplicate episode ids {dup}")
        return cls(env_id=str(d.get("env_id", "SimnOffice-v0")), episodes=eps)
