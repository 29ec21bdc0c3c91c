"""Typed config of the SIMN front-end (:class:`~simn_sim.slam.pipeline.SimnSlam`).

One frozen dataclass holding the per-component configs it composes (mapper, registration,
local-frame trigger, loop closure, pose graph, floor classifier) plus the pipeline's own knobs.
``SlamConfig.for_agent()`` is the closed-loop agent's preset (the learned map, 320x240);
``SlamConfig.for_points_agent()`` its point-store ablation.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

from simn_sim.config import Config, ConfigError, require
from simn_sim.mapping.config import (
    DecoderConfig,
    MapperConfig,
    NeuralPointsConfig,
    TrainingConfig,
)
from simn_sim.perception.frame import PerceptionConfig
from simn_sim.perception.manhattan import WallHeadingConfig
from simn_sim.semantics import FloorClassifierConfig
from simn_sim.tracking.localframes import FrameTriggerConfig
from simn_sim.tracking.posegraph import PoseGraphConfig
from simn_sim.tracking.registration import RegistrationConfig
from simn_sim.tracking.topomap import DescriptorConfig, LoopClosureConfig

# Keys of the flat SlamConfig before the world-model redesign and where they live now: a config
# written by the old code fails with a message naming the new place (see ``SlamConfig.from_dict``).
MOVED_KEYS: dict[str, str] = {
    "pixel_stride": "perception.stride",
    "min_depth": "perception.min_depth",
    "max_depth": "perception.max_depth",
    "normal_smooth_px": "perception.normal_smooth_px",
    "implicit_normal_smooth_px": "perception.map_normal_smooth_px",
    "track_degeneracy_ratio": "track_registration.degeneracy_ratio",
    "track_min_valid_fraction": "track_registration.min_valid_fraction",
    "implicit_grad_norm_min": "track_registration.grad_norm_min",
    "max_correction_m": "track_max_correction_m",
    "max_correction_deg": "track_max_correction_deg",
    "describe_max_points": "descriptor.max_points",
    "obstacle_voxel": "stores.obstacle_voxel",
    "floor_voxel": "stores.floor_voxel",
    "carve": "stores.carve",
    "carve_margin": "stores.carve_margin",
    "carve_frames": "stores.carve_frames",
}


@dataclasses.dataclass(frozen=True)
class StoreConfig(Config):
    """Per-local-frame obstacle / floor point stores (anchor coordinates) and free-space carving:
    stored obstacle points of the ``carve_frames`` most recent local frames (0, the default:
    every local frame) that the current depth image sees *through* (its depth there exceeds
    the point's by ``carve_margin``) are removed, so a person who walked away does not stay an
    obstacle, nor an older frame's copy of a wall that drift between the frames' anchors put
    into a doorway."""

    obstacle_voxel: float = 0.05
    floor_voxel: float = 0.10
    carve: bool = True
    carve_margin: float = 0.10
    carve_frames: int = 0

    def validate(self) -> None:
        n = type(self).__name__
        for f in ("obstacle_voxel", "floor_voxel", "carve_margin"):
            v = getattr(self, f)
            require(math.isfinite(v) and v > 0, n, f, f"must be > 0, got {v}")
        require(self.carve_frames >= 0, n, "carve_frames", "must be >= 0 (0: every frame)")


def merge_changes(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``changes`` applied; a nested mapping changes only the keys it names, at
    every depth (``mapper: {decoder: {residual: false}}`` keeps the preset's other decoder
    settings)."""
    out = dict(base)
    for k, v in changes.items():
        b = out.get(k)
        out[k] = merge_changes(b, v) if isinstance(v, dict) and isinstance(b, dict) else v
    return out


def tracking_mapper_config() -> MapperConfig:
    """The front-end's learned map: :class:`MapperConfig` defaults plus the decoder's geometric
    prior (each neural point's mean surface plane; the MLP learns a residual on it) on 2 cm
    neural points, Gaussian neighbour weights (2 cm, 8 neighbours), BCE sigma 2 cm and a
    Gaussian prior on the residual (``residual_weight`` 1). Why (docs/mapping.md and
    docs/slam.md, "Learned map for tracking"): with the plain decoder the zero level set was
    6-9 mm off after the training this CPU affords and tracking on it gave 3.5 cm ATE on the
    desk; the prior is exact on planes from the first observation; IDW blending followed the
    nearest neural point's noisy plane; 5 cm neural points blur the surface (maps built at the
    true poses, noisy desk: median |SDF| 5.7 mm at the true pose against 3.1 mm at 2 cm); and
    the unconstrained residual fits the depth noise (6.7 mm with it, 3.5 mm with
    ``residual_weight`` 1)."""
    base = MapperConfig()
    return dataclasses.replace(
        base,
        decoder=dataclasses.replace(base.decoder, geometric_prior=True, prior_normal_gate_deg=60.0),
        points=dataclasses.replace(
            base.points, voxel_size=0.02, k_neighbors=8, weighting="gaussian", gaussian_width=0.02
        ),
        training=dataclasses.replace(base.training, sigma=0.02, residual_weight=1.0),
    )


@dataclasses.dataclass(frozen=True)
class SlamConfig(Config):
    """Settings of :class:`~simn_sim.slam.pipeline.SimnSlam` (lengths in metres).

    Perception: every ``pixel_stride``-th pixel (0: automatic, about 160 columns) in
    ``[min_depth, max_depth]``; registration points on a ``track_voxel`` grid, at most
    ``max_track_points`` (random subset, explicit RNG seeded with ``seed``); the mapper
    down-samples its own input at ``mapper.integrate_voxel_size`` (3 cm).
    """

    perception: PerceptionConfig = PerceptionConfig(map_normal_smooth_px=1)
    track_voxel: float = 0.06
    max_track_points: int = 4000
    # which of the voxels' points register when there are more than max_track_points: "random"
    # (a uniform subset) or "normals" (spread evenly over the normal directions, Tracker)
    track_point_selection: Literal["random", "normals"] = "random"
    # mapping: the first observation of a frame trains ``open_train_iters`` (so the next frame
    # can register against it); afterwards every ``train_every``-th frame ``train_iters``.
    train_every: int = 5
    open_train_iters: int = 150
    train_iters: int = 40
    # learned map: one decoder F_theta for all local frames, learned continually (EWC Fisher
    # summed over closed frames, replay of closed frames' samples; docs/mapping.md,
    # "Forgetting in the pipeline"); False: each new frame's decoder starts as a copy of the
    # previous frame's and is never trained again once its frame closes (nothing to forget)
    share_decoder: bool = True
    # per-frame map: "implicit" = the learned ImplicitMap (the paper); "points" = no learning
    # (a surface voxel store with normals; the cheap path).
    map_kind: Literal["implicit", "points"] = "implicit"
    # tracking: which SDF a frame is registered against.
    #   "implicit": the local frame's learned map (the paper's method; needs map_kind implicit);
    #   "points": point-to-plane SDF of the local frame's surface store (surface_voxel grid,
    #   first observation per voxel kept, normals from the organised depth image).
    track_sdf: Literal["implicit", "points"] = "points"
    # implicit tracking: a point further than this along the surface from its neighbours'
    # plane points has no SDF (the map's own validity is its 15 cm search radius, over which the
    # planes at the map's edge are extrapolated and pull the frame; the point store uses 3 cm).
    # Measured (docs/slam.md): 15 cm radius: noise-free corridor 4.4 cm; 4 cm along the surface:
    # desk 0.24 / 2.56 cm (D435i); 3 cm to the nearest neural point: corridor 0.50 / 0.44 cm but
    # the desk diverged (36 / 55 cm)
    implicit_max_dist: float = 0.04
    # the distance (m) a point may move before its k neural-point neighbours are searched again
    # (0: every LM iteration; the search is ~70 % of a query)
    implicit_reuse_neighbors: float = 0.02
    # implicit tracking through an SDF cache (mapping/sdf_cache.py): the map's SDF and gradient
    # baked on a sparse grid of this edge (m) where the registration points fall, the LM
    # iterations interpolate it (first-order Taylor blend, exact on planes); 0: the network at
    # every LM iteration. Off by default: re-baked every frame (the map changes every frame)
    # it evaluates the network about as often as LM does (docs/tracking.md)
    implicit_cache_voxel: float = 0.0
    # train the learned map on a worker thread while the caller plans and steps; the next
    # frame joins it before tracking (same poses as synchronous training, slam/trainer.py)
    train_async: bool = False
    # frames a training chunk lags tracking. 0: frame t+1 joins the chunk of frame t before it
    # tracks (tracks against the map trained on frame t). 1: frame t+1 tracks against the map as
    # it was before that chunk (trained on frames up to t-1) and joins the chunk after
    # tracking, so with ``train_async`` the chunk also overlaps the next frame's perception and
    # tracking; the same poses with and without ``train_async`` either way (slam/trainer.py)
    train_latency: int = 0
    surface_voxel: float = 0.02
    surface_keep: Literal["first", "mean"] = "mean"  # per-voxel model point: first or average
    track_max_depth: float = 4.0  # registration points up to this depth (stereo noise ~ z^2;
    # 2.5 m halves the D435i-noise ATE on the desk but loses the far walls that constrain
    # corridors, docs/slam.md)
    # a point further than this from the surface store has no SDF (invalid): beyond the
    # store's coverage, nearest-point residuals pull the frame back towards the covered part
    point_sdf_max_dist: float = 0.03
    # point SDF of the surface store: 0 = the nearest stored point's plane; h > 0 = implicit
    # MLS surface (Gaussian kernel of width h over the point_sdf_k nearest stored points):
    # continuous, and zero on the surface of a store that depth noise spread into a slab
    # (where the nearest point's plane is flat and registration stalls; docs/tracking.md).
    # Noise-adaptive width: h = clip(point_sdf_kernel_rms_factor x the running inlier RMS of
    # the registrations, point_sdf_kernel_min, point_sdf_kernel) -- wide on noisy depth, near
    # the nearest-point SDF on exact depth; factor 0: always point_sdf_kernel
    point_sdf_kernel: float = 0.03
    point_sdf_kernel_min: float = 0.005
    point_sdf_kernel_rms_factor: float = 4.0
    point_sdf_k: int = 8
    point_sdf_count_weight: bool = False  # kernel weights times the voxel's observation count
    point_sdf_normal_gate_deg: float = 60.0  # kernel neighbours within this angle of the
    # nearest point's normal (keeps creases sharp); 180: all
    c2f: bool = False  # kernel SDF: register with the widest kernel first, then the adaptive
    loop_kernel: bool = False  # revisit checks use the tracking kernel too (else nearest point)
    loop_sdf_max_dist: float = 0.15  # validity radius of the point SDF in revisit checks
    sdf_rebuild_growth: float = 0.1  # rebuild the point SDF when the store grew by this share
    # Tracking registration (revisit checks use the strict ``registration``). A weakly
    # constrained frame (a corridor: walls + floor) is not rejected; instead the registration is
    # fused with the motion prediction through its covariance, so the prediction fills in the
    # degenerate directions.
    track_registration: RegistrationConfig = RegistrationConfig(
        degeneracy_ratio=1e-7, min_valid_fraction=0.2
    )
    fuse_prior: bool = True
    # the registration's covariance (sigma^2 (J^T W J)^-1, which takes every residual as
    # independent) is multiplied by this in the fusion with the motion prior
    track_cov_scale: float = 1.0
    # > 0: the factor on the translation block instead (the rotation block keeps
    # track_cov_scale; the cross terms take the geometric mean); 0: track_cov_scale throughout
    track_cov_scale_trans: float = 0.0
    weak_ratio: float = 1e-2  # information eigenvalues below this share of the largest: dropped
    prior_sigma_rot_deg: float = 1.5  # constant-velocity prediction uncertainty per frame
    prior_sigma_trans: float = 0.03  # m
    odom_prior_sigma_rot_deg: float = 0.3  # an external (wheel odometry) increment per frame
    odom_prior_sigma_trans: float = 0.005  # m
    # growth of the odometry increment's sigma with the motion (Tracker.odom_info): rad per
    # (rad turned + m travelled), m per m travelled; 0: the constant sigmas above
    odom_prior_sigma_rot_per_unit: float = 0.0
    odom_prior_sigma_trans_per_m: float = 0.0
    # registration weights: inverse variance of a point's depth noise, sigma(z) = depth_sigma0
    # + depth_sigma_per_m2 z^2 (stereo depth error grows with z^2); 0 per m^2: equal weights
    depth_sigma0: float = 0.003
    depth_sigma_per_m2: float = 0.0
    # innovation gate: a fused correction beyond this Mahalanobis distance under the motion
    # prior's covariance is rejected (the prediction is kept); 0 disables
    gate_sigmas: float = 12.0
    # odometry consistency over a window: the tracked motion over the last odom_window
    # frames (this one included) against the odometry's over the same frames, in sigmas of the
    # odometry increments' (odom_prior_sigma_*) summed variances, largest of rotation and
    # translation; beyond odom_window_sigmas the pose is the odometry's from the window's
    # start (a registration that slid step by step inside gate_sigmas: a corridor, a person in
    # view). 0 frames: no window test; needs odometry priors
    odom_window: int = 0
    odom_window_sigmas: float = 5.0
    # a tracking registration moving the prediction further is rejected (revisit checks have
    # their own, wider budget: loop.max_correction_*)
    track_max_correction_m: float = 0.3
    track_max_correction_deg: float = 20.0
    # odometry arcs between consecutive anchors: sigma = base + per-unit growth
    odom_sigma_rot: float = 0.005  # rad
    odom_sigma_rot_per_rad: float = 0.02
    odom_sigma_trans: float = 0.005  # m
    odom_sigma_trans_per_m: float = 0.02
    revisits: bool = True
    # 0: all revisit candidates are checked when a frame opens (a 100-600 ms step on 2 CPU
    # cores); k > 0: k candidates per following frame (bounded work per control step)
    revisit_checks_per_frame: int = 0
    # k > 0: a deferred check instead runs at most k registrations per following frame (each
    # candidate's yaw search is spread over frames too; same result as checking at once, since
    # the observation and its pose, the frame's anchor, are kept); overrides the above
    revisit_registrations_per_frame: int = 0
    # with revisit_registrations_per_frame: a check still running when the next frame opens
    # is finished first (the new one waits, replacing an older waiting one) instead of dropped
    revisit_finish_checks: bool = False
    # a revisit candidate is checked only when at least this fraction of the observation lies
    # in its region (x-y box) grown by loop.max_correction_m (the check's drift budget: with
    # less overlap the registration cannot pass it); 0: every descriptor candidate is checked
    revisit_min_overlap: float = 0.0
    # how revisit candidates are ranked before registration verifies them:
    #   "learned": the new frame's learned key points matched to each earlier frame's by their
    #   feature vectors (descriptors.KeyPointIndex; needs map_kind implicit);
    #   "keypoints": the same matching without the features (share of key points in reach);
    #   "geometric": the frames' pooled descriptors (occupancy grid + shape histograms);
    #   "auto": learned with map_kind implicit, geometric with points
    revisit_features: Literal["auto", "learned", "keypoints", "geometric"] = "auto"
    # what a revisit check registers against: "tracking" (the SDF tracking uses: the learned
    # map with track_sdf implicit) or "points" (the frame's surface store, nearest point's
    # plane, with the wider loop_sdf_max_dist)
    revisit_sdf: Literal["tracking", "points"] = "tracking"
    semantics: bool = True  # floor / obstacle labels (needs T_base_cam: the floor plane)
    # the camera rides a ground robot on a flat floor: every pose estimate (and every anchor
    # after a pose-graph correction) is projected onto the plane of the first frame's base
    # (base z, roll and pitch those of the first frame; x, y and yaw kept). Needs T_base_cam.
    # Off for a hand-held camera. Unconstrained, the agent's 6-DoF estimate drifted 0.41 m
    # down and 1.8 deg in pitch over nav2-ref-005, so the low box ahead sank below the
    # obstacle band of the planner's model and the robot drove into it (docs/tracking.md)
    planar: bool = False
    # with planar: tracking and the revisit checks register on the plane (yaw, x, y; Tracker),
    # and tracking fuses the odometry there, instead of projecting a 6-DoF optimum afterwards,
    # which kept the x-y of an optimum that pitch and height had pulled
    planar_registration: bool = False
    # torch intra-op threads while the pipeline runs (restored afterwards); 0 leaves torch's
    # setting. 1 is the default: on the shared 2-core CPU, 2 threads made training ~30x and
    # SDF queries ~3-40x slower under load (OpenMP threads contending with other processes).
    torch_threads: int = 1
    seed: int = 0
    stores: StoreConfig = StoreConfig()
    descriptor: DescriptorConfig = DescriptorConfig()
    mapper: MapperConfig = dataclasses.field(default_factory=MapperConfig)
    registration: RegistrationConfig = dataclasses.field(default_factory=RegistrationConfig)
    trigger: FrameTriggerConfig = dataclasses.field(default_factory=FrameTriggerConfig)
    loop: LoopClosureConfig = dataclasses.field(default_factory=LoopClosureConfig)
    pose_graph: PoseGraphConfig = dataclasses.field(default_factory=PoseGraphConfig)
    classifier: FloorClassifierConfig = dataclasses.field(default_factory=FloorClassifierConfig)
    # heading held to the walls' direction (modulo 90 deg) between local frames; needs planar
    heading: WallHeadingConfig = dataclasses.field(default_factory=WallHeadingConfig)

    def validate(self) -> None:
        n = type(self).__name__
        # the standalone mapper's own perception and training schedule are not used by the
        # front-end (it perceives once per frame with ``perception`` and trains per
        # ``open_train_iters`` / ``train_iters`` / ``train_every``): setting them is an error
        default = MapperConfig()
        require(
            self.mapper.perception == default.perception,
            n,
            "mapper.perception",
            "is not used by the front-end; set SlamConfig.perception instead",
        )
        require(
            self.mapper.training.train_every == default.training.train_every,
            n,
            "mapper.training.train_every",
            "is not used by the front-end; set SlamConfig.train_every instead",
        )
        require(
            self.perception.normal_smooth_px >= 0,
            n,
            "perception.normal_smooth_px",
            "must be >= 0: tracking, labels and the surface store need normals",
        )
        require(
            not (self.track_sdf == "implicit" and self.map_kind == "points"),
            n,
            "track_sdf",
            "'implicit' tracking needs map_kind 'implicit'",
        )
        require(self.sdf_rebuild_growth >= 0, n, "sdf_rebuild_growth", "must be >= 0")
        require(self.implicit_reuse_neighbors >= 0, n, "implicit_reuse_neighbors", ">= 0")
        require(self.implicit_max_dist > 0, n, "implicit_max_dist", "must be > 0")
        require(self.implicit_cache_voxel >= 0, n, "implicit_cache_voxel", "must be >= 0")
        for f in (
            "track_voxel",
            "surface_voxel",
            "point_sdf_max_dist",
        ):
            v = getattr(self, f)
            require(math.isfinite(v) and v > 0, n, f, f"must be > 0, got {v}")
        require(
            math.isfinite(self.point_sdf_kernel) and self.point_sdf_kernel >= 0,
            n,
            "point_sdf_kernel",
            "must be >= 0 (0: nearest point)",
        )
        require(self.point_sdf_k >= 1, n, "point_sdf_k", "must be >= 1")
        require(
            0 < self.point_sdf_kernel_min <= max(self.point_sdf_kernel, self.point_sdf_kernel_min),
            n,
            "point_sdf_kernel_min",
            "must be > 0 and <= point_sdf_kernel",
        )
        require(self.point_sdf_kernel_rms_factor >= 0, n, "point_sdf_kernel_rms_factor", ">= 0")
        require(
            0 < self.point_sdf_normal_gate_deg <= 180, n, "point_sdf_normal_gate_deg", "(0, 180]"
        )
        require(
            self.track_max_depth > self.perception.min_depth,
            n,
            "track_max_depth",
            "must be > perception.min_depth",
        )
        require(self.max_track_points >= 100, n, "max_track_points", "must be >= 100")
        require(self.train_every >= 1, n, "train_every", "must be >= 1")
        require(self.train_latency in (0, 1), n, "train_latency", "must be 0 or 1")
        require(
            self.planar or not self.planar_registration, n, "planar_registration", "needs planar"
        )
        require(self.planar or not self.heading.enabled, n, "heading.enabled", "needs planar")
        require(self.open_train_iters >= 1, n, "open_train_iters", "must be >= 1")
        require(self.train_iters >= 1, n, "train_iters", "must be >= 1")
        require(self.depth_sigma0 > 0, n, "depth_sigma0", "must be > 0")
        require(self.depth_sigma_per_m2 >= 0, n, "depth_sigma_per_m2", "must be >= 0")
        require(self.revisit_checks_per_frame >= 0, n, "revisit_checks_per_frame", "must be >= 0")
        require(0 <= self.revisit_min_overlap <= 1, n, "revisit_min_overlap", "must be in [0, 1]")
        require(
            not (self.revisit_features == "learned" and self.map_kind == "points"),
            n,
            "revisit_features",
            "'learned' needs map_kind 'implicit' (the point store has no learned features)",
        )
        require(
            self.revisit_registrations_per_frame >= 0,
            n,
            "revisit_registrations_per_frame",
            "must be >= 0",
        )
        require(self.gate_sigmas >= 0, n, "gate_sigmas", "must be >= 0 (0: no gate)")
        require(self.odom_window >= 0, n, "odom_window", "must be >= 0 (0: no window test)")
        require(self.odom_window_sigmas > 0, n, "odom_window_sigmas", "must be > 0")
        require(self.track_max_correction_m > 0, n, "track_max_correction_m", "must be > 0")
        require(0 <= self.weak_ratio < 1, n, "weak_ratio", "must be in [0, 1)")
        require(self.prior_sigma_rot_deg > 0, n, "prior_sigma_rot_deg", "must be > 0")
        require(self.prior_sigma_trans > 0, n, "prior_sigma_trans", "must be > 0")
        require(self.odom_prior_sigma_rot_deg > 0, n, "odom_prior_sigma_rot_deg", "must be > 0")
        require(self.odom_prior_sigma_trans > 0, n, "odom_prior_sigma_trans", "must be > 0")
        require(self.track_cov_scale > 0, n, "track_cov_scale", "must be > 0")
        require(self.track_cov_scale_trans >= 0, n, "track_cov_scale_trans", "must be >= 0")
        for k in ("odom_prior_sigma_rot_per_unit", "odom_prior_sigma_trans_per_m"):
            require(getattr(self, k) >= 0, n, k, "must be >= 0")
        require(self.track_max_correction_deg > 0, n, "track_max_correction_deg", "must be > 0")
        for f in (
            "odom_sigma_rot",
            "odom_sigma_trans",
            "odom_sigma_rot_per_rad",
            "odom_sigma_trans_per_m",
        ):
            require(getattr(self, f) >= 0, n, f, "must be >= 0")
        require(self.odom_sigma_rot > 0 and self.odom_sigma_trans > 0, n, "odom_sigma_rot", "> 0")
        require(self.torch_threads >= 0, n, "torch_threads", "must be >= 0 (0: leave as is)")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SlamConfig:
        """As :meth:`Config.from_dict`; a key of the flat pre-redesign config fails with a
        message naming where it lives now (:data:`MOVED_KEYS`)."""
        moved = sorted(set(data or {}) & set(MOVED_KEYS))
        if moved:
            where = ", ".join(f"'{k}' -> '{MOVED_KEYS[k]}'" for k in moved)
            raise ConfigError(f"SlamConfig: key(s) moved: {where}")
        return super().from_dict(data)

    @classmethod
    def for_learned_tracking(cls, **changes: Any) -> SlamConfig:
        """:func:`simn_sim.slam.presets.learned_tracking_preset` (its docstring has the settings)."""
        from simn_sim.slam import presets

        return presets.learned_tracking_preset(**changes)

    @classmethod
    def for_agent(cls, **changes: Any) -> SlamConfig:
        """:func:`simn_sim.slam.presets.agent_preset` (its docstring has the settings)."""
        from simn_sim.slam import presets

        return presets.agent_preset(**changes)

    @classmethod
    def for_points_agent(cls, **changes: Any) -> SlamConfig:
        """:func:`simn_sim.slam.presets.points_agent_preset` (its docstring has the settings)."""
        from simn_sim.slam import presets

        return presets.points_agent_preset(**changes)


__all__ = [
    "MOVED_KEYS",
    "StoreConfig",
    "DecoderConfig",
    "NeuralPointsConfig",
    "SlamConfig",
    "TrainingConfig",
    "tracking_mapper_config",
]
