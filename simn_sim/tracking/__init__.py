"""Tracking: SDF registration, local frames, topological map and pose-graph optimisation.

Nothing here needs the learned map: every component is written against small protocols
(``sdf_and_grad`` callables, ``feature_points()`` providers) and is tested on analytic scenes.
"""

from simn_sim.tracking.lie import adjoint, constant_velocity_prior, se3_log
from simn_sim.tracking.registration import RegistrationConfig, RegistrationResult, register

__all__ = [
    "RegistrationConfig",
    "RegistrationResult",
    "adjoint",
    "constant_velocity_prior",
    "register",
    "se3_log",
]
