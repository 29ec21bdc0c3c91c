"""Spatial-implicit mapping (SIMN): neural points, ray sampling, SDF decoder, continual learning.

Imports nothing from ``mujoco``; everything is testable on synthetic arrays.
"""

from simn_sim.mapping.config import (
    DecoderConfig,
    MapperConfig,
    NeuralPointsConfig,
    PerceptionConfig,
    SamplingConfig,
    TrainingConfig,
)
from simn_sim.mapping.decoder import Decoder
from simn_sim.mapping.mapper import (
    FrameResult,
    ImplicitMap,
    MapFileError,
    SdfQuery,
    TrainResult,
    check_pose,
)
from simn_sim.mapping.mesh import Mesh, extract_mesh, log_mesh
from simn_sim.mapping.neural_points import FeaturePoints, NeuralPointMap
from simn_sim.mapping.perception import (
    EmptyFrameError,
    PointCloud,
    rgbd_to_points,
    voxel_downsample,
)
from simn_sim.mapping.sampling import BEHIND, FRONT, SURFACE, RaySamples, sample_rays

__all__ = [
    "BEHIND",
    "FRONT",
    "SURFACE",
    "Decoder",
    "DecoderConfig",
    "EmptyFrameError",
    "FeaturePoints",
    "FrameResult",
    "ImplicitMap",
    "MapFileError",
    "MapperConfig",
    "Mesh",
    "NeuralPointMap",
    "NeuralPointsConfig",
    "PerceptionConfig",
    "PointCloud",
    "RaySamples",
    "SamplingConfig",
    "SdfQuery",
    "TrainResult",
    "TrainingConfig",
    "check_pose",
    "extract_mesh",
    "log_mesh",
    "rgbd_to_points",
    "sample_rays",
    "voxel_downsample",
]
