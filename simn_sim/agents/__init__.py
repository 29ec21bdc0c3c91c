"""Agents: ``make_agent("oracle" | "simn" | "rrtstar", env, config)``.

:mod:`simn_sim.agents.base` holds the interface and the registry and imports no agent; each
agent module registers itself there when it is imported. This package module is the facade
that knows the built-in agent modules and imports them on first use (they are heavy: the
``simn`` agent pulls in the SLAM front-end), so the dependencies run one way:
facade -> agent modules -> base.
"""

from __future__ import annotations

from typing import Any

from simn_sim.agents.base import Agent, register_agent, registered

__all__ = ["Agent", "agent_names", "make_agent", "register_agent"]


def _load_builtin() -> None:
    """Import the built-in agent modules (each registers itself; imports are idempotent):
    ``oracle``, ``simn`` (which also registers ``rrtstar``)."""
    import simn_sim.agents.oracle  # noqa: F401
    import simn_sim.agents.simn  # noqa: F401


def agent_names() -> list[str]:
    """Every registered agent name, built-ins included, sorted."""
    _load_builtin()
    return sorted(registered())


def make_agent(name: str, env: Any, config: dict[str, Any] | None = None) -> Agent:
    """Create the agent ``name`` for ``env`` (the unwrapped env gives bounds and, for the
    oracle only, the true map). Unknown names raise ``ValueError`` listing the valid ones."""
    _load_builtin()
    factories = registered()
    if name not in factories:
        raise ValueError(f"unknown agent {name!r}; valid agents: {sorted(factories)}")
    return factories[name](env, config or {})
