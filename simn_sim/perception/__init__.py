"""Perception: one RGB-D image -> one :class:`Frame` (the only back-projection of the loop)."""

from simn_sim.perception.frame import Frame, Perception, PerceptionConfig

__all__ = ["Frame", "Perception", "PerceptionConfig"]
