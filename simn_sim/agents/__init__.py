"""Agents: ``make_agent("oracle" | "simn" | "rrtstar", env, config)``."""

from simn_sim.agents.base import Agent, agent_names, make_agent, register_agent

__all__ = ["Agent", "agent_names", "make_agent", "register_agent"]
