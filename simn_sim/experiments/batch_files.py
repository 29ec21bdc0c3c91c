"""The files of a batch output folder: names, the records file and the episode set.

Shared by the batch runner (:mod:`simn_sim.experiments.batch`), which writes the folder, and
the plots (:mod:`simn_sim.experiments.plots`), which read it.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from simn_sim.experiments.batch_config import BatchConfig, BatchError

__all__ = [
    "EPISODE_SET_FILE",
    "RECORDS_FILE",
    "append_record",
    "merge_episode_set",
    "provenance",
    "read_records_lenient",
    "safe_name",
    "trajectory_file",
    "write_records",
]

RECORDS_FILE = "episodes.jsonl"
EPISODE_SET_FILE = "episode_set.json"


def safe_name(s: str) -> str:
    """``s`` with every character but letters, digits and ``-_.=`` replaced by ``_``."""
    return "".join(c if c.isalnum() or c in "-_.=" else "_" for c in s)


def trajectory_file(out: Path, agent: str, episode_id: str) -> Path:
    """``out/trajectories/<agent>/<episode_id>.npy`` (names made file-safe)."""
    return out / "trajectories" / safe_name(agent) / f"{safe_name(episode_id)}.npy"


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


def write_records(path: Path, recs: Iterable[dict[str, Any]]) -> None:
    """Replace ``path`` with ``recs`` atomically (temporary file, fsync, rename)."""
    tmp = path.with_suffix(".jsonl.tmp")
    with tmp.open("w", encoding="utf-8") as f:
        for r in recs:
            f.write(json.dumps(r, default=str) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def append_record(path: Path, rec: dict[str, Any]) -> None:
    """Append one record and flush it to disk (a killed batch keeps it)."""
    with path.open("a", encoding="utf-8") as f:
        f.write(json.dumps(rec, default=str) + "\n")
        f.flush()
        os.fsync(f.fileno())


def merge_episode_set(out: Path, env_id: str, episodes: list[dict[str, Any]]) -> None:
    """Write ``episode_set.json`` (union with what the folder already ran); the same episode id
    with a different start/goal/layout is refused (:class:`BatchError`, nothing written)."""
    from simn_sim.env.episodes import EpisodeSet, EpisodeSpec

    p = out / EPISODE_SET_FILE
    known: dict[str, dict[str, Any]] = {}
    if p.is_file():
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
    EpisodeSet(env_id, [EpisodeSpec.from_dict(e) for e in known.values()]).save(p)


def resolved_agent_config(
    env_id: str, env_cfg: dict[str, Any], agent: str, agent_cfg: dict[str, Any]
) -> dict[str, Any]:
    """Every config value of ``agent`` with ``agent_cfg`` applied (defaults included), for
    config.json; a bad value fails here, before any episode runs."""
    import gymnasium as gym

    from simn_sim.agents import make_agent
    from simn_sim.config import ConfigError

    env = gym.make(env_id, config=env_cfg)
    try:
        return make_agent(agent, env.unwrapped, dict(agent_cfg)).config_dict()
    except (ConfigError, ValueError, TypeError) as e:
        raise BatchError(f"agent config for {agent!r}: {e}") from e
    finally:
        env.close()


def provenance(
    cfg: BatchConfig,
    env_id: str,
    env_cfg: dict[str, Any],
    chash: str,
    episodes: list[dict[str, Any]],
) -> dict[str, Any]:
    """``config.json`` of a batch run: the resolved configs, the episodes, the run's settings and where and with which code it ran."""
    ids = "\n".join(e["episode_id"] for e in episodes).encode()
    return {
        "env_id": env_id,
        "env": env_cfg,
        "agent": cfg.agent,
        "agent_config": dict(cfg.agent_config),
        "agent_config_resolved": resolved_agent_config(
            env_id, env_cfg, cfg.agent, cfg.agent_config
        ),
        "config_hash": chash,
        "episodes": {
            "source": str(cfg.episode_file) if cfg.episode_file else "sampled",
            "n": len(episodes),
            "seed": None if cfg.episode_file else cfg.seed,
            "ids_sha1": hashlib.sha1(ids).hexdigest()[:12],
        },
        "backend": cfg.backend,
        "workers": cfg.workers,
        "threads_per_worker": cfg.threads_per_worker,
        "ray_address": cfg.ray_address,
        "rerun": cfg.rerun,
        "cli_args": cfg.argv,
        "package_version": _package_version(),
        # the outcome of an episode depends on float rounding (a closed loop amplifies a last-bit
        # difference), so on these versions and on the CPU, not only on code and seed
        "dependencies": dependency_versions(),
        "cpu_model": cpu_model(),
        **_git_info(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "host": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


# the packages whose arithmetic an episode's numbers pass through (scripts/constraints.txt pins
# them for scripts/setup.sh)
NUMERIC_DEPENDENCIES = (
    "numpy",
    "scipy",
    "torch",
    "mujoco",
    "gtsam",
    "opencv-python-headless",
    "gymnasium",
    "networkx",
    "shapely",
    "scikit-image",
)


def dependency_versions() -> dict[str, str | None]:
    """Installed version of each of :data:`NUMERIC_DEPENDENCIES` (None: not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {}
    for name in NUMERIC_DEPENDENCIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def cpu_model(cpuinfo: str | None = None) -> str | None:
    """The CPU's model name, its family / model / stepping (one "AMD EPYC" name covers several
    microarchitectures whose kernels round differently) and the vector extensions that change
    which kernels numpy, torch and OpenBLAS run. ``cpuinfo``: the text of ``/proc/cpuinfo``
    (read on Linux when None; elsewhere ``platform.processor()`` or None)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return platform.processor() or None

    def field(key: str) -> str | None:
        m = re.search(rf"^{key}\s*:\s*(.+)$", cpuinfo, re.M)
        return m.group(1).strip() if m else None

    name, flags = field("model name"), field("flags")
    have = set(flags.split()) if flags else set()
    ext = [f for f in ("avx", "avx2", "fma", "avx512f", "avx512_vnni", "amx_tile") if f in have]
    ids = [(k, field(k)) for k in ("cpu family", "model", "stepping")]
    fms = ", ".join(f"{k.split()[-1]} {v}" for k, v in ids if v is not None)
    return f"{name or 'unknown'}{f' ({fms})' if fms else ''} [{' '.join(ext) or 'no avx'}]"


def machine_summary() -> str:
    """One line naming the machine a benchmark ran on: :func:`cpu_model`, the logical CPUs and
    the architecture (timings compare only within one such machine)."""
    return f"{cpu_model() or 'unknown CPU'}, {os.cpu_count()} logical CPUs, {platform.machine()}"


def _git(*args: str) -> str:
    root = Path(__file__).resolve().parents[2]
    cmd = ["git", "-C", str(root), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=10, check=True).stdout


def _git_info() -> dict[str, Any]:
    try:
        commit = _git("rev-parse", "HEAD").strip()
        dirty = _git("status", "--porcelain", "--untracked-files=no").strip()
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
