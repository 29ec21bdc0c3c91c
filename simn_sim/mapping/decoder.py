"""The SDF decoder ``sdf = F_theta(p, c, f)``: a small MLP (2 hidden layers of 64 by default).

ReLU or SiLU only: Softplus is ~8x slower on the CPU (DESIGN.md section 6). The decoder holds no
map state, so several local-frame maps may share one instance or each take a :meth:`copy`.
"""

from __future__ import annotations

import copy
import math

import torch
from torch import nn

from simn_sim.mapping.config import DecoderConfig


class Decoder(nn.Module):
    """MLP from ``[feature (D), colour (3, optional), position (3, optional)]`` to one SDF value."""

    def __init__(
        self,
        cfg: DecoderConfig | None = None,
        feature_dim: int = 8,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.cfg = cfg or DecoderConfig()
        self.feature_dim = feature_dim
        self.in_dim = feature_dim + 3 * self.cfg.use_color + 3 * (self.cfg.position_input != "none")
        act = nn.SiLU if self.cfg.activation == "silu" else nn.ReLU
        layers: list[nn.Module] = []
        d = self.in_dim
        for _ in range(self.cfg.hidden_layers):
            layers += [nn.Linear(d, self.cfg.hidden_dim), act()]
            d = self.cfg.hidden_dim
        layers.append(nn.Linear(d, 1))
        self.mlp = nn.Sequential(*layers)
        self.reset_parameters(generator)

    @torch.no_grad()
    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """PyTorch's default Linear init, drawn from ``generator`` (no global RNG). With the
        geometric prior the last layer starts at zero: the untrained residual is 0."""
        for m in self.mlp:
            if isinstance(m, nn.Linear):
                bound = 1.0 / math.sqrt(m.in_features)
                nn.init.uniform_(m.weight, -bound, bound, generator=generator)
                nn.init.uniform_(m.bias, -bound, bound, generator=generator)
        if self.cfg.geometric_prior:
            self.mlp[-1].weight.zero_()
            self.mlp[-1].bias.zero_()

    def forward(
        self,
        features: torch.Tensor,
        colors: torch.Tensor,
        positions: torch.Tensor,
        weights: torch.Tensor | None = None,
        prior: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Interpolated inputs: features (N, D), colors (N, 3), positions (N, 3) (as prepared
        by the map) -> sdf (N,), plus ``prior`` (N,) when given.

        Per-neighbour inputs: features (N, k, D), colors (N, k, 3), positions (N, k, 3) and
        IDW ``weights`` (N, k) (normalised) -> ``sum_k w_k (prior_k + mlp_k)`` (N,), with the
        per-neighbour ``prior`` (N, k) when given. ``cfg.residual`` False drops the MLP term.
        """
        per_nb = features.ndim == 3
        if self.cfg.residual:
            parts = [features]
            if self.cfg.use_color:
                parts.append(colors)
            if self.cfg.position_input != "none":
                parts.append(positions)
            out = self.mlp(torch.cat(parts, dim=-1)).squeeze(-1)
        else:
            out = torch.zeros(features.shape[:-1], dtype=features.dtype, device=features.device)
        if prior is not None:
            out = out + prior
        if per_nb:
            if weights is None:
                raise ValueError("per-neighbour decoding needs the IDW weights")
            out = (weights * out).sum(-1)
        return out

    def copy(self) -> Decoder:
        """An independent deep copy (for a new local frame that starts from this decoder)."""
        return copy.deepcopy(self)
