"""Batch throughput: episodes per hour with 1 and 2 workers, local process pool vs Ray.

    MUJOCO_GL=egl .venv/bin/python scripts/bench_batch.py [--repeats 2] [--json out.json]

Runs a small fixed oracle batch (``envs/episodes/regression_v1.json``: 6 short episodes over
3 layouts, geodesic 3-6 m; ``--episode-file`` for another set) on ``SimnOfficeFast-v0``
(320x240, ideal sensing like the regression gate) for each backend and worker count, each time
into a fresh folder, and reports:

* ``eps/h``: episodes per hour over the batch's wall time (pool start-up, worker imports and
  env creation included; for Ray, ``ray.init`` is excluded and reported on its own);
* scaling efficiency ``rate(2 workers) / (2 * rate(1 worker))``;
* peak resident memory per worker process (``getrusage`` in the worker) and of this driver;
* worker CPU seconds per episode (user + system, all threads, env creation included) and the
  rate one free core would give, ``3600 / cpu_s_per_episode``: robust to other jobs sharing
  the cores, unlike the wall-clock rate;
* the load average before each run (other jobs share the cores).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

ENV_ID = "SimnOfficeFast-v0"


def _cpu_model() -> str:
    from simn_sim.experiments.batch_files import cpu_model

    return cpu_model() or "unknown"


def run_one(
    backend: str, workers: int, tmp: Path, episode_file: Path | None = None, plots: bool = False
) -> dict[str, Any]:
    """One batch of ``episode_file`` (default: the regression set); returns its figures."""
    from simn_sim.experiments.batch import BatchConfig, regression_episode_file, run_batch

    load = os.getloadavg()[0]
    out = tmp / f"{backend}-{workers}-{len(list(tmp.iterdir()))}"
    res = run_batch(
        BatchConfig(
            out=out,
            agent="oracle",
            env_id=ENV_ID,
            env_config={"sensing": "ideal"},
            episode_file=episode_file or regression_episode_file(),
            workers=workers,
            backend=backend,
            progress=False,
            plots=plots,
        )
    )
    init = float(res.backend_info.get("ray_init_s", 0.0))
    wall = res.wall_time_s - init
    return {
        "backend": backend,
        "workers": workers,
        "episodes": len(res.records),
        "errors": res.n_errors,
        "wall_s": wall,
        "ray_init_s": init if backend == "ray" else None,
        "eps_per_hour": 3600.0 * len(res.records) / wall,
        "episode_wall_s_sum": sum(r["wall_time_s"] for r in res.records),
        "steps": sum(r["steps"] or 0 for r in res.records),
        "worker_peak_rss_mb": sorted(w["peak_rss_mb"] for w in res.workers),
        "cpu_s_per_episode": sum(w["cpu_s"] for w in res.workers) / max(1, len(res.records)),
        "n_worker_processes": len(res.workers),
        "loadavg_1min_before": load,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--backends", nargs="+", default=["local", "ray"])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--keep", type=Path, default=None, help="keep the batch folders here")
    p.add_argument(
        "--episode-file",
        type=Path,
        default=None,
        help="another episode set (default envs/episodes/regression_v1.json)",
    )
    args = p.parse_args(argv)
    if "ray" in args.backends:
        try:
            import ray  # noqa: F401
        except ImportError:
            print("Ray is not installed: benchmarking the local backend only", file=sys.stderr)
            args.backends = [b for b in args.backends if b != "ray"]

    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="simn-bench-batch-") as tmp_dir:
        tmp = args.keep or Path(tmp_dir)
        tmp.mkdir(parents=True, exist_ok=True)
        for rep in range(args.repeats):
            for backend in args.backends:
                for w in args.workers:
                    r = run_one(backend, w, tmp, args.episode_file, plots=args.keep is not None)
                    r["repeat"] = rep
                    runs.append(r)
                    print(
                        f"{backend:5s} workers={w} rep={rep}: {r['episodes']} eps in "
                        f"{r['wall_s']:.1f} s = {r['eps_per_hour']:.0f} eps/h, worker peak RSS "
                        f"{r['worker_peak_rss_mb']} MB, {r['cpu_s_per_episode']:.2f} CPU s/ep, "
                        f"load {r['loadavg_1min_before']:.2f}",
                        flush=True,
                    )

    def med(backend: str, w: int, key: str) -> float:
        return statistics.median(
            r[key] for r in runs if r["backend"] == backend and r["workers"] == w
        )

    print()
    print(f"machine: {_cpu_model()}, {os.cpu_count()} logical CPUs, {platform.platform()}")
    name = args.episode_file.stem if args.episode_file else "regression_v1"
    n_eps = runs[0]["episodes"] if runs else 0
    print(f"batch: {n_eps} oracle episodes ({name}), {ENV_ID} 320x240; median of {args.repeats}")
    print()
    print(
        "| backend | workers | eps/h | wall s | Ray init s | peak RSS / worker (MB) "
        "| CPU s / episode | eps/h per free core |"
    )
    print("|---|---|---|---|---|---|---|---|")
    summary: dict[str, Any] = {}
    for backend in args.backends:
        for w in args.workers:
            rss = max(max(r["worker_peak_rss_mb"]) for r in runs if r["backend"] == backend)
            init = med(backend, w, "ray_init_s") if backend == "ray" else None
            rate = med(backend, w, "eps_per_hour")
            cpu = med(backend, w, "cpu_s_per_episode")
            summary[f"{backend}_{w}"] = {
                "eps_per_hour": rate,
                "peak_rss_mb": rss,
                "cpu_s_per_episode": cpu,
            }
            print(
                f"| {backend} | {w} | {rate:.0f} | {med(backend, w, 'wall_s'):.1f} | "
                + (f"{init:.1f}" if init is not None else "-")
                + f" | {rss:.0f} | {cpu:.2f} | {3600 / cpu:.0f} |"
            )
        if 1 in args.workers and 2 in args.workers:
            eff = summary[f"{backend}_2"]["eps_per_hour"] / (
                2 * summary[f"{backend}_1"]["eps_per_hour"]
            )
            summary[f"{backend}_scaling_efficiency"] = eff
            print(f"| {backend} scaling efficiency | rate2 / (2 rate1) = {eff:.2f} | | | | | | |")
    driver = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\ndriver peak RSS: {driver:.0f} MB")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "machine": _cpu_model(),
                    "cpus": os.cpu_count(),
                    "runs": runs,
                    "summary": summary,
                    "driver_peak_rss_mb": driver,
                },
                indent=2,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
