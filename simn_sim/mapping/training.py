"""One training chunk of a learned local-frame map (:meth:`ImplicitMap.train_deferred`).

The loss is ``lambda_b BCE + lambda_e Eikonal + lambda_EWC EWC`` (plus the Gaussian prior on
the learned residual) on the frame's new samples, this frame's replay and the closed frames'
replay; Adam on a copy of the decoder and on the features of the neural points the batch
touches. Nothing the map's readers see changes until the returned ``apply()`` runs.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch

from simn_sim.mapping.losses import bce_sdf_loss, eikonal_loss
from simn_sim.mapping.results import TrainResult

if TYPE_CHECKING:
    from simn_sim.mapping.mapper import ImplicitMap

__all__ = ["train_chunk"]


def train_chunk(
    imap: ImplicitMap, max_iters: int | None, prepare_all: bool = False
) -> tuple[TrainResult, Callable[[], None]]:
    """The body of :meth:`ImplicitMap.train_deferred` (called with denormals flushed): the
    adaptive loop on ``imap``'s pending samples mixed with replayed ones, on a copy of the
    decoder and a sub-table of the features; returns the result and ``apply()``, which writes
    both back. ``prepare_all``: search and gather the neighbours of every sample, not only of
    those the batches draw (the reference path, the same numbers; for tests)."""
    tc = imap.cfg.training
    t0 = time.perf_counter()
    cap = tc.max_iters if max_iters is None else int(max_iters)
    if cap < 1:
        raise ValueError(f"train: max_iters must be >= 1, got {max_iters}")
    if imap._n_pending == 0:
        return TrainResult(0, False, float("nan"), 0, 0, 0.0), _nothing
    Xn, Sn, Kn = (torch.cat(t) for t in zip(*imap._pending, strict=True))
    imap._pending, imap._n_pending = [], 0
    if not imap.decoder.cfg.residual:  # the geometric prior alone: nothing to learn
        if tc.use_replay:
            imap.replay.add(Xn, Sn, Kn, imap.generator)
        res = TrainResult(0, True, float("nan"), 0, 0, time.perf_counter() - t0)
        imap.last_train = res
        return res, _nothing
    n_new = Xn.shape[0]
    n_prev = len(imap.frame_replay) if tc.use_replay else 0  # closed frames' samples
    if tc.use_replay and len(imap.replay) > 0:
        m = int(round(n_new * tc.replay_ratio / (1.0 - tc.replay_ratio)))
        Xo, So, Ko = imap.replay.sample(max(m, 1), imap.generator)
    else:
        Xo, So, Ko = Xn[:0], Sn[:0], Kn[:0]
    # Validity (a neural point within the search radius): the new samples by k-NN. The
    # replayed ones were valid when they were stored and neural points are only ever added,
    # so they still are; their neighbours are searched below only where a batch draws them.
    idx_new, _ = imap.points.knn(Xn)
    ok = idx_new[:, 0] >= 0
    Xn, Sn, Kn, idx_new = Xn[ok], Sn[ok], Kn[ok], idx_new[ok]
    n_ok = Xn.shape[0]
    X, S, K = torch.cat([Xn, Xo]), torch.cat([Sn, So]), torch.cat([Kn, Ko])
    old = torch.cat(
        [torch.zeros(n_ok, dtype=torch.bool), torch.ones(Xo.shape[0], dtype=torch.bool)]
    )
    old = old.to(imap.device)
    if X.shape[0] == 0:
        return TrainResult(0, False, float("nan"), 0, 0, time.perf_counter() - t0), _nothing
    new_ids = torch.nonzero(~old).squeeze(1)
    old_ids = torch.nonzero(old).squeeze(1)
    B = tc.batch_size
    # batch: new samples, this frame's replay and the closed frames' replay (frame_replay)
    nb_rep = int(round(B * tc.replay_ratio)) if (old_ids.numel() or n_prev) else 0
    nb_prev = 0
    if n_prev:
        nb_prev = nb_rep if not old_ids.numel() else int(round(nb_rep * tc.frame_replay_share))
        nb_prev = min(nb_prev, B - 1)
    Bc = B - nb_prev  # samples of this frame per batch
    # both kinds: nb_old replayed per batch (possibly 0); else uniform over all: None
    nb_old = nb_rep - nb_prev if (old_ids.numel() and new_ids.numel()) else None
    # Every iteration's batch is drawn up front (the generator's state after each is kept, and
    # restored after the last iteration run), so only the rows some batch uses are prepared.
    batches, states = _draw_batches(imap, cap, new_ids, old_ids, Bc, nb_old, nb_prev)
    if prepare_all:
        rows = torch.arange(X.shape[0], device=imap.device)
    else:
        rows = torch.unique(torch.cat([bi for bi, _ in batches]))
    idx = torch.full((X.shape[0], idx_new.shape[1]), -1, dtype=torch.long, device=imap.device)
    idx[:n_ok] = idx_new
    old_rows = rows[rows >= n_ok]
    if old_rows.numel():
        idx_old, _ = imap.points.knn(X[old_rows])
        if not bool((idx_old[:, 0] >= 0).all()):
            raise RuntimeError(
                "train_chunk: a replayed sample has no neural point within search_radius "
                "(the map's points were replaced since it was stored)"
            )
        idx[old_rows] = idx_old
    row_of = torch.full((X.shape[0],), -1, dtype=torch.long, device=imap.device)
    row_of[rows] = torch.arange(rows.numel(), device=imap.device)
    idx = idx[rows]
    # Work on the sub-table of neural points the batches touch.
    nbv = idx >= 0
    active, local = torch.unique(idx[nbv], return_inverse=True)
    lidx = torch.zeros_like(idx)
    lidx[nbv] = local
    nb_pos = imap.points.positions[active][lidx]
    nb_col = imap.points.colors[active][lidx]
    q_all, n_all = imap.points.planes()
    nb_q, nb_n = q_all[active][lidx], n_all[active][lidx]
    feat = imap.points.features[active].clone().requires_grad_(True)
    dec = copy.deepcopy(imap.decoder)  # trained aside; apply() writes it back
    opt = torch.optim.Adam(
        [
            {"params": list(dec.parameters()), "lr": tc.lr},
            {"params": [feat], "lr": tc.feature_lr},
        ]
    )
    use_ewc = tc.use_ewc and imap.ewc.active and tc.ewc_weight > 0
    dc = dec.cfg
    shrink = tc.residual_weight > 0 and dc.geometric_prior and dc.decoding == "interpolated"
    losses: list[float] = []
    converged = False
    it = 0
    for it, (bi, rid) in enumerate(batches, start=1):  # noqa: B007
        x = X[bi]
        r = row_of[bi]
        ne = min(int(round(B * tc.eikonal_fraction)), Bc) if tc.eikonal_weight > 0 else 0
        if ne:
            x = x.clone()
            xe = x[:ne].requires_grad_(True)
            x = torch.cat([xe, x[ne:]])
        inp = imap._decoder_inputs(x, nb_pos[r], nbv[r], feat[lidx[r]], nb_col[r], nb_q[r], nb_n[r])
        pred = dec(*inp)
        label = S[bi]
        prior = inp[4] if shrink else None
        p_ne = pred[:ne]
        if nb_prev:  # closed frames' samples: their frozen decoder inputs
            inp_p, lab_p = imap.frame_replay.take(rid)
            pred = torch.cat([pred, dec(*inp_p)])
            label = torch.cat([label, lab_p])
            if shrink:
                prior = torch.cat([prior, inp_p[4]])
        loss = tc.bce_weight * bce_sdf_loss(pred, label, tc.sigma)
        if shrink:  # Gaussian prior on the learned residual: zero unless the labels agree
            loss = loss + tc.residual_weight * ((pred - prior) / tc.sigma).pow(2).mean()
        if ne:
            (g,) = torch.autograd.grad(p_ne.sum(), xe, create_graph=True)
            loss = loss + tc.eikonal_weight * eikonal_loss(g)
        if use_ewc:
            loss = loss + tc.ewc_weight * imap.ewc.penalty(dec)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        w = tc.loss_window
        if it >= max(tc.min_iters, 2 * w):
            a = sum(losses[-w:]) / w
            b = sum(losses[-2 * w : -w]) / w
            if abs(a - b) < tc.loss_threshold:
                converged = True
                break
    imap.generator.set_state(states[it - 1])  # as if only the iterations run had drawn
    feat = feat.detach()

    def apply() -> None:
        with torch.no_grad():
            imap.points.features[active] = feat
            for p, q in zip(imap.decoder.parameters(), dec.parameters(), strict=True):
                p.copy_(q)
        imap.points.version += 1

    imap.n_trainings += 1
    Xnv, Snv, Knv = X[~old], S[~old], K[~old]
    if tc.use_replay:
        imap.replay.add(Xnv, Snv, Knv, imap.generator)
    imap._recent.add(Xnv, Snv, Knv, imap.generator)
    w = min(tc.loss_window, len(losses))
    res = TrainResult(
        iterations=it,
        converged=converged,
        final_loss=sum(losses[-w:]) / w,
        n_samples=int(X.shape[0]),
        n_replayed=int(old_ids.numel()) + (len(imap.frame_replay) if nb_prev else 0),
        seconds=time.perf_counter() - t0,
    )
    imap.last_train = res
    return res, apply


def _draw_batches(
    imap: ImplicitMap,
    cap: int,
    new_ids: torch.Tensor,
    old_ids: torch.Tensor,
    Bc: int,
    nb_old: int | None,
    nb_prev: int,
) -> tuple[list[tuple[torch.Tensor, torch.Tensor | None]], list[torch.Tensor]]:
    """``cap`` iterations' batches: the rows of this frame's samples (``Bc``, of which
    ``nb_old`` replayed, or uniform over all when ``nb_old`` is None) and the indices of
    ``nb_prev`` closed frames' samples, drawn with replacement from ``imap.generator`` in the
    order the loop uses them; plus the generator's state after each iteration's draws."""
    g, dev = imap.generator, imap.device
    batches, states = [], []
    n_all = new_ids.numel() + old_ids.numel()
    for _ in range(cap):
        if nb_old is not None:
            i_new = torch.randint(new_ids.numel(), (Bc - nb_old,), generator=g, device=dev)
            i_old = torch.randint(old_ids.numel(), (nb_old,), generator=g, device=dev)
            bi = torch.cat([new_ids[i_new], old_ids[i_old]])
        else:
            bi = torch.randint(n_all, (Bc,), generator=g, device=dev)
        rid = imap.frame_replay.draw_ids(nb_prev, g) if nb_prev else None
        batches.append((bi, rid))
        states.append(g.get_state())
    return batches, states


def _nothing() -> None:
    """``apply`` of a training that changed nothing."""
