"""Ray batch backend: the same episodes as Ray tasks (one CPU each).

``ray.init(address=...)`` joins a cluster; otherwise a local instance with ``num_cpus=workers``
starts (and stops after the batch). The driver writes every output except the ``.rrd`` files,
which the workers write (shared storage on a cluster).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from simn_sim.experiments.batch_config import RAY_MISSING, BatchError
from simn_sim.experiments.batch_local import ResultSink
from simn_sim.experiments.batch_worker import MAX_ATTEMPTS, EpisodeTask, crash_result, run_task

__all__ = ["run_ray"]


def _init(workers: int, address: str | None) -> None:
    import ray

    try:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(
                address="local",
                num_cpus=max(1, workers),
                include_dashboard=False,
                log_to_driver=False,
            )
    except Exception as e:  # noqa: BLE001 - ConnectionError, AuthenticationError, ...
        hint = (
            "; a cluster started with token authentication (the default of recent Ray) "
            "needs RAY_AUTH_MODE=token and its token (~/.ray/auth_token or RAY_AUTH_TOKEN) "
            "on the driver"
            if address
            else ""
        )
        where = f"join the Ray cluster at {address}" if address else "start a local Ray"
        raise BatchError(f"cannot {where}: {type(e).__name__}: {e}{hint}") from e


def run_ray(
    tasks: Sequence[EpisodeTask],
    workers: int,
    address: str | None,
    sink: ResultSink,
    per_worker: int = 0,
) -> dict[str, Any]:
    """Run ``tasks`` as Ray tasks; returns what Ray ran on (for ``run_stats.json``).
    ``per_worker``: a Ray worker process runs at most this many episodes (Ray's
    ``max_calls``; 0: no limit)."""
    try:
        import ray
    except ImportError as e:
        raise BatchError(RAY_MISSING) from e
    started = False
    t0 = time.perf_counter()
    if not ray.is_initialized():
        _init(workers, address)
        started = True
    info = {
        "ray_version": ray.__version__,
        "ray_resources": ray.cluster_resources(),
        "ray_init_s": time.perf_counter() - t0,
    }
    remote = ray.remote(num_cpus=1, max_retries=MAX_ATTEMPTS - 1, max_calls=per_worker)(run_task)
    try:
        refs = {remote.remote(t): t for t in tasks}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                t = refs.pop(ref)
                try:
                    res = ray.get(ref)
                except Exception as e:  # noqa: BLE001 - worker died or task failed
                    res = crash_result(t, f"Ray task failed: {type(e).__name__}: {e}")
                sink(t, res)
    except BaseException:
        for ref in list(refs):
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
    return info
