"""Cost of the EWC consolidation's diagonal Fisher: ``torch.func`` vmap against per-sample outer
products (``mapper.training.fisher_method``), on the agent preset's decoder and sample count.

The two methods alternate in one process, ``--repeats`` times each after one warm-up call per
method (the first vmap call traces, about 3 s; reported apart as ``first_call_ms``). The inputs
have the shapes a local frame's consolidation gives the decoder (interpolated decoding: feature,
colour, relative position, weight, prior per sample); the cost depends on those shapes only. Also
reported: the largest difference between the two Fishers relative to each tensor's largest entry.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_fisher.py --repeats 15 --out runs/bench_fisher.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from simn_sim.experiments.batch_files import machine_summary
from simn_sim.experiments.runner import write_json
from simn_sim.mapping.decoder import Decoder
from simn_sim.mapping.losses import bce_sdf_loss, diagonal_fisher
from simn_sim.slam.config import SlamConfig


def consolidation_inputs(n: int, seed: int = 0) -> tuple[Decoder, tuple, torch.Tensor, float]:
    """The agent preset's decoder with a trained-like (non-zero) residual and ``n`` samples of
    decoder inputs and SDF labels."""
    mc = SlamConfig.for_agent().mapper
    g = torch.Generator().manual_seed(seed)
    dec = Decoder(mc.decoder, mc.points.feature_dim, generator=g)
    with torch.no_grad():
        for p in dec.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=g))
    d = mc.points.feature_dim
    if mc.decoder.decoding == "interpolated":
        shapes, w = [(n, d), (n, 3), (n, 3)], torch.ones(n)
        prior = 0.05 * torch.randn(n, generator=g)
    else:
        k = mc.points.k_neighbors
        shapes = [(n, k, d), (n, k, 3), (n, k, 3)]
        w = torch.softmax(torch.randn(n, k, generator=g), 1)
        prior = 0.05 * torch.randn(n, k, generator=g)
    inputs = (*(torch.randn(s, generator=g) for s in shapes), w, prior)
    labels = 0.05 * torch.randn(n, generator=g)
    return dec, inputs, labels, mc.training.sigma


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--samples", type=int, default=None, help="default: the preset's")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats must be >= 1")
    torch.set_num_threads(1)  # as the agent's SLAM (SlamConfig.torch_threads)
    n = a.samples or SlamConfig.for_agent().mapper.training.fisher_samples
    dec, inputs, labels, sigma = consolidation_inputs(n)

    def loss(out: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return bce_sdf_loss(out, y, sigma)

    methods = ("vmap", "outer")
    times: dict[str, list[float]] = {m: [] for m in methods}
    first: dict[str, float] = {}
    result: dict[str, dict] = {}
    for r in range(a.repeats + 1):
        for m in methods:
            t = time.perf_counter()
            result[m] = diagonal_fisher(dec, inputs, labels, loss, method=m)
            ms = (time.perf_counter() - t) * 1e3
            if r == 0:
                first[m] = ms
            else:
                times[m].append(ms)
    rel = max(
        float((result["outer"][k] - result["vmap"][k]).abs().max() / result["vmap"][k].abs().max())
        for k in result["vmap"]
    )
    med = {m: statistics.median(v) for m, v in times.items()}
    doc = {
        "machine": machine_summary(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "samples": n,
        "repeats": a.repeats,
        "median_ms": med,
        "range_ms": {m: [min(v), max(v)] for m, v in times.items()},
        "first_call_ms": first,
        "ratio_vmap_over_outer": med["vmap"] / med["outer"],
        "max_rel_difference": rel,
    }
    print(json.dumps(doc, indent=2))
    if a.out:
        write_json(a.out, doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
