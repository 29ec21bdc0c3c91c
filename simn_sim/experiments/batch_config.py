"""The batch's typed config (:class:`BatchConfig`), its error type and config resolution."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from simn_sim.config import Config, ConfigError

__all__ = ["BatchConfig", "BatchError", "load_yaml", "resolve_env_config"]

BACKENDS = ("local", "ray")
RAY_MISSING = "--backend ray needs Ray: pip install 'simn-sim[ray]' (or 'ray[default]')"


class BatchError(ValueError):
    """Bad batch input or an output folder that cannot be resumed; the message says why."""


@dataclasses.dataclass(frozen=True)
class BatchConfig(Config):
    """One batch invocation (what the CLI parses into); frozen and checked on construction.

    Exactly one of ``episode_file`` and ``n_episodes`` is given. ``env_config`` holds env config
    values that override the env id's registered defaults; ``workers=0`` runs in-process.
    ``out`` and ``episode_file`` may be given as strings. Invalid values raise
    :class:`BatchError`; ``cfg.replace(workers=0)`` gives a changed copy.
    """

    out: Path
    agent: str
    env_id: str | None = None
    n_episodes: int | None = None
    seed: int = 0
    episode_file: Path | None = None
    tag: str | None = None  # run only the episode file's episodes carrying this tag
    workers: int = 1
    backend: str = "local"
    rerun: bool = False
    env_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    agent_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    ray_address: str | None = None
    threads_per_worker: int = 1
    # worker processes are replaced after about this many episodes each (a local pool of W
    # processes runs at most this x W; a Ray worker this many); 0: never. Their memory grows
    # with each episode (see batch_local)
    episodes_per_worker: int = 8
    progress: bool = True
    plots: bool = True
    argv: list[str] | None = None

    def __post_init__(self) -> None:
        for name in ("out", "episode_file"):
            v = getattr(self, name)
            if isinstance(v, str):
                object.__setattr__(self, name, Path(v))
        for name in ("env_config", "agent_config"):  # a copy: the caller's dict stays theirs
            v = getattr(self, name)
            if not isinstance(v, dict):
                raise BatchError(f"{name} must be a mapping, got {type(v).__name__}")
            object.__setattr__(self, name, dict(v))
        if not isinstance(self.out, Path):
            raise BatchError(f"out must be a path, got {self.out!r}")
        try:
            super().__post_init__()
        except ConfigError as e:
            raise BatchError(str(e)) from e

    def validate(self) -> None:
        if (self.episode_file is None) == (self.n_episodes is None):
            raise BatchError("give exactly one of --episodes N and --episode-file F")
        if self.tag is not None and self.episode_file is None:
            raise BatchError("--tag selects from an episode file; give --episode-file")
        if self.n_episodes is not None and self.n_episodes < 1:
            raise BatchError(f"--episodes must be >= 1, got {self.n_episodes}")
        if self.workers < 0:
            raise BatchError(f"--workers must be >= 0, got {self.workers}")
        if self.backend not in BACKENDS:
            raise BatchError(f"--backend must be 'local' or 'ray', got {self.backend!r}")
        if self.backend == "ray" and self.workers < 1 and self.ray_address is None:
            raise BatchError("--backend ray needs --workers >= 1 (or --ray-address)")
        if self.episodes_per_worker < 0:
            raise BatchError(
                f"--episodes-per-worker must be >= 0 (0: no limit), got {self.episodes_per_worker}"
            )
        if self.threads_per_worker < 1:
            raise BatchError(f"--threads-per-worker must be >= 1, got {self.threads_per_worker}")
        if self.backend == "ray":
            import importlib.util

            if importlib.util.find_spec("ray") is None:
                raise BatchError(RAY_MISSING)


def resolve_env_config(env_id: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The full env config for ``env_id``: its registered defaults, then ``overrides``.

    Raises:
        BatchError: unknown env id or an invalid config value (the message names the field).
    """
    import gymnasium as gym

    import simn_sim  # noqa: F401
    from simn_sim.env.office import EnvConfig

    try:
        spec = gym.spec(env_id)
    except gym.error.Error as e:
        ids = sorted(k for k in gym.registry if k.startswith("Simn"))
        raise BatchError(f"unknown env id {env_id!r}; valid ids: {ids}") from e
    try:
        return EnvConfig.from_dict({**(spec.kwargs or {}), **overrides}).to_dict()
    except ConfigError as e:
        raise BatchError(f"env config: {e}") from e


def load_yaml(path: str | Path | None, what: str) -> dict[str, Any]:
    """The mapping in the YAML file ``path`` ({} for None); ``what`` names it in errors."""
    if path is None:
        return {}
    import yaml

    try:
        d = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise BatchError(f"cannot read {what} file {path}: {e}") from e
    if not isinstance(d, dict):
        raise BatchError(f"{what} file {path} must hold a mapping, got {type(d).__name__}")
    return d
