"""What a batch worker runs: one episode (:func:`run_task`) from a picklable
:class:`EpisodeTask`, in a pool process, a Ray worker or in-process.

A worker keeps its env between episodes (one per env id and config; the env itself rebuilds
the scene when an episode's layout differs). An episode failure never raises: the record's
``error`` holds it and the batch goes on.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import sys
from typing import Any

import numpy as np

__all__ = [
    "MAX_ATTEMPTS",
    "EpisodeResult",
    "EpisodeTask",
    "crash_result",
    "identity_record",
    "limit_threads",
    "make_env",
    "run_task",
]

#: An episode whose worker process dies this many times while it runs alone gets an error
#: record (local backend); Ray retries a task ``MAX_ATTEMPTS - 1`` times.
MAX_ATTEMPTS = 2


@dataclasses.dataclass(frozen=True)
class EpisodeTask:
    """One episode to run: everything a worker needs, picklable.

    ``env_cfg`` is the resolved env config (``EnvConfig.to_dict()``); ``episode`` an episode
    spec dict (``EpisodeSpec.to_dict()``); ``rerun_path`` where to write the ``.rrd`` or None.
    """

    env_id: str
    env_cfg: dict[str, Any]
    agent: str
    agent_cfg: dict[str, Any]
    episode: dict[str, Any]
    rerun_path: str | None = None
    threads: int = 1


@dataclasses.dataclass
class EpisodeResult:
    """What a worker sends back: the record, the driven path and where it ran."""

    record: dict[str, Any]
    trajectory_xy: np.ndarray  # (T+1, 2) float32 true base positions, world frame, metres
    pid: int
    host: str
    peak_rss_mb: float  # peak resident memory of the worker process so far
    cpu_s: float = 0.0  # CPU time (user + system, all threads) the worker spent on this task


_ENV_CACHE: dict[tuple[str, str], Any] = {}


def limit_threads(n: int) -> None:
    """Keep numeric libraries and Mesa's software renderer (llvmpipe, which otherwise starts
    one render thread per core) in a worker to ``n`` threads: the workers share the cores.
    Takes effect for libraries not yet loaded (a pool worker calls it before anything else)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "LP_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != n:
        torch.set_num_threads(n)


def _cpu_s() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def _peak_rss_mb() -> float:
    import resource

    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024.0 if sys.platform != "darwin" else kb / 2**20


def make_env(env_id: str, env_cfg: dict[str, Any]) -> Any:
    """``gym.make`` where the resolved config wins over the variant's registered kwargs."""
    import gymnasium as gym

    import simn_sim  # noqa: F401  (registers the env ids, selects the GL backend)

    spec_kw = gym.spec(env_id).kwargs or {}
    over = {k: env_cfg[k] for k in spec_kw if k in env_cfg}
    return gym.make(env_id, config=env_cfg, **over)


def _env_key(env_id: str, env_cfg: dict[str, Any]) -> tuple[str, str]:
    return env_id, json.dumps(env_cfg, sort_keys=True)


def _cached_env(env_id: str, env_cfg: dict[str, Any]) -> Any:
    key = _env_key(env_id, env_cfg)
    env = _ENV_CACHE.get(key)
    if env is None:
        for old in _ENV_CACHE.values():  # one env per worker: free the GL context first
            old.close()
        _ENV_CACHE.clear()
        env = make_env(env_id, env_cfg)
        _ENV_CACHE[key] = env
    return env


def _drop_cached_env(env_id: str, env_cfg: dict[str, Any]) -> None:
    env = _ENV_CACHE.pop(_env_key(env_id, env_cfg), None)
    if env is not None:
        try:
            env.close()
        except Exception:  # noqa: BLE001 - a broken env is dropped either way
            pass


def identity_record(task: EpisodeTask, error: str) -> dict[str, Any]:
    """An error record for ``task`` when the runner itself never got to run."""
    from simn_sim.experiments.runner import RECORD_FIELDS, config_hash

    rec: dict[str, Any] = {k: None for k in RECORD_FIELDS}
    rec.update(
        episode_id=task.episode["episode_id"],
        layout_seed=task.episode.get("layout_seed"),
        seed=int(task.episode.get("seed", 0)),
        agent=task.agent,
        env_id=task.env_id,
        config_hash=config_hash(task.env_cfg, task.agent, task.agent_cfg),
        termination="error",
        error=error,
    )
    return rec


def crash_result(task: EpisodeTask, why: str) -> EpisodeResult:
    """The result of a task whose worker died or failed outside the episode (pid -1)."""
    return EpisodeResult(identity_record(task, why), np.zeros((0, 2), np.float32), -1, "", 0.0)


def run_task(task: EpisodeTask, limit: bool = True) -> EpisodeResult:
    """Run one episode in this process, reusing this process's env. Never raises for an
    episode failure (the record's ``error`` holds it); runs in pool and Ray workers.
    ``limit``: apply ``task.threads`` (:func:`limit_threads`; off in-process)."""
    import traceback

    import gymnasium as gym

    from simn_sim.experiments.runner import run_episode

    if limit:
        limit_threads(task.threads)
    cpu0 = _cpu_s()
    xy: list[np.ndarray] = []

    class _Track(gym.Wrapper):
        """Collects the true base (x, y) after reset and every step."""

        def reset(self, **kw: Any) -> Any:
            obs, info = self.env.reset(**kw)
            xy.clear()
            xy.append(np.asarray(info["T_world_base"])[:2, 3].copy())
            return obs, info

        def step(self, action: Any) -> Any:
            out = self.env.step(action)
            xy.append(np.asarray(out[4]["T_world_base"])[:2, 3].copy())
            return out

    try:
        env = _cached_env(task.env_id, task.env_cfg)
    except Exception as e:  # noqa: BLE001 - recorded, the batch goes on
        rec = identity_record(task, f"{type(e).__name__}: {e}\n{traceback.format_exc()}")
    else:
        rec = run_episode(
            task.env_id,
            task.env_cfg,
            task.agent,
            task.agent_cfg,
            episode=task.episode,
            seed=int(task.episode.get("seed", 0)),
            rerun_path=task.rerun_path,
            env=_Track(env),
        )
        if rec.get("error") is not None:  # the env may be half-reset: start clean next time
            _drop_cached_env(task.env_id, task.env_cfg)
    traj = np.asarray(xy, np.float32).reshape(-1, 2)
    return EpisodeResult(
        rec, traj, os.getpid(), socket.gethostname(), _peak_rss_mb(), _cpu_s() - cpu0
    )
