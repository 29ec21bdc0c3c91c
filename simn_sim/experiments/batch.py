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
  the agent config as given (``agent_config``, which the config hash covers) and resolved
  with every default (``agent_config_resolved``), CLI arguments, package version and git
  commit.
* ``summary.md`` / ``summary.csv`` (means and 95 % CIs per agent over every record in the
  folder), ``success_spl.png`` and ``trajectories_<layout>.png``
  (:mod:`simn_sim.experiments.plots`), ``run_stats.json`` (rate, per-worker peak memory).

Resume: re-running into the same ``DIR`` skips every episode that already has a record without
an error for the same ``(episode_id, agent, config_hash)``. Errored records of the episodes to
run are removed from ``episodes.jsonl`` and the episodes run again. A different config for an
agent that already has records in ``DIR`` is refused (use another ``--out``): mixing would make
the summary meaningless. Several agents may share one ``DIR`` (side-by-side summary).

Backends: ``local`` is a process pool with the ``spawn`` start method
(:mod:`simn_sim.experiments.batch_local`; ``workers=0`` runs in this process, for debugging);
``ray`` runs the same episodes as Ray tasks (:mod:`simn_sim.experiments.batch_ray`). What a
worker runs is :mod:`simn_sim.experiments.batch_worker`: a failing episode gets an error record
and the batch goes on; a worker process that dies is replaced and the death pinned on its
episode. The config is :class:`BatchConfig` (:mod:`simn_sim.experiments.batch_config`), the
folder's files are :mod:`simn_sim.experiments.batch_files`, the summary and plots
:mod:`simn_sim.experiments.batch_report`. Every public name stays importable from here.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from simn_sim.experiments.batch_config import (
    BatchConfig,
    BatchError,
    load_yaml,
    resolve_env_config,
)
from simn_sim.experiments.batch_files import (
    EPISODE_SET_FILE,
    RECORDS_FILE,
    append_record,
    merge_episode_set,
    provenance,
    read_records_lenient,
    safe_name,
    trajectory_file,
    write_records,
)
from simn_sim.experiments.batch_local import run_inprocess, run_local
from simn_sim.experiments.batch_report import BATCH_METRICS, write_reports
from simn_sim.experiments.batch_worker import (
    MAX_ATTEMPTS,
    EpisodeResult,
    EpisodeTask,
    make_env,
    run_task,
)

__all__ = [
    "BATCH_METRICS",
    "EPISODE_SET_FILE",
    "MAX_ATTEMPTS",
    "RECORDS_FILE",
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
    from simn_sim.experiments.runner import config_hash, write_json

    cfg.validate()
    env_id, episodes_in = _episode_source(cfg)
    env_cfg = resolve_env_config(env_id, cfg.env_config)
    _check_agent(cfg.agent)
    chash = config_hash(env_cfg, cfg.agent, dict(cfg.agent_config))
    episodes = (
        episodes_in
        if episodes_in is not None
        else sample_episodes(env_id, env_cfg, int(cfg.n_episodes or 0), cfg.seed)
    )
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    done = _prepare_resume(out, cfg.agent, chash, env_id, episodes)
    conf = provenance(cfg, env_id, env_cfg, chash, episodes)  # a bad agent config fails here
    write_json(out / "config.json", conf)
    write_json(out / "configs" / f"{safe_name(cfg.agent)}-{chash}.json", conf)

    rrd_dir = out / "rrd" / safe_name(cfg.agent)
    tasks = [
        EpisodeTask(
            env_id=env_id,
            env_cfg=env_cfg,
            agent=cfg.agent,
            agent_cfg=dict(cfg.agent_config),
            episode=e,
            rerun_path=(
                str((rrd_dir / f"{safe_name(e['episode_id'])}.rrd").resolve())
                if cfg.rerun
                else None
            ),
            threads=cfg.threads_per_worker,
        )
        for e in _by_layout(episodes)
        if e["episode_id"] not in done
    ]
    skipped = [e["episode_id"] for e in episodes if e["episode_id"] in done]
    (out / "trajectories" / safe_name(cfg.agent)).mkdir(parents=True, exist_ok=True)
    sink = _Sink(out, _progress(len(tasks), cfg, skipped))

    t0 = time.perf_counter()
    ray_info: dict[str, Any] = {}
    try:
        if not tasks:
            pass
        elif cfg.backend == "ray":
            from simn_sim.experiments.batch_ray import run_ray

            ray_info = run_ray(tasks, cfg.workers, cfg.ray_address, sink, cfg.episodes_per_worker)
        elif cfg.workers == 0:
            run_inprocess(tasks, sink)
        else:
            run_local(tasks, min(cfg.workers, len(tasks)), sink, per_worker=cfg.episodes_per_worker)
    finally:
        if sink.bar is not None:
            sink.bar.close()
    wall = time.perf_counter() - t0
    written = sink.written
    result = BatchResult(out, written, skipped, wall, list(sink.workers.values()), chash, ray_info)
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


def _episode_source(cfg: BatchConfig) -> tuple[str, list[dict[str, Any]] | None]:
    """The env id and the episode file's specs (None: sample ``cfg.n_episodes``)."""
    if cfg.episode_file is None:
        return cfg.env_id or "SimnOffice-v0", None
    from simn_sim.env.episodes import EpisodeSet

    try:
        eset = EpisodeSet.load(cfg.episode_file)
    except (OSError, ValueError) as e:
        raise BatchError(str(e)) from e
    eps = eset.episodes
    if cfg.tag is not None:
        eps = [e for e in eps if cfg.tag in e.tags]
        if not eps:
            raise BatchError(f"{cfg.episode_file}: no episode carries the tag {cfg.tag!r}")
    return cfg.env_id or eset.env_id, [e.to_dict() for e in eps]


def _prepare_resume(
    out: Path, agent: str, chash: str, env_id: str, episodes: list[dict[str, Any]]
) -> set[str]:
    """The ids of ``agent``'s episodes already done in ``out`` with config hash ``chash``.

    Errored (or half-written) records of the episodes to run are removed so that they run
    again; records of ``agent`` with another config hash are refused (:class:`BatchError`,
    before anything in ``out`` changes)."""
    rec_path = out / RECORDS_FILE
    existing, dropped = read_records_lenient(rec_path)
    if dropped:
        print(f"{rec_path}: dropped an unfinished last line (killed batch)", file=sys.stderr)
    mine = [r for r in existing if r["agent"] == agent]
    other = sorted({r.get("config_hash") for r in mine if r.get("config_hash") != chash} - {None})
    if other:
        raise BatchError(
            f"{out} already holds records of agent {agent!r} with config hash(es) {other} "
            f"(this run: {chash}); use another --out for a different config"
        )
    done = {
        r["episode_id"] for r in mine if r.get("config_hash") == chash and r.get("error") is None
    }
    ids = {e["episode_id"] for e in episodes}
    keep = [
        r
        for r in existing
        if not (r["agent"] == agent and r["episode_id"] in ids and r["episode_id"] not in done)
    ]
    merge_episode_set(out, env_id, episodes)  # refuses before anything changes
    if dropped or len(keep) != len(existing):
        write_records(rec_path, keep)
    return done


class _Sink:
    """Takes each finished episode in the driver: appends its record (flushed), saves its
    trajectory, tallies the worker's figures and advances the progress bar."""

    def __init__(self, out: Path, bar: Any) -> None:
        self.out = out
        self.bar = bar
        self.written: list[dict[str, Any]] = []
        self.workers: dict[tuple[str, int], dict[str, Any]] = {}

    def __call__(self, task: EpisodeTask, res: EpisodeResult) -> None:
        rec = res.record
        append_record(self.out / RECORDS_FILE, rec)
        if len(res.trajectory_xy):
            np.save(trajectory_file(self.out, rec["agent"], rec["episode_id"]), res.trajectory_xy)
        self.written.append(rec)
        if res.pid >= 0:
            w = self.workers.setdefault(
                (res.host, res.pid),
                {"host": res.host, "pid": res.pid, "episodes": 0, "peak_rss_mb": 0.0, "cpu_s": 0.0},
            )
            w["episodes"] += 1
            w["cpu_s"] = round(w["cpu_s"] + res.cpu_s, 3)
            w["peak_rss_mb"] = max(w["peak_rss_mb"], round(res.peak_rss_mb, 1))
        if self.bar is not None:
            ok = sum(bool(r.get("success")) for r in self.written)
            err = sum(r.get("error") is not None for r in self.written)
            self.bar.set_postfix(success=f"{ok}/{len(self.written)}", errors=err, refresh=False)
            self.bar.update(1)


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


# --------------------------------------------------------------------------- regression set

#: The fixed regression set (``envs/episodes/regression_v1.json``) runs at this resolution.
REGRESSION_SET = "regression_v1"
REGRESSION_ENV_ID = "SimnOffice-v0"
# ideal sensing: the stored baselines (tests/baselines/regression_v1_*.jsonl) were recorded with it
REGRESSION_ENV_CONFIG: dict[str, Any] = {"width": 160, "height": 120, "sensing": "ideal"}
#: env config per regression set (others: REGRESSION_ENV_CONFIG). regression_real_v1: four
#: office_nav_v2 episodes at 320x240 under the env's default realistic sensing
REGRESSION_SETS: dict[str, dict[str, Any]] = {
    "regression_v1": REGRESSION_ENV_CONFIG,
    "regression_real_v1": {"width": 320, "height": 240},
}


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
        env_config=dict(REGRESSION_SETS.get(name, REGRESSION_ENV_CONFIG)),
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
    p.add_argument("--tag", default=None, help="only the episode file's episodes with this tag")
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
    p.add_argument(
        "--episodes-per-worker",
        type=int,
        default=BatchConfig.episodes_per_worker,
        help="replace the worker processes after about this many episodes each (a local pool of "
        "W runs N x W, then a fresh pool follows); their memory grows with each (0: never; "
        "default %(default)s)",
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
            tag=args.tag,
            workers=args.workers,
            backend=args.backend,
            rerun=args.rerun,
            env_config=load_yaml(args.config, "env config"),
            agent_config=load_yaml(args.agent_config, "agent config"),
            ray_address=args.ray_address,
            threads_per_worker=args.threads_per_worker,
            episodes_per_worker=args.episodes_per_worker,
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
