"""Planning: collision model, goal-vector / uniform RRT*, OMPL baseline, topological guidance,
path follower. Everything is in a 2-D planning frame (x-y metres, z up); nothing imports mujoco."""

from simn_sim.planning.collision import CollisionChecker, CollisionConfig
from simn_sim.planning.follower import FollowerCommand, FollowerConfig, PathFollower
from simn_sim.planning.rrt import (
    PlanStats,
    RRTStar,
    RRTStarConfig,
    goal_vector_rrt_star,
    uniform_rrt_star,
)
from simn_sim.planning.samplers import (
    GoalVectorConfig,
    GoalVectorSampler,
    UniformSampler,
    sample_goal_vector,
)
from simn_sim.planning.smoothing import path_length, shortcut_path
from simn_sim.planning.topo import RouteSubgoal, route_subgoal
from simn_sim.planning.tree import Tree

# OMPL is optional: import OmplRRTStar from simn_sim.planning.ompl_rrtstar (clear ImportError on use)

__all__ = [
    "CollisionChecker",
    "CollisionConfig",
    "FollowerCommand",
    "FollowerConfig",
    "PathFollower",
    "RouteSubgoal",
    "route_subgoal",
    "GoalVectorConfig",
    "GoalVectorSampler",
    "PlanStats",
    "RRTStar",
    "RRTStarConfig",
    "Tree",
    "UniformSampler",
    "goal_vector_rrt_star",
    "path_length",
    "sample_goal_vector",
    "shortcut_path",
    "uniform_rrt_star",
]
