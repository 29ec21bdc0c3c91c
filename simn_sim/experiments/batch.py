"""Headless batch experiments: many episodes of one agent, in parallel, resumable.

``simn-sim batch`` (:func:`batch_main`) or :func:`run_batch` runs a set of episodes (an episode
file, or ``N`` episodes sampled from seeds ``S .. S+N-1``) with one agent and writes into
``DIR``:

* ``episodes.jsonl``: one record per episode (:data:`~simn_sim.experiments.runner.RECORD_FIELDS`),
  appended and flushed as soon as the episode is done, so a killed batch loses nothing finished.
* ``trajectories/<agent>/<episode_id>.npy``: the driven true (x, y) positions, (T+1, 2) float32,
  world frame (metres), start included.
* ``rrd/<agent>/<episode_id>.rrd`` with ``--rerun``: a rerun recording per episode.
* ``episode_set.json``: the episode specs that were run (an episode file of the same format, so
  a sampled batch can be re-run exactly with ``--episode-file``).
* ``config.json`` (and a copy ``configs/<agent>-<config_hash>.json``): resolved env config,
  agent config, CLI arguments, package version and git commit.
* ``summary.md`` / ``summary.csv`` (means and 95 % CIs per agent over every record in the
  folder), ``success_spl.png`` and ``trajectories_<layout>.png``
  (:mod:`simn_sim.experiments.plots`), ``run_stats.json`` (rate, per-worker peak memory).

Resume: re-running into the same ``DIR`` skips every episode that already has a record without
an error for the same ``(episode_id, agent, config_hash)``. Errored records of the episodes to
run are removed from ``episodes.jsonl`` and the episodes run again. A different config for an
agent that already has records in ``DIR`` is refused (use another ``--out``): mixing would make
the summary meaningless. Several agents may share one ``DIR`` (side-by-side summary).

Backends: ``local`` is a ``ProcessPoolExecutor`` with the ``spawn`` start method (an EGL
context must never be forked). Each worker keeps its env between episodes (one per env id and
config; the env itself rebuilds the scene when an episode's layout differs). At most ``workers``
episodes are in flight; when a worker process dies (e.g. a segfault in a native library) the
episodes that were in flight run again one at a time in a fresh process, so that the death is
pinned on the right episode, which gets an error record after dying twice on its own. ``workers=0`` runs in this process (debugging). ``ray``
runs the same episodes as Ray tasks (``ray.init(address=...)`` joins a cluster; otherwise a
local instance with ``num_cpus=workers``); the driver writes every output except the ``.rrd``
files, which the workers write (shared storage on a cluster).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import hashlib
import json
import math
import multiprocessing
import os
import platform
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "BatchConfig",
    "BatchError",
    "BatchResult",
    "EpisodeResult",
    "EpisodeTask",
    "batch_main",
    "build_parser",
    "make_env",
    "read_records_lenient",
    "regression_episode_file",
    "resolve_env_config",
    "run_regression",
    "run_batch",
    "run_task",
    "sample_episodes",
    "write_reports",
]

RECORDS_FILE = "episodes.jsonl"
EPISODE_SET_FILE = "episode_set.json"
#: Metrics in summary.md / summary.csv (record field names).
BATCH_METRICS: tuple[str, ...] = (
    "success",
    "spl",
    "soft_spl",
    "collisions",
    "collisions_with_people",
    "path_length_m",
    "steps",
    "plan_ms_median",
    "wall_time_s",
)
#: An episode whose worker process dies this many times while it runs alone gets an error
#: record (local backend); Ray retries a task ``MAX_ATTEMPTS - 1`` times.
MAX_ATTEMPTS = 2


class BatchError(ValueError):
    """Bad batch input or an output folder that cannot be resumed; the message says why."""


# --------------------------------------------------------------------------- tasks (workers)


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


def _limit_threads(n: int) -> None:
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


def _cached_env(env_id: str, env_cfg: dict[str, Any]) -> Any:
    key = (env_id, json.dumps(env_cfg, sort_keys=True))
    env = _ENV_CACHE.get(key)
    if env is None:
        for old in _ENV_CACHE.values():  # one env per worker: free the GL context first
            old.close()
        _ENV_CACHE.clear()
        env = make_env(env_id, env_cfg)
        _ENV_CACHE[key] = env
    return env


def _drop_cached_env(env_id: str, env_cfg: dict[str, Any]) -> None:
    env = _ENV_CACHE.pop((env_id, json.dumps(env_cfg, sort_keys=True)), None)
    if env is not None:
        try:
            env.close()
        except Exception:  # noqa: BLE001 - a broken env is dropped either way
            pass


def _identity_record(task: EpisodeTask, error: str) -> dict[str, Any]:
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


def run_task(task: EpisodeTask, limit_threads: bool = True) -> EpisodeResult:
    """Run one episode in this process, reusing this process's env. Never raises for an
    episode failure (the record's ``error`` holds it); runs in pool and Ray workers.
    ``limit_threads``: apply ``task.threads`` (:func:`_limit_threads`; off in-process)."""
    import traceback

    import gymnasium as gym

    from simn_sim.experiments.runner import run_episode

    if limit_threads:
        _limit_threads(task.threads)
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
        rec = _identity_record(task, f"{type(e).__name__}: {e}\n{traceback.format_exc()}")
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


# --------------------------------------------------------------------------- configuration


@dataclasses.dataclass
class BatchConfig:
    """One batch invocation (what the CLI parses into).

    Exactly one of ``episode_file`` and ``n_episodes`` is given. ``env_config`` holds env config
    values that override the env id's registered defaults; ``workers=0`` runs in-process.
    """

    out: Path
    agent: str
    env_id: str | None = None
    n_episodes: int | None = None
    seed: int = 0
    episode_file: Path | None = None
    workers: int = 1
    backend: str = "local"
    rerun: bool = False
    env_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    agent_config: dict[str, Any] = dataclasses.field(default_factory=dict)
    ray_address: str | None = None
    threads_per_worker: int = 1
    progress: bool = True
    plots: bool = True
    argv: list[str] | None = None

    def validate(self) -> None:
        if (self.episode_file is None) == (self.n_episodes is None):
            raise BatchError("give exactly one of --episodes N and --episode-file F")
        if self.n_episodes is not None and self.n_episodes < 1:
            raise BatchError(f"--episodes must be >= 1, got {self.n_episodes}")
        if self.workers < 0:
            raise BatchError(f"--workers must be >= 0, got {self.workers}")
        if self.backend not in ("local", "ray"):
            raise BatchError(f"--backend must be 'local' or 'ray', got {self.backend!r}")
        if self.backend == "ray" and self.workers < 1 and self.ray_address is None:
            raise BatchError("--backend ray needs --workers >= 1 (or --ray-address)")
        if self.threads_per_worker < 1:
            raise BatchError(f"--threads-per-worker must be >= 1, got {self.threads_per_worker}")
        if self.backend == "ray":
            import importlib.util

            if importlib.util.find_spec("ray") is None:
                raise BatchError(
                    "--backend ray needs Ray: pip install 'simn-sim[ray]' (or 'ray[default]')"
                )


def resolve_env_config(env_id: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The full env config for ``env_id``: its registered defaults, then ``overrides``.

    Raises:
        BatchError: unknown env id or an invalid config value (the message names the field).
    """
    import gymnasium as gym

    import simn_sim  # noqa: F401
    from simn_sim.config import ConfigError
    from simn_sim.env.office import EnvConfig

    try:
        spec = gym.spec(env_id)
    except gym.error.Error as e:
        ids = sorted(k for k in gym.registry if k.startswith("Simn"))
        raise BatchError(f"unknown env id {env_id!r}; valid ids: {ids}") from e
    try:
        return EnvConfig.from_dict({**(spec.kwargs or {}), **overrides}).to_dict()
    except ConfigError as e:
        raise BatchError(f"env config: {e}") from e


def sample_episodes(
    env_id: str, env_cfg: dict[str, Any], n: int, seed: int
) -> list[dict[str, Any]]:
    """``n`` episode specs sampled as ``reset(seed=seed + i)`` samples them, with ids
    ``seed-<seed+i>`` and ``seed`` set, so they can be stored, resumed and re-run exactly.
    Sampling renders at 64x48 (start/goal sampling does not depend on the image size)."""
    small = {**env_cfg, "width": 64, "height": 48}
    env = make_env(env_id, small)
    try:
        out = []
        for i in range(n):
            s = seed + i
            _, info = env.reset(seed=s)
            spec = dict(info["episode_spec"])
            spec.update(episode_id=f"seed-{s}", seed=s)
            out.append(spec)
        return out
    finally:
        env.close()


def _load_yaml(path: str | Path | None, what: str) -> dict[str, Any]:
    if path is None:
        return {}
    import yaml

    try:
        d = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise BatchError(f"cannot read {what} file {path}: {e}") from e
    if not isinstance(d, dict):
        raise BatchError(f"{what} file {path} must hold a mapping, got {type(d).__name__}")
    return d


def _git_info() -> dict[str, Any]:
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        return {"git_commit": commit or None, "git_dirty": bool(dirty)}
    except (OSError, subprocess.SubprocessError):
        return {"git_commit": None, "git_dirty": None}


def _package_version() -> str:
    try:
        from importlib.metadata import version

        return version("simn-sim")
    except Exception:  # noqa: BLE001 - not installed as a distribution
        import simn_sim

        return simn_sim.__version__


# --------------------------------------------------------------------------- output folder


def read_records_lenient(path: Path) -> tuple[list[dict[str, Any]], bool]:
    """Records of an ``episodes.jsonl`` being resumed.

    A last line that is not valid JSON is an unfinished write of a killed batch and is dropped
    (returned flag True); a corrupt line elsewhere raises :class:`BatchError`.
    """
    if not path.is_file():
        return [], False
    lines = path.read_text(encoding="utf-8").splitlines()
    recs: list[dict[str, Any]] = []
    dropped = False
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or "episode_id" not in rec or "agent" not in rec:
                raise ValueError("not an episode record")
        except ValueError as e:
            if all(not rest.strip() for rest in lines[i + 1 :]):
                dropped = True
                break
            raise BatchError(f"{path}:{i + 1}: corrupt record ({e}); fix or remove it") from e
        recs.append(rec)
    return recs, dropped


def _write_records(path: Path, recs: Iterable[dict[str, Any]]) -> None:
    tmp = path.with_suffix(".jsonl.tmp")
    with tmp.open("w", encoding="utf-8") as f:
        for r in recs:
            f.write(json.dumps(r, default=str) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _safe_name(s: str) -> str:
    return "".join(c if c.isalnum() or c in "-_.=" else "_" for c in s)


def _check_and_merge_episode_set(out: Path, env_id: str, episodes: list[dict[str, Any]]) -> None:
    """Write ``episode_set.json`` (union with what the folder already ran); the same episode id
    with a different start/goal/layout is refused."""
    p = out / EPISODE_SET_FILE
    known: dict[str, dict[str, Any]] = {}
    if p.is_file():
        from simn_sim.env.episodes import EpisodeSet

        try:
            known = {e.episode_id: e.to_dict() for e in EpisodeSet.load(p).episodes}
        except ValueError as e:
            raise BatchError(f"{p}: {e}") from e
    for ep in episodes:
        old = known.get(ep["episode_id"])
        if old is not None and old != ep:
            raise BatchError(
                f"{out}: episode {ep['episode_id']!r} was run there with a different spec "
                f"({old} vs {ep}); use another --out"
            )
        known[ep["episode_id"]] = ep
    from simn_sim.env.episodes import EpisodeSet, EpisodeSpec

    EpisodeSet(env_id, [EpisodeSpec.from_dict(e) for e in known.values()]).save(p)


# --------------------------------------------------------------------------- backends

ResultSink = Callable[[EpisodeTask, EpisodeResult], None]


def _crash_result(task: EpisodeTask, why: str) -> EpisodeResult:
    return EpisodeResult(_identity_record(task, why), np.zeros((0, 2), np.float32), -1, "", 0.0)


def _run_inprocess(tasks: Sequence[EpisodeTask], sink: ResultSink) -> None:
    for t in tasks:
        sink(t, run_task(t, limit_threads=False))


def _worker_init(threads: int) -> None:
    _limit_threads(threads)


def _pool_pass(
    queue: list[EpisodeTask],
    width: int,
    sink: ResultSink,
    fn: Callable[[EpisodeTask], EpisodeResult],
    threads: int,
) -> list[EpisodeTask]:
    """Run tasks popped from ``queue`` in one spawn pool of ``width`` processes, at most
    ``width`` in flight. Returns the tasks that were in flight when a worker process died
    (the pool is then unusable; the rest stay in ``queue``), or [] when ``queue`` ran empty."""
    from concurrent.futures.process import BrokenProcessPool

    pool = cf.ProcessPoolExecutor(
        max_workers=width,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_worker_init,
        initargs=(threads,),
    )
    inflight: dict[cf.Future, EpisodeTask] = {}
    broken = False
    try:
        while queue or inflight:
            while queue and len(inflight) < width:
                t = queue.pop()
                inflight[pool.submit(fn, t)] = t
            done, _ = cf.wait(inflight, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                try:
                    res = fut.result()
                except BrokenProcessPool:
                    broken = True
                    continue  # stays in flight: returned below
                except Exception as e:  # noqa: BLE001 - e.g. an unpicklable result
                    res = _crash_result(inflight[fut], f"{type(e).__name__} in the worker: {e}")
                sink(inflight.pop(fut), res)
            if broken:
                return list(inflight.values())
        return []
    finally:
        pool.shutdown(wait=not broken, cancel_futures=True)


def _run_local(
    tasks: Sequence[EpisodeTask],
    workers: int,
    sink: ResultSink,
    fn: Callable[[EpisodeTask], EpisodeResult] = run_task,
) -> None:
    """Process pool (spawn), at most ``workers`` episodes in flight.

    When a worker process dies, the episodes that were in flight are suspects: each runs again
    alone in a fresh one-process pool, so a death is pinned on the right episode; one whose
    process dies ``MAX_ATTEMPTS`` times on its own gets an error record, the others their
    normal record. ``fn``: the task function (module-level, so that a spawned worker can
    import it; tests swap it)."""
    queue = list(reversed(tasks))
    threads = tasks[0].threads if tasks else 1
    suspects: list[EpisodeTask] = []
    deaths: dict[int, int] = {}
    while queue or suspects:
        if suspects:
            t = suspects.pop()
            if _pool_pass([t], 1, sink, fn, threads):
                deaths[id(t)] = deaths.get(id(t), 0) + 1
                if deaths[id(t)] >= MAX_ATTEMPTS:
                    why = f"worker process died running this episode alone {deaths[id(t)]} times"
                    sink(t, _crash_result(t, why))
                else:
                    suspects.append(t)
        else:
            suspects.extend(_pool_pass(queue, workers, sink, fn, threads))


def _run_ray(
    tasks: Sequence[EpisodeTask], workers: int, address: str | None, sink: ResultSink
) -> dict[str, Any]:
    """Ray tasks (one CPU each); returns what Ray ran on (for config.json)."""
    try:
        import ray
    except ImportError as e:
        raise BatchError(
            "--backend ray needs Ray: pip install 'simn-sim[ray]' (or 'ray[default]')"
        ) from e
    started = False
    t0 = time.perf_counter()
    if not ray.is_initialized():
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
        started = True
    info = {
        "ray_version": ray.__version__,
        "ray_resources": ray.cluster_resources(),
        "ray_init_s": time.perf_counter() - t0,
    }
    remote = ray.remote(num_cpus=1, max_retries=MAX_ATTEMPTS - 1)(run_task)
    try:
        refs = {remote.remote(t): t for t in tasks}
        while refs:
            done, _ = ray.wait(list(refs), num_returns=1)
            for ref in done:
                t = refs.pop(ref)
                try:
                    res = ray.get(ref)
                except Exception as e:  # noqa: BLE001 - worker died or task failed
                    res = _crash_result(t, f"Ray task failed: {type(e).__name__}: {e}")
                sink(t, res)
    except BaseException:
        for ref in list(refs):
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
    return info


# --------------------------------------------------------------------------- the batch


@dataclasses.dataclass
class BatchResult:
    """What :func:`run_batch` did. ``records``: the records written by this run (in order of
    completion); ``skipped``: episode ids already done; ``workers``: per worker process
    ``{pid, host, episodes, peak_rss_mb, cpu_s}`` (``cpu_s``: CPU seconds spent on tasks, env
    creation included)."""

    out: Path
    records: list[dict[str, Any]]
    skipped: list[str]
    wall_time_s: float
    workers: list[dict[str, Any]]
    config_hash: str
    backend_info: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def n_errors(self) -> int:
        return sum(r.get("error") is not None for r in self.records)

    @property
    def episodes_per_hour(self) -> float:
        return 3600.0 * len(self.records) / self.wall_time_s if self.wall_time_s > 0 else math.nan


def run_batch(cfg: BatchConfig) -> BatchResult:
    """Run (or resume) a batch; see the module docstring for the outputs.

    Raises:
        BatchError: invalid input, or an output folder holding records of this agent with a
            different config.
    """
    from simn_sim.env.episodes import EpisodeSet
    from simn_sim.experiments.runner import config_hash, write_json

    cfg.validate()
    if cfg.episode_file is not None:
        try:
            eset = EpisodeSet.load(cfg.episode_file)
        except (OSError, ValueError) as e:
            raise BatchError(str(e)) from e
        env_id = cfg.env_id or eset.env_id
    else:
        eset = None
        env_id = cfg.env_id or "SimnOffice-v0"
    env_cfg = resolve_env_config(env_id, cfg.env_config)
    _check_agent(cfg.agent)
    chash = config_hash(env_cfg, cfg.agent, dict(cfg.agent_config))
    episodes = (
        [e.to_dict() for e in eset.episodes]
        if eset is not None
        else sample_episodes(env_id, env_cfg, int(cfg.n_episodes or 0), cfg.seed)
    )

    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    rec_path = out / RECORDS_FILE
    existing, dropped = read_records_lenient(rec_path)
    if dropped:
        print(f"{rec_path}: dropped an unfinished last line (killed batch)", file=sys.stderr)
    ids = {e["episode_id"] for e in episodes}
    other = sorted(
        {
            r.get("config_hash")
            for r in existing
            if r["agent"] == cfg.agent and r.get("config_hash") != chash
        }
        - {None}
    )
    if other:
        raise BatchError(
            f"{out} already holds records of agent {cfg.agent!r} with config hash(es) {other} "
            f"(this run: {chash}); use another --out for a different config"
        )
    done = {
        r["episode_id"]
        for r in existing
        if r["agent"] == cfg.agent and r.get("config_hash") == chash and r.get("error") is None
    }
    keep = [
        r
        for r in existing
        if not (r["agent"] == cfg.agent and r["episode_id"] in ids and r["episode_id"] not in done)
    ]
    _check_and_merge_episode_set(out, env_id, episodes)  # refuses before anything changes
    if dropped or len(keep) != len(existing):
        _write_records(rec_path, keep)  # errored (or half-written) records run again

    conf = {
        "env_id": env_id,
        "env": env_cfg,
        "agent": cfg.agent,
        "agent_config": dict(cfg.agent_config),
        "config_hash": chash,
        "episodes": {
            "source": str(cfg.episode_file) if cfg.episode_file else "sampled",
            "n": len(episodes),
            "seed": None if cfg.episode_file else cfg.seed,
            "ids_sha1": hashlib.sha1(
                "\n".join(e["episode_id"] for e in episodes).encode()
            ).hexdigest()[:12],
        },
        "backend": cfg.backend,
        "workers": cfg.workers,
        "threads_per_worker": cfg.threads_per_worker,
        "ray_address": cfg.ray_address,
        "rerun": cfg.rerun,
        "cli_args": cfg.argv,
        "package_version": _package_version(),
        **_git_info(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "host": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    write_json(out / "config.json", conf)
    write_json(out / "configs" / f"{_safe_name(cfg.agent)}-{chash}.json", conf)

    agent_dir = _safe_name(cfg.agent)
    tasks = [
        EpisodeTask(
            env_id=env_id,
            env_cfg=env_cfg,
            agent=cfg.agent,
            agent_cfg=dict(cfg.agent_config),
            episode=e,
            rerun_path=(
                str((out / "rrd" / agent_dir / f"{_safe_name(e['episode_id'])}.rrd").resolve())
                if cfg.rerun
                else None
            ),
            threads=cfg.threads_per_worker,
        )
        for e in _by_layout(episodes)
        if e["episode_id"] not in done
    ]
    skipped = [e["episode_id"] for e in episodes if e["episode_id"] in done]

    written: list[dict[str, Any]] = []
    workers: dict[tuple[str, int], dict[str, Any]] = {}
    traj_dir = out / "trajectories" / agent_dir
    traj_dir.mkdir(parents=True, exist_ok=True)
    bar = _progress(len(tasks), cfg, skipped)

    def sink(task: EpisodeTask, res: EpisodeResult) -> None:
        rec = res.record
        with rec_path.open("a", encoding="utf-8") as f:
            f.write(json.dumps(rec, default=str) + "\n")
            f.flush()
            os.fsync(f.fileno())
        if len(res.trajectory_xy):
            np.save(traj_dir / f"{_safe_name(rec['episode_id'])}.npy", res.trajectory_xy)
        written.append(rec)
        if res.pid >= 0:
            w = workers.setdefault(
                (res.host, res.pid),
                {"host": res.host, "pid": res.pid, "episodes": 0, "peak_rss_mb": 0.0, "cpu_s": 0.0},
            )
            w["episodes"] += 1
            w["cpu_s"] = round(w["cpu_s"] + res.cpu_s, 3)
            w["peak_rss_mb"] = max(w["peak_rss_mb"], round(res.peak_rss_mb, 1))
        if bar is not None:
            ok = sum(bool(r.get("success")) for r in written)
            err = sum(r.get("error") is not None for r in written)
            bar.set_postfix(success=f"{ok}/{len(written)}", errors=err, refresh=False)
            bar.update(1)

    t0 = time.perf_counter()
    ray_info: dict[str, Any] = {}
    try:
        if not tasks:
            pass
        elif cfg.backend == "ray":
            ray_info = _run_ray(tasks, cfg.workers, cfg.ray_address, sink)
        elif cfg.workers == 0:
            _run_inprocess(tasks, sink)
        else:
            _run_local(tasks, min(cfg.workers, len(tasks)), sink)
    finally:
        if bar is not None:
            bar.close()
    wall = time.perf_counter() - t0
    result = BatchResult(out, written, skipped, wall, list(workers.values()), chash, ray_info)
    write_json(
        out / "run_stats.json",
        {
            "config_hash": chash,
            "agent": cfg.agent,
            "episodes_run": len(written),
            "episodes_skipped": len(skipped),
            "errors": result.n_errors,
            "wall_time_s": wall,
            "episodes_per_hour": result.episodes_per_hour if written else None,
            "workers": result.workers,
            **ray_info,
        },
    )
    write_reports(out, plots=cfg.plots)
    return result


def _by_layout(episodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Episodes grouped by layout (stable), so a worker rebuilds its scene as rarely as it can."""
    first: dict[Any, int] = {}
    for i, e in enumerate(episodes):
        first.setdefault(e.get("layout_seed"), i)
    return sorted(episodes, key=lambda e: first[e.get("layout_seed")])


def _check_agent(name: str) -> None:
    from simn_sim.agents import agent_names

    names = agent_names()
    if name not in names:
        raise BatchError(f"unknown agent {name!r}; valid agents: {names}")


def _progress(total: int, cfg: BatchConfig, skipped: list[str]) -> Any:
    if not cfg.progress:
        return None
    from tqdm import tqdm

    desc = f"{cfg.agent} ({cfg.backend}, {cfg.workers} worker{'s' if cfg.workers != 1 else ''})"
    if skipped:
        desc += f", {len(skipped)} done before"
    return tqdm(total=total, desc=desc, unit="ep", dynamic_ncols=True)


def write_reports(out: str | Path, plots: bool = True) -> dict[str, Path]:
    """(Re)write ``summary.md``, ``summary.csv`` and the plots from the records in ``out``.

    Returns the written files by name. Records of every agent in the folder are summarised.
    """
    from simn_sim.experiments.stats import summarize, summary_markdown, write_summary_csv

    out = Path(out)
    recs, _ = read_records_lenient(out / RECORDS_FILE)
    files: dict[str, Path] = {}
    if not recs:
        return files
    rows = summarize(recs, BATCH_METRICS)
    n_err = sum(r.get("error") is not None for r in recs)
    md = [
        f"# Batch summary: {out.name}",
        "",
        f"{len(recs)} episode records; means with 95 % Student-t confidence intervals. "
        "Errored episodes count as failures (0) for success/spl/soft_spl and are left out of "
        "the other metrics.",
        "",
        summary_markdown(rows),
    ]
    if n_err:
        md += ["## Errors", ""]
        for r in recs:
            if r.get("error") is not None:
                first = str(r["error"]).splitlines()[0]
                md.append(f"- `{r['agent']}` `{r['episode_id']}`: {first}")
        md.append("")
    files["summary.md"] = out / "summary.md"
    files["summary.md"].write_text("\n".join(md))
    files["summary.csv"] = out / "summary.csv"
    write_summary_csv(rows, files["summary.csv"])
    if plots:
        from simn_sim.experiments.plots import plot_success_spl, plot_trajectories

        files["success_spl.png"] = plot_success_spl(rows, out / "success_spl.png")
        for p in plot_trajectories(out):
            files[p.name] = p
    return files


# --------------------------------------------------------------------------- regression set

#: The fixed regression set (``envs/episodes/regression_v1.json``) runs at this resolution.
REGRESSION_SET = "regression_v1"
REGRESSION_ENV_ID = "SimnOffice-v0"
REGRESSION_ENV_CONFIG: dict[str, Any] = {"width": 160, "height": 120}


def regression_episode_file(name: str = REGRESSION_SET) -> Path:
    """``envs/episodes/<name>.json``."""
    from simn_sim.paths import envs_dir

    return envs_dir() / "episodes" / f"{name}.json"


def run_regression(
    agent: str,
    out: str | Path,
    workers: int = 0,
    agent_config: dict[str, Any] | None = None,
    name: str = REGRESSION_SET,
) -> list[dict[str, Any]]:
    """Run the regression episode set with ``agent`` into ``out`` (a fresh or resumable batch
    folder, no plots) and return all of that agent's records there, in episode-file order.
    Used by ``tests/test_regression_nav.py`` and ``scripts/refresh_regression_baseline.py``."""
    f = regression_episode_file(name)
    cfg = BatchConfig(
        out=Path(out),
        agent=agent,
        env_id=REGRESSION_ENV_ID,
        episode_file=f,
        workers=workers,
        env_config=dict(REGRESSION_ENV_CONFIG),
        agent_config=dict(agent_config or {}),
        progress=False,
        plots=False,
    )
    run_batch(cfg)
    from simn_sim.env.episodes import EpisodeSet

    order = {e.episode_id: i for i, e in enumerate(EpisodeSet.load(f).episodes)}
    recs, _ = read_records_lenient(Path(out) / RECORDS_FILE)
    mine = [r for r in recs if r["agent"] == agent and r["episode_id"] in order]
    return sorted(mine, key=lambda r: order[r["episode_id"]])


# --------------------------------------------------------------------------- CLI


def build_parser() -> argparse.ArgumentParser:
    """The ``simn-sim batch`` argument parser."""
    p = argparse.ArgumentParser(
        prog="simn-sim batch",
        description="Run many headless episodes of one agent in parallel; resumable.",
    )
    p.add_argument(
        "--env", default=None, help="env id (default: the episode file's, else SimnOffice-v0)"
    )
    p.add_argument("--agent", required=True, help="agent name (oracle, simn, rrtstar, ...)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--episodes", type=int, help="sample N episodes from seeds S..S+N-1")
    src.add_argument("--episode-file", type=Path, help="episode set JSON (envs/episodes/)")
    p.add_argument("--seed", type=int, default=0, help="first seed with --episodes")
    p.add_argument("--workers", type=int, default=1, help="parallel episodes (0: in-process)")
    p.add_argument("--backend", choices=["local", "ray"], default="local")
    p.add_argument("--out", type=Path, required=True, help="output folder (resumable)")
    p.add_argument("--rerun", action="store_true", help="write rrd/<agent>/<episode>.rrd")
    p.add_argument("--config", type=Path, default=None, help="YAML of env config values")
    p.add_argument("--agent-config", type=Path, default=None, help="YAML of agent config values")
    p.add_argument("--ray-address", default=None, help="join this Ray cluster (e.g. auto)")
    p.add_argument(
        "--threads-per-worker",
        type=int,
        default=1,
        help="threads per worker for OpenMP/MKL/torch and Mesa llvmpipe rendering (default 1)",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def batch_main(argv: list[str] | None = None) -> int:
    """``simn-sim batch`` entry point. Exit status: 0 all episodes ran without an error,
    1 some episode errored (recorded), 2 bad input, 130 interrupted (finished records kept)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code) if isinstance(exc.code, int) else 2
    try:
        cfg = BatchConfig(
            out=args.out,
            agent=args.agent,
            env_id=args.env,
            n_episodes=args.episodes,
            seed=args.seed,
            episode_file=args.episode_file,
            workers=args.workers,
            backend=args.backend,
            rerun=args.rerun,
            env_config=_load_yaml(args.config, "env config"),
            agent_config=_load_yaml(args.agent_config, "agent config"),
            ray_address=args.ray_address,
            threads_per_worker=args.threads_per_worker,
            progress=not args.no_progress,
            plots=not args.no_plots,
            argv=argv,
        )
        res = run_batch(cfg)
    except BatchError as e:
        print(f"simn-sim batch: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            "simn-sim batch: interrupted; finished episodes are kept (re-run to resume)",
            file=sys.stderr,
        )
        return 130
    n = len(res.records)
    ok = sum(bool(r.get("success")) for r in res.records)
    print(
        f"{n} episodes run ({ok} successful, {res.n_errors} errors), {len(res.skipped)} skipped "
        f"as done, {res.wall_time_s:.1f} s; wrote {res.out / RECORDS_FILE} and "
        f"{res.out / 'summary.md'}"
    )
    return 1 if res.n_errors else 0


if __name__ == "__main__":
    raise SystemExit(batch_main())
