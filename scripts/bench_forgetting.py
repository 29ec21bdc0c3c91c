#!/usr/bin/env python
"""Forgetting of the learned map inside the SLAM pipeline: one decoder shared by the local
frames with replay + EWC, with replay only, with neither, and a copy per frame (reference).

Runs :class:`~simn_sim.slam.pipeline.SimnSlam` (``map_kind: implicit``) on a rendered sequence
of an analytic room (exact depth, exact SDF; :mod:`simn_sim.slam.forgetting`): the camera
turns in place and a local frame closes every ``--frame-deg`` degrees. For the first local
frame it reports the SDF error (mean ``|F_theta - true SDF|`` at points within ``--band`` of
the surface it observed) right after it closed and after each later frame closed; forgetting
is the growth of that error. ``own`` is the mean error of every closed frame right after its
close (how well the frames are learned). With ``--seeds`` the runs repeat with other mapper
seeds and the table gives the mean (and the spread of the forgetting).

    .venv/bin/python scripts/bench_forgetting.py [--obs 70] [--color] [--seeds 0 1 2]
        [--preset default|converged] [--batch 1024] [--out forgetting.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time

import numpy as np
import torch

from simn_sim.experiments.batch_files import machine_summary
from simn_sim.slam.forgetting import VARIANTS, ForgettingSetup, base_config, measure_forgetting


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--obs", type=int, default=70, help="observations (views) in the sequence")
    ap.add_argument("--deg-per-obs", type=float, default=3.0)
    ap.add_argument(
        "--first-deg-per-obs", type=float, default=1.0, help="turn per view in the first frame"
    )
    ap.add_argument("--frame-deg", type=float, default=30.0, help="turn that closes a frame")
    ap.add_argument("--width", type=int, default=80)
    ap.add_argument("--height", type=int, default=60)
    ap.add_argument("--queries", type=int, default=100, help="query points per view")
    ap.add_argument("--band", type=float, default=0.05, help="query band around the surface, m")
    ap.add_argument("--color", action="store_true", help="painted walls (hue by azimuth)")
    ap.add_argument("--preset", choices=("default", "converged"), default="default")
    ap.add_argument("--batch", type=int, default=1024, help="training batch (0: the config's)")
    ap.add_argument("--open-iters", type=int, default=0, help="open_train_iters (0: config)")
    ap.add_argument("--train-iters", type=int, default=0, help="train_iters (0: config)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    setup = ForgettingSetup(
        n_obs=a.obs,
        deg_per_obs=a.deg_per_obs,
        first_deg_per_obs=a.first_deg_per_obs,
        queries_per_view=a.queries,
        frame_deg=a.frame_deg,
        width=a.width,
        height=a.height,
        band=a.band,
        color=a.color,
    )
    variants = {k: VARIANTS[k] for k in a.variants}
    runs = []
    t0 = time.perf_counter()
    for seed in a.seeds:
        cfg = base_config(a.preset, a.batch, seed, a.open_iters, a.train_iters)
        r = measure_forgetting(cfg, setup, variants, log=lambda m: print(m, file=sys.stderr))
        runs.append({"seed": seed, **r})
    wall = time.perf_counter() - t0

    mm = 1e3
    n_later = min(len(v["first_err_after"]) for r in runs for v in r["variants"].values())
    print(
        f"first local frame's SDF error, mm (|F - SDF| within {mm * a.band:.0f} mm of its "
        f"surface), mean over seeds {a.seeds}; +k: after k later frames closed; forgetting: "
        "mean of +1..+n minus 'at close' (per-seed range), final: +n minus 'at close'; own: "
        "every closed frame's error at its close"
    )
    print(
        f"{'variant':<18} {'at close':>8} "
        + " ".join(f"{'+' + str(k + 1):>6}" for k in range(n_later))
        + f" {'forgetting':>22} {'final':>6} {'own':>6} {'s/run':>6}"
    )
    summary = {}
    for name in variants:
        vs = [r["variants"][name] for r in runs]
        close = np.mean([v["first_err_close"] for v in vs])
        after = [np.mean([v["first_err_after"][k] for v in vs]) for k in range(n_later)]
        fm = np.array([np.mean(v["first_err_after"][:n_later]) - v["first_err_close"] for v in vs])
        ff = np.array([v["first_err_after"][n_later - 1] - v["first_err_close"] for v in vs])
        own = np.mean([np.mean(v["own_err_close"]) for v in vs])
        sec = np.mean([v["seconds"] for v in vs])
        summary[name] = {
            "first_err_close_mm": mm * close,
            "first_err_after_mm": [mm * x for x in after],
            "forgetting_mean_mm": mm * float(fm.mean()),
            "forgetting_mean_mm_per_seed": [mm * float(x) for x in fm],
            "forgetting_final_mm": mm * float(ff.mean()),
            "own_err_close_mm": mm * own,
            "seconds_per_run": sec,
        }
        rng = f" [{mm * fm.min():+.2f}, {mm * fm.max():+.2f}]" if len(fm) > 1 else ""
        print(
            f"{name:<18} {mm * close:8.2f} "
            + " ".join(f"{mm * x:6.2f}" for x in after)
            + f" {f'{mm * fm.mean():+.2f}{rng}':>22} {mm * ff.mean():+6.2f} {mm * own:6.2f}"
            + f" {sec:6.0f}"
        )
    # EWC against the same variant without it, seed by seed
    pairs = [("shared+replay+ewc", "shared+replay"), ("shared+ewc", "shared")]
    for on, off in pairs:
        if on in summary and off in summary:
            d = np.subtract(
                summary[on]["forgetting_mean_mm_per_seed"],
                summary[off]["forgetting_mean_mm_per_seed"],
            )
            summary[f"ewc_effect:{on}-{off}"] = {"per_seed_mm": d.tolist()}
            print(
                f"EWC: {on} minus {off}: forgetting {d.mean():+.2f} mm (mean), lower in "
                f"{int((d < 0).sum())} of {len(d)} seeds"
            )
    if a.out:
        doc = {
            "command": "scripts/bench_forgetting.py " + " ".join(argv or sys.argv[1:]),
            "date": datetime.date.today().isoformat(),
            "machine": f"{machine_summary()}, {torch.get_num_threads()} torch thread(s)",
            "preset": a.preset,
            "seeds": a.seeds,
            "summary": summary,
            "runs": runs,
            "wall_s": wall,
        }
        with open(a.out, "w") as f:
            json.dump(doc, f, indent=1)
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
