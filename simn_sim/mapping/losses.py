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
    method: str = "auto",
) -> dict[str, torch.Tensor]:
    """Mean squared per-sample gradient of ``loss_fn(module(*inputs_i), label_i)`` w.r.t. each
    parameter (empirical diagonal Fisher). ``loss_fn`` is the mean of per-sample losses over
    a batch (as :func:`bce_sdf_loss`).

    ``method``: ``"vmap"`` takes every sample's gradient with ``torch.func`` (vmap over
    samples); ``"outer"`` uses that a linear layer's per-sample weight gradient is the outer
    product of the gradient at its output and its input, so the sum of their squares is one
    product of the squared tables (one forward and one backward for all samples; the same
    quantity, summed in another order). ``"auto"`` (default) is ``"outer"`` when every
    parameter belongs to an ``nn.Linear`` applied once per call to (N, in) rows, else
    ``"vmap"``."""
    if method not in ("auto", "vmap", "outer"):
        raise ValueError(f"diagonal_fisher: unknown method {method!r} (auto, vmap or outer)")
    if method != "vmap":
        fisher = _fisher_outer(module, inputs, labels, loss_fn, chunk)
        if fisher is not None:
            return fisher
        if method == "outer":
            raise ValueError(
                "diagonal_fisher: method 'outer' needs every parameter in an nn.Linear applied "
                "once per call to (N, in) rows"
            )
    return _fisher_vmap(module, inputs, labels, loss_fn, chunk)


def _fisher_vmap(module, inputs, labels, loss_fn, chunk: int) -> dict[str, torch.Tensor]:
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


def _fisher_outer(module, inputs, labels, loss_fn, chunk: int) -> dict[str, torch.Tensor] | None:
    """:func:`diagonal_fisher` from per-layer outer products; None when ``module`` is not
    made of linear layers applied once per call to (N, in) rows."""
    linears = {m: name for name, m in module.named_modules() if isinstance(m, nn.Linear)}
    owned = {f"{linears[m]}.{pn}" for m in linears for pn, _ in m.named_parameters()}
    names = [k for k, _ in module.named_parameters()]
    if not linears or set(names) != owned:
        return None
    n = labels.shape[0]
    acc = {k: torch.zeros_like(v) for k, v in module.named_parameters()}
    for s in range(0, n, chunk):
        seen: dict[nn.Linear, list[tuple[torch.Tensor, torch.Tensor]]] = {m: [] for m in linears}

        def hook(m, args, out, seen=seen):
            seen[m].append((args[0], out))

        handles = [m.register_forward_hook(hook) for m in linears]
        try:
            with torch.enable_grad():
                out = module(*(x[s : s + chunk] for x in inputs))
                b = labels[s : s + chunk].shape[0]
                ok = all(
                    len(v) == 1 and v[0][0].ndim == 2 and v[0][0].shape[0] == b
                    for v in seen.values()
                )
                if not ok:
                    return None
                # the sum of the per-sample losses: its gradient at each layer's output row i
                # is sample i's own (the samples do not interact)
                total = loss_fn(out, labels[s : s + chunk]) * b
                outs = [seen[m][0][1] for m in linears]
                deltas = torch.autograd.grad(total, outs)
        finally:
            for h in handles:
                h.remove()
        for m, d in zip(linears, deltas, strict=True):
            a = seen[m][0][0].detach()
            d2 = d.detach() ** 2
            acc[f"{linears[m]}.weight"] += d2.T @ (a**2)
            if m.bias is not None:
                acc[f"{linears[m]}.bias"] += d2.sum(0)
    return {k: v / max(n, 1) for k, v in acc.items()}
