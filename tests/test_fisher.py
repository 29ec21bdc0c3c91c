"""The EWC consolidation's diagonal Fisher by per-sample outer products (``fisher_method:
outer``) equals the one from ``torch.func`` (vmap over samples), for both decodings."""

import pytest
import torch

from simn_sim.mapping.config import DecoderConfig
from simn_sim.mapping.decoder import Decoder
from simn_sim.mapping.losses import bce_sdf_loss, diagonal_fisher


@pytest.mark.parametrize("decoding", ["interpolated", "per_neighbor"])
def test_outer_product_fisher_equals_the_vmap_fisher(decoding):
    g = torch.Generator().manual_seed(0)
    dec = Decoder(DecoderConfig(geometric_prior=True, decoding=decoding), generator=g)
    with torch.no_grad():
        for p in dec.parameters():  # leave the prior's zero last layer
            p.add_(0.1 * torch.randn(p.shape, generator=g))
    n, k = 700, 5
    if decoding == "interpolated":
        shapes = [(n, 8), (n, 3), (n, 3)]
        w, prior = torch.ones(n), 0.02 * torch.randn(n, generator=g)
    else:
        shapes = [(n, k, 8), (n, k, 3), (n, k, 3)]
        w = torch.softmax(torch.randn(n, k, generator=g), 1)
        prior = 0.02 * torch.randn(n, k, generator=g)
    inputs = tuple(torch.randn(s, generator=g) for s in shapes) + (w, prior)
    labels = 0.05 * torch.randn(n, generator=g)

    def loss(out, y):
        return bce_sdf_loss(out, y, 0.02)

    ref = diagonal_fisher(dec, inputs, labels, loss, chunk=256)
    got = diagonal_fisher(dec, inputs, labels, loss, chunk=256, method="outer")
    assert ref.keys() == got.keys()
    for name in ref:
        assert float(ref[name].abs().max()) > 0, name
        torch.testing.assert_close(
            got[name], ref[name], rtol=1e-4, atol=1e-6 * float(ref[name].abs().max())
        )


def test_unknown_fisher_method_is_rejected():
    dec = Decoder(DecoderConfig())
    x = torch.zeros(2, 8)
    with pytest.raises(ValueError, match="method must be"):
        diagonal_fisher(
            dec, (x, x[:, :3], x[:, :3]), torch.zeros(2), lambda o, y: o.sum(), method="svd"
        )


def test_a_layer_used_twice_falls_back_to_the_vmap_fisher():
    """Shared weights: each sample's gradient is a sum of outer products, so the outer-product
    shortcut does not apply and the vmap Fisher is returned."""
    g = torch.Generator().manual_seed(1)

    class Twice(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lin = torch.nn.Linear(3, 3)

        def forward(self, x):
            return self.lin(torch.tanh(self.lin(x))).sum(-1)

    mod = Twice()
    x = torch.randn(50, 3, generator=g)
    y = 0.05 * torch.randn(50, generator=g)

    def loss(out, t):
        return bce_sdf_loss(out, t, 0.05)

    ref = diagonal_fisher(mod, (x,), y, loss)
    got = diagonal_fisher(mod, (x,), y, loss, method="outer")
    for name in ref:
        torch.testing.assert_close(got[name], ref[name])


def test_bench_fisher_times_both_methods_on_the_agent_decoder_and_they_agree(tmp_path):
    """scripts/bench_fisher.py: both methods timed in one run on the agent preset's decoder,
    and the two Fishers agree there (the equality the outer-product default rests on)."""
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "bench_fisher.py"
    spec = importlib.util.spec_from_file_location("bench_fisher", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "fisher.json"
    assert mod.main(["--samples", "96", "--repeats", "2", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["samples"] == 96 and set(doc["median_ms"]) == {"vmap", "outer"}
    assert all(len(v) == 2 and 0 < v[0] <= v[1] for v in doc["range_ms"].values())
    assert doc["max_rel_difference"] < 1e-4
    assert doc["ratio_vmap_over_outer"] == doc["median_ms"]["vmap"] / doc["median_ms"]["outer"]
    with pytest.raises(SystemExit):
        mod.main(["--repeats", "0"])
