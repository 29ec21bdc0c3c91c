"""The world model the agent reads: pose, local frames, the planner's obstacle view, topology.

Two implementations (:func:`make_world`): :class:`~simn_sim.world.slam_world.SlamWorld` (the
SIMN front-end: tracking, local frames, topological map, revisits; ``pose_source: slam``) and
:class:`~simn_sim.world.odometry_world.OdometryWorld` (the ablation without the front-end: the
wheel-odometry pose and one local frame; ``pose_source: odometry``). Both perceive once per
step (:class:`~simn_sim.perception.Frame`), keep their points in
:class:`~simn_sim.slam.frames.LocalFrames` and feed the same :class:`ObstacleMap`. Coordinates:
the agent's own frame (the episode start frame, z up, floor at z = 0).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np

from simn_sim.slam.frames import LocalFrames
from simn_sim.tracking.topomap import TopoMap
from simn_sim.world.obstacles import ObstacleMap


@dataclasses.dataclass
class WorldStep:
    """What one :meth:`WorldModel.update` did. T_world_base: (4, 4) estimated base pose (agent
    frame); track_ok: the pose came from a successful registration (always True without
    tracking); revisit: a revisit was accepted (anchors moved); track_ms / map_ms: timings."""

    T_world_base: np.ndarray
    track_ok: bool
    revisit: bool
    track_ms: float | None
    map_ms: float | None


class WorldModel(Protocol):
    """What the agent reads (see the module docstring)."""

    obstacles: ObstacleMap

    def update(self, t: float, obs: dict[str, np.ndarray], T_odom: np.ndarray) -> WorldStep:
        """Perceive -> (track) -> integrate -> (topology) with one observation; ``T_odom``:
        (4, 4) wheel-odometry base pose in the agent frame."""
        ...

    @property
    def pose(self) -> np.ndarray:
        """(4, 4) latest estimated base pose ``T_world_base`` (agent frame)."""
        ...

    def close(self) -> None:
        """Release what outlives a call (the learned map's training thread); idempotent."""
        ...

    @property
    def frames(self) -> LocalFrames:
        """The local frames, their point stores and carving."""
        ...

    @property
    def topology(self) -> TopoMap:
        """The topological map over the local frames."""
        ...

    @property
    def current_frame_id(self) -> int: ...

    def counters(self) -> dict[str, int]:
        """Fallbacks and events of the episode so far (go into the episode record)."""
        ...

    def revisit_events(self) -> dict[str, Any] | None:
        """Frame opening times, accepted revisits and their arcs (see ``SlamWorld``), or None
        where nothing checks revisits."""
        ...

    def debug(self) -> dict[str, Any]:
        """Recording data (local frames, topology, estimated pose) in the agent frame."""
        ...
