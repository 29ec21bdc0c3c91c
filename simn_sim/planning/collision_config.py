"""Parameters of the 2-D collision model (:mod:`simn_sim.planning.collision`)."""

from __future__ import annotations

import dataclasses
import math

from simn_sim.config import Config, require
from simn_sim.semantics import OBSTACLE

__all__ = ["CollisionConfig"]


@dataclasses.dataclass(frozen=True)
class CollisionConfig(Config):
    """Collision model parameters (metres)."""

    resolution: float = 0.05
    """Grid cell size."""
    robot_radius: float = 0.25
    """Radius of the robot's footprint disk."""
    margin: float = 0.0
    """Extra inflation on top of ``robot_radius`` (e.g. to absorb quantisation or drift)."""
    z_min: float = 0.05
    """Lowest point height (planning frame z, up) that can hit the robot."""
    z_max: float = 1.5
    """Highest point height that can hit the robot."""
    obstacle_labels: tuple[int, ...] = (OBSTACLE,)
    """Semantic labels that count as obstacles (``simn_sim.semantics``: OBSTACLE = 2; FLOOR,
    OVERHEAD and UNKNOWN are ignored)."""
    max_clearance: float = 2.0
    """Clearance values are capped here; the incremental update window is padded by it."""
    grow_padding: float = 2.5
    """When the grid must grow, it grows by this much beyond the new points (at least
    ``max_clearance + resolution``, so that space outside the grid is beyond the cap)."""

    def validate(self) -> None:
        n = type(self).__name__
        require(math.isfinite(self.resolution) and self.resolution > 0, n, "resolution", "> 0")
        require(self.resolution <= 0.5, n, "resolution", "<= 0.5 m (coarser is meaningless)")
        require(
            math.isfinite(self.robot_radius) and self.robot_radius >= 0, n, "robot_radius", ">= 0"
        )
        require(math.isfinite(self.margin) and self.margin >= 0, n, "margin", ">= 0")
        require(math.isfinite(self.z_min) and math.isfinite(self.z_max), n, "z_min", "finite")
        require(self.z_max > self.z_min, n, "z_max", "must exceed z_min")
        require(
            self.max_clearance > self.robot_radius + self.margin,
            n,
            "max_clearance",
            "must exceed robot_radius + margin",
        )
        require(self.grow_padding >= 0, n, "grow_padding", ">= 0")

    @property
    def inflation(self) -> float:
        """Total inflation radius: ``robot_radius + margin``."""
        return self.robot_radius + self.margin
