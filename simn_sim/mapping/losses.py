"""Losses of the mapper: BCE on sigmoid(sdf / sigma), Eikonal, and EWC with a diagonal Fisher."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn


def bce_sdf_loss(pred: torch.Tensor, label: torch.Tensor, sigma: float) -> torch.Tensor:
    """Mean BCE between ``sigmoid(pred / sigma)`` and ``sigmoid(label / sigma)``."""
    return F.binary_cross_entropy_with_logits(pred / sigma, torch.sigmoid(label / sigma))


def eikonal_loss(grad: torch.Tensor) -> torch.Tensor:
    """Mean of ``(||grad_p F|| - 1)^2`` over (N, 3) gradients."""
    return ((grad.norm(dim=1) - 1.0) ** 2).mean()


class EWC:
    """Elastic weight consolidation on a module's parameters.

    ``penalty = sum_i G_i (theta_i - theta*_i)^2`` with ``G`` the diagonal empirical Fisher
    (mean of squared per-sample gradients of the data loss) accumulated over consolidations,
    and ``theta*`` the parameters at the latest consolidation.
    """

    def __init__(self) -> None:
        self.fisher: dict[str, torch.Tensor] | None = None
        self.anchor: dict[str, torch.Tensor] | None = None
        self.count = 0

    @property
    def active(self) -> bool:
        return self.fisher is not None

    def penalty(self, module: nn.Module) -> torch.Tensor:
        if self.fisher is None or self.anchor is None:
            return torch.zeros(())
        total = None
        for name, p in module.named_parameters():
            t = (self.fisher[name] * (p - self.anchor[name]) ** 2).sum()
            total = t if total is None else total + t
        return total

    def consolidate(self, module: nn.Module, fisher: dict[str, torch.Tensor]) -> None:
        """Add ``fisher`` to the accumulated one and anchor at the current parameters."""
        if self.fisher is None:
            self.fisher = {k: v.detach().clone() for k, v in fisher.items()}
        else:
            self.fisher = {k: self.fisher[k] + fisher[k].detach() for k in self.fisher}
        self.anchor = {k: p.detach().clone() for k, p in module.named_parameters()}
        self.count += 1

    def state_dict(self) -> dict:
        if self.fisher is None or self.anchor is None:
            return {"count": self.count}
        return {"count": self.count, "fisher": self.fisher, "anchor": self.anchor}

    def load_state_dict(self, state: dict) -> None:
        self.count = int(state.get("count", 0))
        self.fisher = state.get("fisher")
        self.anchor = state.get("anchor")


def diagonal_fisher(
    module: nn.Module,
    inputs: tuple[torch.Tensor, ...],
    labels: torch.Tensor,
    loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    chunk: int = 1024,
    method: str = "vmap",
) -> dict[str, torch.Tensor]:
    """Mean squared per-sample gradient of ``loss_fn(module(*inputs_i), label_i)`` w.r.t. each
    parameter (empirical diagonal Fisher).

    ``method``: ``"vmap"`` (``torch.func``, any module) or ``"outer"``: one batched backward,
    each linear layer's per-sample weight gradient the outer product of its output gradient and
    its input (so the squared one is ``(delta^2)^T (a^2)``); the same quantity, for modules whose
    parameters all belong to ``nn.Linear`` layers and whose samples do not interact, with
    ``loss_fn`` a mean over samples. Other modules fall back to ``"vmap"``.
    """
    if method not in ("vmap", "outer"):
        raise ValueError(f"diagonal_fisher: method must be 'vmap' or 'outer', got {method!r}")
    if method == "outer" and _all_linear(module):
        fisher = _outer_fisher(module, inputs, labels, loss_fn, chunk)
        if fisher is not None:
            return fisher
    from torch.func import functional_call, grad, vmap

    params = {k: v.detach() for k, v in module.named_parameters()}

    def one(p: dict, *args: torch.Tensor) -> torch.Tensor:
        *xs, y = args
        out = functional_call(module, p, tuple(x[None] for x in xs))
        return loss_fn(out, y[None])

    g_fn = vmap(grad(one), in_dims=(None, *([0] * (len(inputs) + 1))))
    acc = {k: torch.zeros_like(v) for k, v in params.items()}
    n = labels.shape[0]
    for s in range(0, n, chunk):
        gs = g_fn(params, *(x[s : s + chunk] for x in inputs), labels[s : s + chunk])
        for k in acc:
            acc[k] += (gs[k] ** 2).sum(0)
    return {k: v / max(n, 1) for k, v in acc.items()}


def _all_linear(module: nn.Module) -> bool:
    """Whether every parameter of ``module`` is the weight or bias of an ``nn.Linear``."""
    lin = {id(p) for m in module.modules() if isinstance(m, nn.Linear) for p in m.parameters()}
    return all(id(p) in lin for p in module.parameters())


def _outer_fisher(
    module: nn.Module,
    inputs: tuple[torch.Tensor, ...],
    labels: torch.Tensor,
    loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    chunk: int,
) -> dict[str, torch.Tensor] | None:
    """:func:`diagonal_fisher` by per-sample outer products (see there); None when a linear
    layer runs more than once in a forward pass (shared weights: a sample's gradient is then a
    sum of outer products, squared only after summing)."""
    names = {id(p): k for k, p in module.named_parameters()}
    seen: list[tuple[nn.Linear, torch.Tensor, torch.Tensor]] = []

    def hook(m: nn.Module, args: tuple, out: torch.Tensor) -> None:
        seen.append((m, args[0].detach(), out))

    lins = [m for m in module.modules() if isinstance(m, nn.Linear)]
    handles = [m.register_forward_hook(hook) for m in lins]
    acc = {k: torch.zeros_like(p) for k, p in module.named_parameters()}
    n = labels.shape[0]
    try:
        for s in range(0, n, chunk):
            seen.clear()
            with torch.enable_grad():
                out = module(*(x[s : s + chunk] for x in inputs))
                m_ = out.shape[0]
                # loss_fn is a mean over samples: m_ x it is the sum of the per-sample losses,
                # whose gradient w.r.t. a layer's output row is that sample's alone
                total = loss_fn(out, labels[s : s + chunk]) * m_
                if len({id(m) for m, _, _ in seen}) != len(seen):
                    return None
                deltas = torch.autograd.grad(total, [o for _, _, o in seen])
            for (m, a, _), d in zip(seen, deltas, strict=True):
                a2 = a.reshape(m_, -1, a.shape[-1])
                d2 = d.reshape(m_, -1, d.shape[-1])
                if a2.shape[1] == 1:  # one row per sample: the outer products summed at once
                    gw2 = (d2[:, 0] ** 2).T @ (a2[:, 0] ** 2)
                    gb2 = (d2[:, 0] ** 2).sum(0)
                else:  # several rows per sample (per-neighbour decoding): sum, then square
                    gw2 = (torch.einsum("nro,nri->noi", d2, a2) ** 2).sum(0)
                    gb2 = (d2.sum(1) ** 2).sum(0)
                acc[names[id(m.weight)]] += gw2
                if m.bias is not None:
                    acc[names[id(m.bias)]] += gb2
    finally:
        for h in handles:
            h.remove()
    return {k: v / max(n, 1) for k, v in acc.items()}
