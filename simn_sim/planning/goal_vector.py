"""SIMN's goal-vector ray distribution for RRT*: its config and the stateless sampler.

Goal-vector sampling (paper, "Navigation With Local Frames And Topological Map"): instead of the
whole space, sample along the goal vector from the robot (start) to the goal and along
alternative rays at angles ``±alpha, ±2 alpha, ..., ±n_rays alpha`` around it, so the tree grows
towards the goal but can still go around large obstacles. A sample on ray k is

    x = start + t * u(theta) + s * u_perp(theta),   theta = theta_goal + k alpha + dtheta

with ``dtheta ~ U(-angular_spread, angular_spread)``, ``t ~ U(0, t_max)``,
``t_max = max(min_range, range_scale * ||goal - start||)`` and lateral jitter
``s ~ U(-lateral_spread, lateral_spread)``. Rays are drawn with weights ``ray_decay ** |k|`` (the
goal ray most often). Optionally (``tree_anchor_fraction``) the rays are cast from a random tree
node instead of the start. A fraction ``uniform_fraction`` of samples is drawn uniformly over a
local window around start and goal, which keeps the planner probabilistically complete there.
Optionally (``open_rays``, needs the planner's collision checker) each anchor's rays are tested
against the map first and only the open ones are cast.
Samplers that use this distribution are in :mod:`simn_sim.planning.samplers`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from simn_sim.config import Config, require

__all__ = ["GoalVectorConfig", "RaySamples", "sample_goal_vector"]


@dataclasses.dataclass(frozen=True)
class GoalVectorConfig(Config):
    """Goal-vector ray sampling (angles in degrees, distances in metres)."""

    n_rays: int = 6
    """Alternative rays per side: angles 0, ±alpha, ..., ±n_rays * alpha."""
    alpha_deg: float = 25.0
    """Angle between neighbouring rays."""
    ray_decay: float = 0.8
    """Ray k is drawn with weight ray_decay ** |k| (1 = all rays equally likely)."""
    angular_spread_deg: float = 5.0
    """Half-width of the uniform angular jitter of each ray's direction."""
    lateral_spread: float = 0.3
    """Half-width of the uniform lateral jitter around each ray."""
    range_scale: float = 1.3
    """Samples along a ray reach up to range_scale * distance(start, goal) ..."""
    min_range: float = 2.0
    """... but at least this far."""
    radial_power: float = 0.5
    """t = t_max * U(0, 1) ** radial_power: 1 = uniform along the ray, 0.5 = uniform over the
    area of the ray's wedge (fewer samples crowd the start)."""
    uniform_fraction: float = 0.1
    """Fraction of samples drawn uniformly over the local window: the bounding box of start and
    goal padded by ``uniform_margin`` (and clipped to the planner's bounds, if any)."""
    uniform_margin: float = 3.0
    window_stall: int = 100
    """Global stall: after this many samples in a row without the tree getting nearer the goal
    (by ``progress_min``; never once it has reached the goal), the uniform fraction becomes
    ``stall_uniform_fraction`` and the local window's margin doubles, and again after each
    further ``window_stall`` samples, up to the planner's bounds (without bounds: up to
    ``4 * uniform_margin``); progress shrinks it back. 0 = off (fixed window and fraction)."""
    stall_uniform_fraction: float = 0.3
    """``uniform_fraction`` while the window is grown (``window_stall``): a goal-directed
    sampler that has stopped getting nearer is in a trap (a long detour, a door behind it),
    where uniform samples' Voronoi bias finds the way out."""
    tree_anchor_fraction: float = 0.3
    """Fraction of ray samples cast from a random tree node instead of the start (0 and
    ``frontier_anchor_fraction = 0`` = the paper's sampler: rays from the robot only)."""
    frontier_anchor_fraction: float = 0.5
    """Fraction of ray samples cast from the tree node nearest the goal (the frontier)."""
    adaptive_rays: bool = True
    """Per-anchor fan: rays cast from a tree node are ``|k| <= initial_rays +
    visits // stall_samples``, where ``visits`` counts the samples cast from that node that
    brought the tree no closer to the goal (by ``progress_min``): a fresh node aims at the goal,
    a blocked one widens its fan one ray pair per ``stall_samples`` fruitless samples. False:
    all rays always."""
    initial_rays: int = 1
    stall_samples: int = 2
    progress_min: float = 0.05
    visit_penalty: float = 0.05
    """Best-first frontier: the frontier anchor is the tree node with the smallest
    ``distance to goal + visit_penalty * visits`` (metres per fruitless sample cast from it);
    0 = always the node nearest the goal."""
    open_rays: bool = False
    """With a collision checker (``GoalVectorSampler(..., checker=...)``): the fan cast from an
    anchor is made of its *open* rays only, i.e. rays whose first ``open_step`` metres from the
    anchor are free, taken in the order 0, -1, 1, -2, 2, ... (nearest the goal direction
    first); the fan width (``2 level + 1`` rays, ``level`` from the adaptive fan) counts open
    rays. If no ray of the anchor is open, all rays are used. False (or no checker): every ray
    of the fan, blocked or not."""
    open_tree_anchors: bool = False
    """Test rays for being open also from random tree anchors (``tree_anchor_fraction``); False:
    only from the frontier and the start, and rays from random tree nodes stay blind."""
    open_visits: int = 4
    """Rays are tested only while the anchor has fewer fruitless samples than this; after that
    its fan is the blind one (``initial_rays + visits // stall_samples``), as without a checker
    (a ray open at its nominal angle can still fail under the jitter, or when the sample is
    extended from another node: without this, anchors in corners kept drawing on grazing open
    rays)."""
    open_step: float = 0.5
    """Free length a ray needs from its anchor to be open (the planner's ``step_size``)."""
    open_initial_rays: int = 0
    """``initial_rays`` of the adaptive fan when rays are tested for being open: the fan of a
    fresh anchor is its ``2 open_initial_rays + 1`` open rays nearest the goal direction (0:
    the nearest open ray only; the map already says which rays are blocked)."""
    ray_overshoot: float = math.inf
    """With a checker and ``open_rays``: samples on a ray reach at most ``ray_overshoot``
    metres beyond its first blocked point (the free extent of the ray, marched on the
    checker's distance transform); ``inf`` (default) = the whole ray, as without a checker
    (1-3 m gave more iterations and more misses on the simulator maps: the tree crowds the
    walls)."""

    def validate(self) -> None:
        n = type(self).__name__
        require(self.n_rays >= 0, n, "n_rays", ">= 0")
        require(
            math.isfinite(self.alpha_deg) and 0 < self.alpha_deg <= 180,
            n,
            "alpha_deg",
            "in (0, 180]",
        )
        require(0 < self.ray_decay <= 1, n, "ray_decay", "in (0, 1]")
        require(
            math.isfinite(self.angular_spread_deg) and 0 <= self.angular_spread_deg <= 90,
            n,
            "angular_spread_deg",
            "in [0, 90]",
        )
        require(
            math.isfinite(self.lateral_spread) and self.lateral_spread >= 0,
            n,
            "lateral_spread",
            ">= 0",
        )
        require(math.isfinite(self.range_scale) and self.range_scale > 0, n, "range_scale", "> 0")
        require(math.isfinite(self.min_range) and self.min_range > 0, n, "min_range", "> 0")
        require(0 <= self.uniform_fraction < 1, n, "uniform_fraction", "in [0, 1)")
        require(
            math.isfinite(self.radial_power) and self.radial_power > 0, n, "radial_power", "> 0"
        )
        require(
            math.isfinite(self.uniform_margin) and self.uniform_margin >= 0,
            n,
            "uniform_margin",
            ">= 0",
        )
        require(self.window_stall >= 0, n, "window_stall", ">= 0")
        require(0 <= self.stall_uniform_fraction < 1, n, "stall_uniform_fraction", "in [0, 1)")
        require(0 <= self.tree_anchor_fraction <= 1, n, "tree_anchor_fraction", "in [0, 1]")
        require(0 <= self.frontier_anchor_fraction <= 1, n, "frontier_anchor_fraction", "in [0, 1]")
        require(
            self.tree_anchor_fraction + self.frontier_anchor_fraction <= 1,
            n,
            "frontier_anchor_fraction",
            "tree + frontier anchor fractions must be <= 1",
        )
        require(0 <= self.initial_rays <= self.n_rays, n, "initial_rays", "in [0, n_rays]")
        require(self.stall_samples >= 1, n, "stall_samples", ">= 1")
        require(
            math.isfinite(self.progress_min) and self.progress_min >= 0, n, "progress_min", ">= 0"
        )
        require(
            math.isfinite(self.visit_penalty) and self.visit_penalty >= 0,
            n,
            "visit_penalty",
            ">= 0",
        )
        require(math.isfinite(self.open_step) and self.open_step > 0, n, "open_step", "> 0")
        require(
            0 <= self.open_initial_rays <= self.n_rays, n, "open_initial_rays", "in [0, n_rays]"
        )
        require(self.open_visits >= 0, n, "open_visits", ">= 0")
        require(
            not math.isnan(self.ray_overshoot) and self.ray_overshoot >= 0,
            n,
            "ray_overshoot",
            ">= 0 (inf allowed)",
        )

    def ray_offsets(self) -> np.ndarray:
        """(2 n_rays + 1,) ray indices k = 0, -1, 1, -2, 2, ... (angle = k * alpha)."""
        ks = [0]
        for k in range(1, self.n_rays + 1):
            ks += [-k, k]
        return np.array(ks, dtype=np.int64)


class RaySamples(NamedTuple):
    """Goal-vector samples and how they were drawn (for inspection and tests)."""

    xy: np.ndarray
    """(N, 2) sample positions, planning frame."""
    ray: np.ndarray
    """(N,) int ray index k (angle k * alpha from the goal vector)."""
    t: np.ndarray
    """(N,) distance along the ray."""
    lateral: np.ndarray
    """(N,) signed lateral offset from the (jittered) ray direction."""
    dtheta: np.ndarray
    """(N,) angular jitter (rad) of the direction from the ray's nominal angle."""


def sample_goal_vector(
    rng: np.random.Generator,
    start: np.ndarray,
    goal: np.ndarray,
    cfg: GoalVectorConfig,
    n: int,
) -> RaySamples:
    """Draw n samples on the goal-vector rays from ``start`` (2,) towards ``goal`` (2,)."""
    start = np.asarray(start, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    v = goal - start
    dist = float(np.hypot(*v))
    theta0 = math.atan2(v[1], v[0]) if dist > 1e-12 else 0.0
    ks = cfg.ray_offsets()
    w = cfg.ray_decay ** np.abs(ks).astype(np.float64)
    ray = rng.choice(ks, size=n, p=w / w.sum())
    t_max = max(cfg.min_range, cfg.range_scale * dist)
    t = t_max * rng.random(n) ** cfg.radial_power
    lat = rng.uniform(-cfg.lateral_spread, cfg.lateral_spread, size=n)
    jit = rng.uniform(-1.0, 1.0, size=n) * math.radians(cfg.angular_spread_deg)
    th = theta0 + ray * math.radians(cfg.alpha_deg) + jit
    c, s = np.cos(th), np.sin(th)
    xy = start + np.stack([t * c - lat * s, t * s + lat * c], axis=1)
    return RaySamples(xy, ray, t, lat, jit)
