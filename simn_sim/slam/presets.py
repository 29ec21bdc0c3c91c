"""SLAM configs from presets: :meth:`SlamConfig.for_agent` (``agent``, the learned map),
:meth:`SlamConfig.for_points_agent` (``points_agent``, its point-store ablation) and
:meth:`SlamConfig.for_learned_tracking` (``learned_tracking``), changed by the other keys of a
mapping or a YAML file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from simn_sim.config import ConfigError
from simn_sim.slam.config import SlamConfig

__all__ = ["RENAMED_PRESETS", "load_slam_config", "slam_config_from_preset"]

# presets of earlier versions: a config naming one fails with where it went
RENAMED_PRESETS: dict[str, str] = {
    "learned_agent": "the learned map is the agent's default now, preset 'agent'"
    " (the point store: 'points_agent')",
}


def load_slam_config(
    path: str | Path | None, default_preset: str | None = None, **overrides: Any
) -> SlamConfig:
    """A :class:`SlamConfig` from a YAML file (nested mappings per component), or defaults.

    A top-level ``preset`` (:func:`slam_config_from_preset`), else ``default_preset`` (None:
    the plain :class:`SlamConfig` defaults), starts from that preset; the other keys then change
    it (a nested mapping only the keys it names). ``simn-sim slam`` passes
    ``learned_tracking``: offline, the frames are tracked on the learned map by default."""
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config file {p} does not exist")
        try:
            loaded = yaml.safe_load(p.read_text())
        except yaml.YAMLError as e:
            raise ConfigError(f"{p}: not valid YAML ({e})") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{p}: expected a mapping at the top level")
        data = loaded
    data.update(overrides)
    return slam_config_from_preset(data, default=default_preset)


def slam_config_from_preset(data: dict[str, Any], default: str | None) -> SlamConfig:
    """A :class:`SlamConfig` from a mapping whose ``preset`` key (else ``default``; None: the
    plain defaults) names the preset the other keys change: ``point_tracking`` (the plain
    :class:`SlamConfig`: the learned map is trained, tracking uses the surface point store),
    ``agent``
    (:meth:`SlamConfig.for_agent`, the learned map), ``points_agent``
    (:meth:`SlamConfig.for_points_agent`, the point-store ablation) or
    ``learned_tracking`` (:meth:`SlamConfig.for_learned_tracking`)."""
    data = dict(data)
    preset = data.pop("preset", default)
    if preset is None:
        return SlamConfig.from_dict(data)
    presets = {
        "point_tracking": SlamConfig,
        "agent": SlamConfig.for_agent,
        "points_agent": SlamConfig.for_points_agent,
        "learned_tracking": SlamConfig.for_learned_tracking,
    }
    if preset in RENAMED_PRESETS:
        raise ConfigError(f"SlamConfig.preset: {preset!r} was renamed: {RENAMED_PRESETS[preset]}")
    if preset not in presets:
        raise ConfigError(
            f"SlamConfig.preset: unknown preset {preset!r} (one of {sorted(presets)})"
        )
    return presets[preset](**data)
