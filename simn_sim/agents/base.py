"""The agent interface and registry (no agent is imported here: see :mod:`simn_sim.agents`).

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

    def debug(self) -> dict[str, Any]:
        """What the rerun recorder draws (``"frame": "start"``: in the agent's own frame)."""
        ...

    def config_dict(self) -> dict[str, Any]:
        """The resolved config, written beside every result."""
        ...

    def state(self) -> str:
        """A short status, e.g. ``"following"``, ``"no_plan"``, ``"recovering"``."""
        ...

    def counters(self) -> dict[str, int]:
        """Fallbacks and events of the episode so far (plan failures, grid fallbacks, bumps,
        tracking failures, revisits, ...); the runner copies them into the episode record."""
        ...

    def close(self) -> None:
        """Optional: release per-episode resources (threads); the runner calls it, when the
        agent has it, after every episode, failed ones included."""
        ...


_REGISTRY: dict[str, Callable[..., Agent]] = {}


def register_agent(name: str, factory: Callable[..., Agent]) -> None:
    """Register ``factory(env, config) -> Agent`` under ``name`` (an agent module does this
    when it is imported; a later registration of the same name replaces the earlier one)."""
    _REGISTRY[name] = factory


def registered() -> dict[str, Callable[..., Agent]]:
    """The agents registered so far, by name (a copy). Use :func:`simn_sim.agents.make_agent`
    and :func:`simn_sim.agents.agent_names`, which import the built-in agents first."""
    return dict(_REGISTRY)
