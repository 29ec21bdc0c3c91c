"""The agent interface and registry.

Every agent implements ``reset(obs, info)`` and ``act(obs, info=None) -> action``. ``info`` is
passed to ``act`` only so that the oracle can read the true pose; every other agent must ignore
the true pose and use its own estimate. ``debug()`` returns what the rerun recorder draws
(estimated pose, local frames, topological map, RRT* tree, path, timings) and ``state()`` a short
status (e.g. ``"tracking"``, ``"lost"``, ``"no_plan"``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np


class Agent(Protocol):
    name: str

    def reset(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> None: ...

    def act(self, obs: dict[str, np.ndarray], info: dict[str, Any] | None = None) -> np.ndarray: ...

    def debug(self) -> dict[str, Any]: ...

    def config_dict(self) -> dict[str, Any]: ...


_REGISTRY: dict[str, Callable[..., Agent]] = {}


def register_agent(name: str, factory: Callable[..., Agent]) -> None:
    _REGISTRY[name] = factory


def agent_names() -> list[str]:
    _load_builtin()
    return sorted(_REGISTRY)


def make_agent(name: str, env: Any, config: dict[str, Any] | None = None) -> Agent:
    """Create the agent ``name`` for ``env`` (the unwrapped env gives bounds and, for the
    oracle only, the true map). Unknown names raise ``ValueError`` listing the valid ones."""
    _load_builtin()
    if name not in _REGISTRY:
        raise ValueError(f"unknown agent {name!r}; valid agents: {sorted(_REGISTRY)}")
    return _REGISTRY[name](env, config or {})


def _load_builtin() -> None:
    """Import the built-in agent modules (each registers itself; imports are idempotent)."""
    from simn_sim.agents import oracle, simn  # noqa: F401
