"""SLAM configs from presets: :meth:`SlamConfig.for_agent` (``agent``, the learned map),
:meth:`SlamConfig.for_points_agent` (``points_agent``, its point-store ablation) and
:meth:`SlamConfig.for_learned_tracking` (``learned_tracking``), changed by the other keys of a
mapping or a YAML file."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from simn_sim.config import ConfigError
from simn_sim.slam.config import SlamConfig, merge_changes, tracking_mapper_config

__all__ = [
    "RENAMED_PRESETS",
    "agent_preset",
    "learned_tracking_preset",
    "load_slam_config",
    "points_agent_preset",
    "slam_config_from_preset",
]

# presets of earlier versions: a config naming one fails with where it went
RENAMED_PRESETS: dict[str, str] = {
    "learned_agent": "the learned map is the agent's default now, preset 'agent'"
    " (the point store: 'points_agent')",
}


def load_slam_config(
    path: str | Path | None, default_preset: str | None = None, **overrides: Any
) -> SlamConfig:
    """A :class:`SlamConfig` from a YAML file (nested mappings per component), or defaults.

    A top-level ``preset`` (:func:`slam_config_from_preset`), else ``default_preset`` (None:
    the plain :class:`SlamConfig` defaults), starts from that preset; the other keys then change
    it (a nested mapping only the keys it names). ``simn-sim slam`` passes
    ``learned_tracking``: offline, the frames are tracked on the learned map by default."""
    data: dict[str, Any] = {}
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config file {p} does not exist")
        try:
            loaded = yaml.safe_load(p.read_text())
        except yaml.YAMLError as e:
            raise ConfigError(f"{p}: not valid YAML ({e})") from None
        if loaded is None:
            loaded = {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"{p}: expected a mapping at the top level")
        data = loaded
    data.update(overrides)
    return slam_config_from_preset(data, default=default_preset)


def slam_config_from_preset(data: dict[str, Any], default: str | None) -> SlamConfig:
    """A :class:`SlamConfig` from a mapping whose ``preset`` key (else ``default``; None: the
    plain defaults) names the preset the other keys change: ``point_tracking`` (the plain
    :class:`SlamConfig`: the learned map is trained, tracking uses the surface point store),
    ``agent``
    (:meth:`SlamConfig.for_agent`, the learned map), ``points_agent``
    (:meth:`SlamConfig.for_points_agent`, the point-store ablation) or
    ``learned_tracking`` (:meth:`SlamConfig.for_learned_tracking`)."""
    data = dict(data)
    preset = data.pop("preset", default)
    if preset is None:
        return SlamConfig.from_dict(data)
    presets = {
        "point_tracking": SlamConfig,
        "agent": SlamConfig.for_agent,
        "points_agent": SlamConfig.for_points_agent,
        "learned_tracking": SlamConfig.for_learned_tracking,
    }
    if preset in RENAMED_PRESETS:
        raise ConfigError(f"SlamConfig.preset: {preset!r} was renamed: {RENAMED_PRESETS[preset]}")
    if preset not in presets:
        raise ConfigError(
            f"SlamConfig.preset: unknown preset {preset!r} (one of {sorted(presets)})"
        )
    return presets[preset](**data)


def learned_tracking_preset(**changes: Any) -> SlamConfig:
    """Tracking against the local frame's learned map (``track_sdf="implicit"``) with
    :func:`tracking_mapper_config` (geometric prior + learned residual); ``changes`` as in
    :func:`agent_preset`. The k neural-point neighbours are searched at every LM iteration
    (reusing them while a point moved < 2 cm stopped LM early: maps at the true poses, noisy
    desk, error after LM from a 1.7 cm / 0.9 deg offset 7.6 mm / 0.30 deg with reuse, 4.8 mm
    / 0.09 deg without) and a point further than 3 cm along the surface from the map has no
    SDF. Revisit checks, ranked by the learned key-point features, verify by registration
    against the frame's surface store (``revisit_sdf: points``, as the closed-loop agent): on
    TUM fr1/rpy the learned SDF's checks accepted 1 revisit (ATE 3.22 cm), the store's 4
    (2.11 cm; docs/slam.md). The preset ``simn-sim slam`` starts from; its ATE against the
    targets, sequence by sequence, is in docs/slam.md (met on 7 of 12 at the last run,
    2026-12-07)."""
    d = SlamConfig().to_dict()
    # the gradient-norm validity floor on the learned map: 0.5 made points flip between
    # valid and invalid where the blended planes of noisy normals meet, so LM's cost jumped
    # and it stopped early. A revisit check on the learned SDF (``revisit_sdf: tracking``)
    # takes the same floor (with 0.5, 7-8 % of an observation had no valid SDF against 2-3 %
    # on the point store, so no revisit of TUM fr1/rpy reached the 0.85 inlier share;
    # docs/slam.md); on the surface store, the default, the floor does not act (its SDF is a
    # plane distance, gradient norm 1)
    floor = 0.3
    d.update(
        track_sdf="implicit",
        implicit_reuse_neighbors=0.0,
        implicit_max_dist=0.03,
        track_registration={**d["track_registration"], "grad_norm_min": floor},
        registration={**d["registration"], "grad_norm_min": floor},
        mapper=tracking_mapper_config().to_dict(),
        revisit_sdf="points",
        # registration weights by range: the inverse variance of sigma(z) = 1 cm + 0.0052 z^2
        # (the D435i's stereo error at the 320x240 stream's focal length over a 1 cm floor;
        # the shape alone matters: sigma doubles at 1.39 m). Against equal weights, ATE over
        # the 12 simulated sequences 2.56 -> 1.50 cm mean, 10.75 -> 2.94 cm worst, targets
        # met on 7 against 5; TUM fr1/rpy 2.11 -> 1.16 cm. Worse on 5 of the 8 sequences with
        # the wheel-odometry prior, and in the agent, which keeps equal weights (docs/slam.md)
        depth_sigma_per_m2=0.0052,
        depth_sigma0=0.01,
    )
    return SlamConfig.from_dict(merge_changes(d, changes))


def agent_preset(**changes: Any) -> SlamConfig:
    """The closed-loop agent's front-end (the ``simn`` default, preset ``agent``): the
    paper's method, each local frame's map the learned implicit map, tracked against,
    at the loop's cost. :func:`points_agent_preset` (perception, classifier, revisit budget)
    with the settings of :func:`learned_tracking_preset` (k-NN by KD-trees), training on a
    worker thread
    (``train_async``) in short chunks every frame (6 iterations when a
    frame opens, then 3 per frame on at most 4096 new samples: the agent's 15 per 5 frames
    without a long step every 5th frame). Registration (tracking and revisit checks): 1500
    points spread over the normal directions, each point's k neighbours and their tables
    reused while it moved less than 5 mm (:class:`~simn_sim.mapping.tracking_sdf.TrackingSdf`);
    in tracking one rejected LM step ends the registration (the point store's preset: 2500
    random points, 3 rejections). The wheel odometry is weighed against the registration
    (``g1c30``, see below). Revisit checks, ranked by the learned key-point features, verify
    by registration against the frame's surface store (``revisit_sdf: points``); a check still
    running when the next frame opens is finished, not dropped. Cost and
    accuracy against the point store: docs/tracking.md ("Tracking on the learned map") and
    docs/navigation.md."""
    d = points_agent_preset().to_dict()
    lt = learned_tracking_preset().to_dict()
    m = lt["mapper"]
    m["training"] = {**m["training"], "batch_size": 2048, "max_pending": 4096}
    d.update(
        map_kind="implicit",
        track_sdf="implicit",
        implicit_reuse_neighbors=0.005,
        implicit_max_dist=lt["implicit_max_dist"],
        max_track_points=1500,
        track_point_selection="normals",
        track_registration={
            **d["track_registration"],
            "grad_norm_min": lt["track_registration"]["grad_norm_min"],
            "max_rejects": 1,
        },
        mapper=m,
        train_async=True,
        open_train_iters=6,
        train_iters=3,
        train_every=1,
        # the wheel odometry weighed against the learned registration (`g1c30`): the
        # odometry increment's sigma grows with the motion at the realistic sensing's
        # drift rates (0.02 m per m, 0.02 rad per unit of motion), and the registration's
        # covariance is scaled by 30 (its residuals are not independent). office_nav_v2:
        # ATE 0.141 -> 0.095 m, 7 -> 4 collision events, success 54 -> 53/60 (paired
        # -0.017 +- 0.074), docs/navigation.md
        odom_prior_sigma_rot_deg=0.05,
        odom_prior_sigma_trans=0.002,
        odom_prior_sigma_rot_per_unit=0.02,
        odom_prior_sigma_trans_per_m=0.02,
        track_cov_scale=30.0,
        # revisit checks (ranked by the learned key-point features) verified by registration
        # against the frame's surface store: its loop arcs are more accurate than the learned
        # SDF's. office_nav_v2: 56/60 against 55/60, ATE 0.084 against 0.094 m, 393 revisits
        # (98 % correct) against 126 (37b24d2 against df5d74e; CHANGELOG 2026-12-05)
        revisit_sdf="points",
        # a deferred revisit check still running when the next frame opens is finished
        # first, not dropped (956 checks were dropped over office_nav_v2's 60 episodes).
        # office_nav_v2: 59/60 against 56/60, ATE 0.073 against 0.084 m (docs/navigation.md)
        revisit_finish_checks=True,
        # the tracked motion over the last 10 frames against the odometry's (5 sigmas of the
        # g1c30 increments above): a registration pulled along by a person walking in view
        # slid 0.4 m in 15 frames inside the per-frame gate. office_dynamic_v1: 22/30 against
        # 21/30, mean ATE 0.085 against 0.208 m; office_nav_v2 unchanged (docs/tracking.md)
        odom_window=10,
        odom_window_sigmas=5.0,
    )
    return SlamConfig.from_dict(merge_changes(d, changes))


def points_agent_preset(**changes: Any) -> SlamConfig:
    """The point-store ablation of the closed-loop agent (agent ``simn_points``, preset
    ``points_agent``): each local frame's map is a surface voxel store whose SDF is the
    nearest point's plane (no learning); fewer registration points and shorter training
    bursts than the offline defaults (10 Hz at 320x240 frames on a CPU)."""
    base = SlamConfig()
    tr = dataclasses.replace(base.mapper.training, batch_size=2048)
    # stereo depth noise grows with range^2: the floor band widens with range and far
    # points are not obstacles (the values the agent's odometry ablation uses)
    cl = dataclasses.replace(base.classifier, floor_tol_per_m2=0.01, max_obstacle_range=3.5)
    d = base.to_dict()
    d.update(
        max_track_points=2500,
        map_kind="points",
        planar=True,
        revisit_checks_per_frame=1,
        revisit_registrations_per_frame=1,
        revisit_min_overlap=0.5,
        descriptor={**d["descriptor"], "max_points": 3000},
        # nearest-point SDF: the kernel's 8-neighbour queries doubled tracking time in the
        # loop (median up to 47 ms per frame at 320x240, 55815d3; docs/navigation.md)
        point_sdf_kernel=0.0,
        open_train_iters=60,
        train_iters=15,
        train_every=5,
        mapper={**d["mapper"], "training": tr.to_dict()},
        classifier=cl.to_dict(),
    )
    return SlamConfig.from_dict(merge_changes(d, changes))
