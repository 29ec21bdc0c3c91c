"""SIMN front-end: tracking + spatial-implicit local frames + topological map, on RGB-D streams."""

from simn_sim.slam.config import SlamConfig
from simn_sim.slam.pipeline import SimnSlam, SlamFrame
from simn_sim.slam.presets import load_slam_config

__all__ = ["SimnSlam", "SlamConfig", "SlamFrame", "load_slam_config"]
