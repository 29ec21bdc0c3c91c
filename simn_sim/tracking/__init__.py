"""Tracking: SDF registration, local frames, topological map and pose-graph optimisation.

Nothing here needs the learned map: every component is written against small protocols
(``sdf_and_grad`` callables, ``feature_points()`` providers) and is tested on analytic scenes
(:mod:`simn_sim.tracking.synthetic`) and real TUM depth (:mod:`simn_sim.tracking.pointsdf`).
See ``docs/tracking.md``.
"""

from simn_sim.tracking.lie import adjoint, constant_velocity_prior, se3_log
from simn_sim.tracking.localframes import (
    FrameMap,
    FrameTrigger,
    FrameTriggerConfig,
    LocalFrame,
    unpack_feature_points,
)
from simn_sim.tracking.posegraph import (
    PoseGraphConfig,
    PoseGraphResult,
    optimize_anchors,
    optimize_pose_graph,
)
from simn_sim.tracking.registration import RegistrationConfig, RegistrationResult, register
from simn_sim.tracking.topomap import (
    DescriptorConfig,
    FrameDescriptor,
    LoopClosureConfig,
    LoopClosureResult,
    TopoMap,
    close_loop,
    describe,
    registration_callback,
    similarity,
)
from simn_sim.tracking.tracker import FrameTracker

__all__ = [
    "DescriptorConfig",
    "FrameDescriptor",
    "FrameMap",
    "FrameTracker",
    "FrameTrigger",
    "FrameTriggerConfig",
    "LocalFrame",
    "LoopClosureConfig",
    "LoopClosureResult",
    "PoseGraphConfig",
    "PoseGraphResult",
    "RegistrationConfig",
    "RegistrationResult",
    "TopoMap",
    "adjoint",
    "close_loop",
    "constant_velocity_prior",
    "describe",
    "optimize_anchors",
    "optimize_pose_graph",
    "register",
    "registration_callback",
    "se3_log",
    "similarity",
    "unpack_feature_points",
]
