"""SIMN front-end: tracking + spatial-implicit local frames + topological map, on RGB-D streams."""

from simn_sim.slam.config import SlamConfig, load_slam_config
from simn_sim.slam.pipeline import SimnSlam, SlamFrame

__all__ = ["SimnSlam", "SlamConfig", "SlamFrame", "load_slam_config"]
