"""Typed, validated configs of the spatial-implicit mapper (one per component).

Defaults follow the paper's hyper-parameter table (learning rate 1e-3, loss weights
1.0 / 0.5 / 0.1, adaptive-loop threshold 1e-4, training every 5th frame, k = 6 neighbours,
feature dimension 8) where the paper gives a value, and the CPU cost envelope of
``DESIGN.md`` section 6 where it does not.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

from simn_sim.config import Config, require


def _finite(x: float) -> bool:
    return math.isfinite(x)


@dataclasses.dataclass(frozen=True)
class PerceptionConfig(Config):
    """RGB-D -> coloured points. Depth is metres after multiplying by ``depth_scale``."""

    min_depth: float = 0.28
    max_depth: float = 10.0
    depth_scale: float = 1.0  # e.g. 0.001 for uint16 millimetre depth
    pixel_stride: int = 1  # keep every n-th pixel in u and v before back-projection
    voxel_size: float = 0.0  # down-sampling of the frame's points; 0 disables

    def validate(self) -> None:
        n = type(self).__name__
        require(_finite(self.min_depth) and self.min_depth >= 0.0, n, "min_depth", "must be >= 0")
        require(
            _finite(self.max_depth) and self.max_depth > self.min_depth,
            n,
            "max_depth",
            f"must be finite and > min_depth ({self.min_depth}), got {self.max_depth}",
        )
        require(_finite(self.depth_scale) and self.depth_scale > 0, n, "depth_scale", "must be > 0")
        require(self.pixel_stride >= 1, n, "pixel_stride", "must be >= 1")
        require(_finite(self.voxel_size) and self.voxel_size >= 0, n, "voxel_size", "must be >= 0")


@dataclasses.dataclass(frozen=True)
class SamplingConfig(Config):
    """Ray sampling around each observed surface point ``p`` seen from camera centre ``e``.

    Samples are ``e + l (p - e)``: ``n_front`` with ``l ~ U(front_range)``, ``n_behind`` with
    ``l ~ U(1 + behind_min, 1 + behind_max)`` (the paper's ``(1.01, 1 + l_b)``), and
    ``n_surface`` on the plane through ``p`` perpendicular to the ray within ``surface_radius``.
    The label is the signed distance along the ray, ``(1 - l) |p - e|`` (positive in front).
    """

    n_front: int = 3
    n_behind: int = 2
    n_surface: int = 2
    front_range: tuple[float, float] = (0.3, 0.99)
    behind_min: float = 0.01
    behind_max: float = 0.1  # l_b
    surface_radius: float = 0.01  # r of the plane-radius sampling, metres

    def validate(self) -> None:
        n = type(self).__name__
        for f in ("n_front", "n_behind", "n_surface"):
            require(getattr(self, f) >= 0, n, f, "must be >= 0")
        require(
            self.n_front + self.n_behind + self.n_surface > 0, n, "n_front", "no samples per point"
        )
        lo, hi = self.front_range
        require(
            0.0 <= lo < hi < 1.0, n, "front_range", f"need 0 <= lo < hi < 1, got {self.front_range}"
        )
        require(
            0.0 <= self.behind_min < self.behind_max and _finite(self.behind_max),
            n,
            "behind_max",
            f"need 0 <= behind_min < behind_max, got {self.behind_min}, {self.behind_max}",
        )
        require(
            _finite(self.surface_radius) and self.surface_radius >= 0,
            n,
            "surface_radius",
            "must be >= 0",
        )


@dataclasses.dataclass(frozen=True)
class NeuralPointsConfig(Config):
    """The neural-point store: one point per ``voxel_size`` voxel, k-NN within ``search_radius``."""

    voxel_size: float = 0.05
    feature_dim: int = 8
    k_neighbors: int = 6
    search_radius: float = 0.15
    idw_power: float = 2.0  # paper eq.: 1; PIN-SLAM reference code: 2
    feature_init_std: float = 0.01
    query_chunk: int = 8192  # queries per k-NN chunk (bounds memory)
    # Neighbour weights of the per-neighbour decoding and of the geometric prior (the paper's
    # interpolated decoding without the prior always uses IDW): "idw" = 1 / d^idw_power;
    # "gaussian" = exp(-d^2 / (2 gaussian_width^2)), which averages the neighbours' planes
    # instead of following the nearest one (on noisy depth the nearest plane is offset by the
    # noise and the blended SDF gets cm-scale steps where registration stalls; docs/mapping.md)
    weighting: Literal["idw", "gaussian"] = "idw"
    gaussian_width: float = 0.05

    def validate(self) -> None:
        n = type(self).__name__
        require(_finite(self.voxel_size) and self.voxel_size > 0, n, "voxel_size", "must be > 0")
        require(self.feature_dim >= 1, n, "feature_dim", "must be >= 1")
        require(1 <= self.k_neighbors <= 64, n, "k_neighbors", "must be in [1, 64]")
        require(
            _finite(self.search_radius) and self.search_radius >= self.voxel_size,
            n,
            "search_radius",
            f"must be >= voxel_size ({self.voxel_size}), got {self.search_radius}",
        )
        require(
            _finite(self.idw_power) and 0 < self.idw_power <= 4, n, "idw_power", "must be in (0, 4]"
        )
        require(self.feature_init_std >= 0, n, "feature_init_std", "must be >= 0")
        require(self.query_chunk >= 1, n, "query_chunk", "must be >= 1")
        require(
            _finite(self.gaussian_width) and self.gaussian_width > 0,
            n,
            "gaussian_width",
            "must be > 0",
        )


@dataclasses.dataclass(frozen=True)
class DecoderConfig(Config):
    """``sdf = F_theta(p, c, f)``: an MLP on position, interpolated colour and feature."""

    hidden_dim: int = 64
    hidden_layers: int = 2
    activation: Literal["relu", "silu"] = "silu"
    # "relative": p minus the IDW centroid of its neighbours, divided by the search radius
    # (translation invariant, so a decoder can be shared by local frames in their own anchor
    # coordinates); "absolute": p in map coordinates; "none": features (and colour) only.
    position_input: Literal["relative", "absolute", "none"] = "relative"
    use_color: bool = True
    # "interpolated": the decoder sees the IDW-interpolated feature and colour and p relative
    # to the neighbours' IDW centroid (the paper's equation); "per_neighbor" (PIN-SLAM): each
    # of the k neighbours' features is decoded with p relative to that neural point, and the k
    # SDF values are IDW-blended (no centroid that jumps when the neighbour set changes).
    decoding: Literal["interpolated", "per_neighbor"] = "interpolated"
    # Geometric prior: every neural point carries the mean observed surface point q_k and
    # normal n_k of its voxel; the SDF is the IDW blend of the point-to-plane distances
    # n_k . (p - q_k) plus the MLP's output as a learned residual (its last layer starts at
    # zero, so an untrained map is the prior). ``residual: false`` is the prior alone (the
    # ablation; nothing is learned).
    geometric_prior: bool = False
    residual: bool = True
    # the prior blends only the neighbours whose normal is within this angle of the nearest
    # neighbour's (keeps creases sharp instead of rounding them over the blending width);
    # 180: all
    prior_normal_gate_deg: float = 180.0
    # "own": each neighbour's plane uses its own mean normal; "blended": every neighbour's
    # plane point with the weighted mean of the (gated) neighbours' normals, i.e. the implicit
    # MLS surface n(x) . (x - q(x)): a neighbour's normal error no longer acts over the lever
    # arm from its plane point to the query (docs/mapping.md)
    prior_normal: Literal["own", "blended"] = "own"
    # gradient of the prior: "full" differentiates through the blend weights too; "planes"
    # holds the weights fixed (the gradient is the weighted mean of the neighbours' normals,
    # the linearisation of IMLS-SLAM). On noisy depth the neighbours' plane distances differ
    # by the noise, and d w_k / d p times those differences (~ |p - p_k| / width^2 x noise)
    # puts a tangential gradient of the order of the normal itself into every residual.
    prior_grad: Literal["full", "planes"] = "full"

    def validate(self) -> None:
        n = type(self).__name__
        require(self.hidden_dim >= 1, n, "hidden_dim", "must be >= 1")
        require(self.hidden_layers >= 1, n, "hidden_layers", "must be >= 1")
        require(
            0 < self.prior_normal_gate_deg <= 180,
            n,
            "prior_normal_gate_deg",
            "must be in (0, 180]",
        )
        require(
            self.prior_grad == "full" or self.decoding == "interpolated",
            n,
            "prior_grad",
            "'planes' needs decoding 'interpolated'",
        )
        require(
            self.residual or self.geometric_prior,
            n,
            "residual",
            "false (no learned term) needs geometric_prior true",
        )


@dataclasses.dataclass(frozen=True)
class TrainingConfig(Config):
    """Losses, optimiser, replay and the adaptive training loop."""

    lr: float = 1e-3
    feature_lr: float = 1e-2  # paper: one rate (1e-3); features learn ~3x faster at 1e-2 (docs)
    bce_weight: float = 1.0
    eikonal_weight: float = 0.5
    ewc_weight: float = 0.1
    sigma: float = 0.05  # BCE on sigmoid(sdf / sigma), metres
    batch_size: int = 4096
    eikonal_fraction: float = 0.5  # share of each batch that also gets the Eikonal term
    train_every: int = 5  # train on every k-th integrated frame
    max_iters: int = 20
    min_iters: int = 10
    loss_window: int = 5
    loss_threshold: float = 1e-4  # stop when |mean(last window) - mean(previous)| < this
    replay_capacity: int = 200_000
    replay_ratio: float = 0.5  # share of replayed (old) samples in a batch once the pool has any
    use_replay: bool = True
    # Replay across local frames that share the decoder (mapping/continual.py): at most this
    # many samples of the closed frames, split evenly over them, stored with their decoder
    # inputs; ``frame_replay_share`` of the replayed part of a batch comes from them when the
    # frame has replay of its own as well (all of it when not). 0: no replay across frames.
    frame_replay_capacity: int = 50_000
    frame_replay_share: float = 0.5
    use_ewc: bool = True
    fisher_samples: int = 2048
    # how the diagonal Fisher is computed (losses.diagonal_fisher): "vmap" (torch.func) or
    # "outer" (per-sample outer products of the linear layers; the same quantity, ~4-8x faster)
    fisher_method: Literal["vmap", "outer"] = "vmap"
    # Divide each consolidated Fisher by its mean, so ewc_weight is a stiffness relative to
    # the average parameter importance rather than tied to the loss scale.
    ewc_normalize: bool = True
    max_pending: int = 20_000  # samples kept between training calls (uniform subset)
    # With the decoder's geometric prior: weight of a Gaussian prior on the learned residual,
    # ``residual_weight * mean((residual / sigma)^2)`` beside the BCE. 0: off.
    residual_weight: float = 0.0

    def validate(self) -> None:
        n = type(self).__name__
        for f in ("lr", "feature_lr", "sigma"):
            v = getattr(self, f)
            require(_finite(v) and v > 0, n, f, f"must be > 0, got {v}")
        for f in (
            "bce_weight",
            "eikonal_weight",
            "ewc_weight",
            "loss_threshold",
            "residual_weight",
        ):
            v = getattr(self, f)
            require(_finite(v) and v >= 0, n, f, f"must be >= 0, got {v}")
        require(self.batch_size >= 1, n, "batch_size", "must be >= 1")
        require(0 <= self.eikonal_fraction <= 1, n, "eikonal_fraction", "must be in [0, 1]")
        require(self.train_every >= 1, n, "train_every", "must be >= 1")
        require(self.max_iters >= 1, n, "max_iters", "must be >= 1")
        require(0 <= self.min_iters <= self.max_iters, n, "min_iters", "must be in [0, max_iters]")
        require(self.loss_window >= 1, n, "loss_window", "must be >= 1")
        require(self.replay_capacity >= 0, n, "replay_capacity", "must be >= 0")
        require(0 <= self.replay_ratio < 1, n, "replay_ratio", "must be in [0, 1)")
        require(self.frame_replay_capacity >= 0, n, "frame_replay_capacity", "must be >= 0")
        require(0 <= self.frame_replay_share <= 1, n, "frame_replay_share", "must be in [0, 1]")
        require(self.fisher_samples >= 1, n, "fisher_samples", "must be >= 1")
        require(self.max_pending >= 1, n, "max_pending", "must be >= 1")


@dataclasses.dataclass(frozen=True)
class MapperConfig(Config):
    """Everything an :class:`~simn_sim.mapping.mapper.ImplicitMap` needs."""

    perception: PerceptionConfig = dataclasses.field(default_factory=PerceptionConfig)
    sampling: SamplingConfig = dataclasses.field(default_factory=SamplingConfig)
    points: NeuralPointsConfig = dataclasses.field(default_factory=NeuralPointsConfig)
    decoder: DecoderConfig = dataclasses.field(default_factory=DecoderConfig)
    training: TrainingConfig = dataclasses.field(default_factory=TrainingConfig)
    # Voxel of the frame's points that become neural points / training rays (0: no down-sampling).
    integrate_voxel_size: float = 0.03
    device: str = "cpu"
    seed: int = 0

    def validate(self) -> None:
        n = type(self).__name__
        require(
            _finite(self.integrate_voxel_size) and self.integrate_voxel_size >= 0,
            n,
            "integrate_voxel_size",
            "must be >= 0",
        )
        require(
            self.device == "cpu" or self.device.startswith("cuda"),
            n,
            "device",
            f"must be 'cpu' or 'cuda[:i]', got {self.device!r}",
        )
