"""The decoder's inputs at query points from their neural-point neighbours: interpolated
features and colours, position inputs, blend weights and the geometric (point-to-plane) prior
(see :class:`~simn_sim.mapping.decoder.Decoder` and :class:`~simn_sim.mapping.config.DecoderConfig`)."""

from __future__ import annotations

import math

import torch

from simn_sim.mapping.config import DecoderConfig, NeuralPointsConfig
from simn_sim.mapping.neural_points import gaussian_weights, idw_interpolate, idw_weights

__all__ = ["decoder_inputs", "position_input"]


def position_input(
    dc: DecoderConfig, pc: NeuralPointsConfig, x: torch.Tensor, centroid: torch.Tensor
) -> torch.Tensor:
    """The decoder's position input at ``x`` for its ``position_input`` mode."""
    if dc.position_input == "relative":
        return (x - centroid) / pc.search_radius
    return x  # "absolute" (and ignored by the decoder for "none")


def decoder_inputs(
    dc: DecoderConfig,
    pc: NeuralPointsConfig,
    x: torch.Tensor,
    nb_pos: torch.Tensor,
    nb_valid: torch.Tensor,
    nb_feat: torch.Tensor,
    nb_col: torch.Tensor,
    nb_q: torch.Tensor,
    nb_n: torch.Tensor,
) -> tuple[torch.Tensor, ...]:
    """The decoder's inputs at map-frame points ``x`` (Q, 3) from their k neighbours'
    tables (Q, k, ...): ``(f, c, pos)`` for the interpolated decoding without the prior
    (the paper's), else ``(f, c, pos, weights, prior)`` (see :meth:`Decoder.forward`).
    ``dc``: the decoder's config, ``pc``: the map's neural-point config."""
    power = pc.idw_power
    if dc.decoding == "interpolated" and not dc.geometric_prior:
        f, c, ctr = idw_interpolate(x, nb_pos, nb_valid, nb_feat, nb_col, power)
        return f, c, position_input(dc, pc, x, ctr)
    if pc.weighting == "gaussian":
        w = gaussian_weights(x, nb_pos, nb_valid, pc.gaussian_width)  # (Q, k)
    else:
        w = idw_weights(x, nb_pos, nb_valid, power)
    # the prior's blend weights; "planes" holds them fixed in the gradient (DecoderConfig)
    wp = w.detach() if dc.prior_grad == "planes" else w
    prior = torch.zeros_like(w)
    if dc.geometric_prior:
        # point-to-plane distance to each neighbour's mean surface plane; neighbours
        # without a normal take the blend of those with one
        has = (nb_n.abs().sum(-1) > 0) & nb_valid
        if dc.prior_normal_gate_deg < 180:
            cos_gate = math.cos(math.radians(dc.prior_normal_gate_deg))
            near = (nb_n * nb_n[:, :1]).sum(-1) >= cos_gate  # column 0: the nearest
            has = has & (near | ~has[:, :1])
        wh = wp * has
        nrm = nb_n
        if dc.prior_normal == "blended":
            nb_ = (wh[..., None] * nb_n).sum(1, keepdim=True)
            nrm = nb_ / nb_.norm(dim=-1, keepdim=True).clamp(min=1e-9)
        d = ((x[:, None, :] - nb_q) * nrm).sum(-1)
        blend = (wh * d).sum(1, keepdim=True) / wh.sum(1, keepdim=True).clamp(min=1e-12)
        prior = torch.where(has, d, blend)
    if dc.decoding == "interpolated":
        f = (w[..., None] * nb_feat).sum(1)
        c = (w[..., None] * nb_col).sum(1)
        ctr = (w[..., None] * nb_pos).sum(1)
        return f, c, position_input(dc, pc, x, ctr), torch.ones_like(w[:, 0]), (wp * prior).sum(1)
    if dc.position_input == "relative":
        pos = (x[:, None, :] - nb_pos) / pc.search_radius
    else:
        pos = x[:, None, :].expand_as(nb_pos)
    return nb_feat, nb_col, pos, w, prior
