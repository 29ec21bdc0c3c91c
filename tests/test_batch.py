"""Batch runner: records, outputs, a crashing episode, resume after a kill, Ray = local."""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from simn_sim.env.episodes import EpisodeSet, EpisodeSpec
from simn_sim.experiments.batch import (
    BatchConfig,
    BatchError,
    batch_main,
    read_records_lenient,
    regression_episode_file,
    run_batch,
)
from simn_sim.experiments.runner import RECORD_FIELDS
from simn_sim.experiments.stats import load_records

SMALL = {"width": 160, "height": 120}
#: Outcome fields that must agree exactly between two runs of the same episodes.
OUTCOME = (
    "episode_id",
    "layout_seed",
    "seed",
    "agent",
    "env_id",
    "config_hash",
    "success",
    "spl",
    "soft_spl",
    "path_length_m",
    "geodesic_distance_m",
    "collisions",
    "collisions_with_people",
    "min_clearance_m",
    "steps",
    "termination",
    "sim_time_s",
    "error",
)


def _inside_obstacle() -> tuple[float, float]:
    """A point inside furniture of the reference office (checked against the exact free space)."""
    from simn_sim.env.office import load_layout
    from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND
    from simn_sim.geometry.freespace import FreeSpace2D

    lay = load_layout(None)
    polys = lay.footprints(ROBOT_Z_BAND)
    big = max(polys, key=lambda p: np.ptp(p[:, 0]) * np.ptp(p[:, 1]))
    xy = big.mean(axis=0)
    fs = FreeSpace2D(polys, robot_radius=ROBOT_RADIUS, bounds=lay.bounds)
    assert not fs.is_free(xy[None])[0]
    return float(xy[0]), float(xy[1])


def _episode_file(tmp: Path) -> Path:
    """Two short regression episodes (two layouts) and one starting inside an obstacle."""
    reg = {e.episode_id: e for e in EpisodeSet.load(regression_episode_file()).episodes}
    good = [reg["reg-ref-000"], reg["reg-L2-000"]]
    x, y = _inside_obstacle()
    bad = EpisodeSpec("bad-start", None, (x, y, 0.0), good[0].goal, seed=7)
    f = tmp / "eps.json"
    EpisodeSet("SimnOffice-v0", [good[0], bad, good[1]]).save(f)
    return f


def _lines(path: Path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if ln.strip()]


def test_local_batch_error_record_outputs_and_resume(tmp_path: Path) -> None:
    eps = _episode_file(tmp_path)
    out = tmp_path / "run"
    cfg = BatchConfig(
        out=out, agent="oracle", episode_file=eps, workers=2, env_config=SMALL, progress=False
    )
    res = run_batch(cfg)
    assert len(res.records) == 3 and res.n_errors == 1
    recs = {r["episode_id"]: r for r in load_records(out / "episodes.jsonl")}
    assert set(recs) == {"reg-ref-000", "reg-L2-000", "bad-start"}
    for r in recs.values():
        assert set(RECORD_FIELDS) <= set(r)
        assert r["agent"] == "oracle" and r["env_id"] == "SimnOffice-v0"
        assert r["config_hash"] == res.config_hash
    bad = recs["bad-start"]
    assert bad["termination"] == "error" and "not in free space" in bad["error"]
    assert "Traceback" in bad["error"] and bad["success"] is None
    for eid in ("reg-ref-000", "reg-L2-000"):
        r = recs[eid]
        assert r["error"] is None and r["success"] is True and 0.5 < r["spl"] <= 1.0
        xy = np.load(out / "trajectories" / "oracle" / f"{eid}.npy")
        assert xy.shape == (r["steps"] + 1, 2) and xy.dtype == np.float32
        spec = next(e for e in EpisodeSet.load(eps).episodes if e.episode_id == eid)
        np.testing.assert_allclose(xy[0], spec.start[:2], atol=1e-4)
        np.testing.assert_allclose(xy[-1], spec.goal, atol=0.37)  # within success_distance
        path_len = float(np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1)))
        assert path_len == pytest.approx(r["path_length_m"], rel=0.02, abs=0.02)
    # per-worker figures: two spawned processes (not this one), each with a plausible RSS
    import os

    assert {w["pid"] for w in res.workers} and os.getpid() not in {w["pid"] for w in res.workers}
    assert all(50 < w["peak_rss_mb"] < 8000 for w in res.workers)
    # reports
    conf = json.loads((out / "config.json").read_text())
    assert conf["env"]["width"] == 160 and conf["agent"] == "oracle"
    assert conf["config_hash"] == res.config_hash and conf["package_version"]
    assert "git_commit" in conf
    # the versions the numbers came from: those this process imports
    import mujoco
    import torch

    deps = conf["dependencies"]
    assert deps["numpy"] == np.__version__ and deps["torch"] == torch.__version__
    assert deps["mujoco"] == mujoco.__version__ and set(deps) >= {"scipy", "gtsam"}
    assert conf["cpu_model"]
    from simn_sim.agents.oracle import OracleConfig

    assert conf["agent_config_resolved"] == OracleConfig().to_dict()
    md = (out / "summary.md").read_text()
    assert "| oracle | 3 | 1 |" in md and "bad-start" in md
    csv = (out / "summary.csv").read_text().splitlines()
    assert csv[0].startswith("agent,metric,n,mean") and any(",success,3,0.666" in c for c in csv)
    for png in ("success_spl.png", "trajectories_ref.png", "trajectories_L2.png"):
        assert (out / png).stat().st_size > 5000
    set_ids = [e.episode_id for e in EpisodeSet.load(out / "episode_set.json").episodes]
    assert sorted(set_ids) == sorted(recs)

    # resume: finished episodes are skipped, the errored one runs again (and errors again)
    before = {json.loads(ln)["episode_id"]: ln for ln in _lines(out / "episodes.jsonl")}
    cfg = cfg.replace(workers=0)  # the config is frozen
    res2 = run_batch(cfg)
    assert sorted(res2.skipped) == ["reg-L2-000", "reg-ref-000"]
    assert [r["episode_id"] for r in res2.records] == ["bad-start"]
    after = _lines(out / "episodes.jsonl")
    assert len(after) == 3
    for ln in after:  # finished records kept byte for byte, nothing duplicated
        eid = json.loads(ln)["episode_id"]
        if eid != "bad-start":
            assert ln == before[eid]
    load_records(out / "episodes.jsonl")  # raises on a duplicate (episode_id, agent)

    # a batch killed mid-write: one record lost, a half-written last line
    kept = [ln for ln in after if json.loads(ln)["episode_id"] != "reg-L2-000"]
    (out / "episodes.jsonl").write_text("\n".join(kept) + "\n" + before["reg-L2-000"][:57])
    res3 = run_batch(cfg)
    assert sorted(r["episode_id"] for r in res3.records) == ["bad-start", "reg-L2-000"]
    final = load_records(out / "episodes.jsonl")
    assert sorted(r["episode_id"] for r in final) == ["bad-start", "reg-L2-000", "reg-ref-000"]
    again = next(r for r in final if r["episode_id"] == "reg-L2-000")
    old = json.loads(before["reg-L2-000"])
    assert {k: again[k] for k in OUTCOME} == {k: old[k] for k in OUTCOME}  # deterministic

    # the same agent with another config into the same folder is refused
    with pytest.raises(BatchError, match="config hash"):
        run_batch(
            BatchConfig(
                out=out,
                agent="oracle",
                episode_file=eps,
                workers=0,
                env_config=SMALL,
                agent_config={"margin": 0.2},
                progress=False,
            )
        )


def test_cli_sampled_episodes_with_rerun(tmp_path: Path) -> None:
    cfg_yaml = tmp_path / "env.yaml"
    cfg_yaml.write_text("width: 160\nheight: 120\nmin_geodesic: 2.0\nmax_geodesic: 4.0\n")
    out = tmp_path / "run"
    argv = ["--agent", "oracle", "--episodes", "2", "--seed", "5", "--workers", "0"]
    argv += ["--out", str(out), "--config", str(cfg_yaml), "--rerun", "--no-plots"]
    assert batch_main(argv) == 0
    recs = load_records(out / "episodes.jsonl")
    assert [r["episode_id"] for r in recs] == ["seed-5", "seed-6"]
    assert [r["seed"] for r in recs] == [5, 6]
    assert all(2.0 <= r["geodesic_distance_m"] <= 4.0 for r in recs)
    specs = EpisodeSet.load(out / "episode_set.json").episodes
    assert [e.episode_id for e in specs] == ["seed-5", "seed-6"]
    for r in recs:
        assert (out / "rrd" / "oracle" / f"{r['episode_id']}.rrd").stat().st_size > 10_000
    conf = json.loads((out / "config.json").read_text())
    assert conf["cli_args"] == argv and conf["env"]["max_geodesic"] == 4.0
    # the same command again: nothing to do, exit 0, the file unchanged
    before = (out / "episodes.jsonl").read_text()
    assert batch_main(argv) == 0
    assert (out / "episodes.jsonl").read_text() == before


@pytest.mark.parametrize(
    "argv, msg",
    [
        (["--agent", "oracle", "--episodes", "2", "--episode-file", "x.json"], "not allowed"),
        (["--agent", "nobody", "--episodes", "1"], "unknown agent"),
        (["--agent", "oracle", "--episodes", "1", "--env", "Nope-v0"], "unknown env id"),
        (["--agent", "oracle", "--episode-file", "missing.json"], "does not exist"),
        (["--agent", "oracle", "--episodes", "0"], "must be >= 1"),
    ],
)
def test_cli_bad_input_exit_2(
    argv: list[str], msg: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    assert batch_main([*argv, "--out", str(tmp_path / "o")]) == 2
    assert msg in capsys.readouterr().err


def test_bad_agent_config_fails_before_any_episode(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    bad = tmp_path / "agent.yaml"
    bad.write_text("obstacles:\n  transient:\n    point_share: 2.0\n")
    out = tmp_path / "o"
    argv = ["--agent", "simn", "--episodes", "1", "--agent-config", str(bad), "--out", str(out)]
    assert batch_main(argv) == 2
    assert "point_share" in capsys.readouterr().err
    assert not (out / "episodes.jsonl").exists()


def test_lenient_reader_rejects_corruption_in_the_middle(tmp_path: Path) -> None:
    p = tmp_path / "episodes.jsonl"
    good = json.dumps({"episode_id": "a", "agent": "oracle"})
    p.write_text(good + "\n{broken\n" + good.replace('"a"', '"b"') + "\n")
    with pytest.raises(BatchError, match=":2: corrupt record"):
        read_records_lenient(p)
    p.write_text(good + "\n{broken")
    recs, dropped = read_records_lenient(p)
    assert dropped and [r["episode_id"] for r in recs] == ["a"]


def _outcomes(recs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    return {r["episode_id"]: {k: r[k] for k in OUTCOME if k != "config_hash"} for r in recs}


def test_ray_backend_gives_the_same_records_as_local(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    eps = tmp_path / "eps.json"
    allr = EpisodeSet.load(regression_episode_file()).episodes
    EpisodeSet("SimnOffice-v0", [allr[0], allr[4]]).save(eps)
    common = dict(agent="oracle", episode_file=eps, env_config=SMALL, progress=False, plots=False)
    local = run_batch(BatchConfig(out=tmp_path / "local", workers=1, **common))
    ray_ = run_batch(BatchConfig(out=tmp_path / "ray", workers=2, backend="ray", **common))
    assert ray_.backend_info["ray_resources"]["CPU"] == 2.0
    assert len(ray_.records) == 2 and ray_.n_errors == 0
    assert _outcomes(ray_.records) == _outcomes(local.records)
    assert ray_.config_hash == local.config_hash


def _pid_task(task: Any) -> Any:
    """Stands in for ``run_task`` in a spawned worker: a clean record from this process."""
    import os

    from simn_sim.experiments.batch_worker import EpisodeResult, identity_record

    rec = identity_record(task, "")
    rec.update(error=None, termination="success", success=True)
    return EpisodeResult(rec, np.zeros((1, 2), np.float32), os.getpid(), "h", 1.0)


def _flaky_task(task: Any) -> Any:
    """Stands in for ``run_task`` in a spawned worker: ``die-*`` episodes kill the worker
    process (``die-once`` only on its first attempt, remembered by a marker file)."""
    import os

    eid = task.episode["episode_id"]
    marker = Path(task.rerun_path) if task.rerun_path else None
    if eid == "die-always" or (eid == "die-once" and marker is not None and not marker.exists()):
        if marker is not None:
            marker.touch()
        os._exit(3)
    return _pid_task(task)


def _task(eid: str, rerun_path: str | None = None) -> Any:
    """An episode task for the pool tests (their task functions never run the env)."""
    from simn_sim.experiments.batch_worker import EpisodeTask

    ep = {"episode_id": eid, "layout_seed": None, "seed": 0, "start": [0, 0, 0], "goal": [1, 1]}
    return EpisodeTask("SimnOffice-v0", {}, "oracle", {}, ep, rerun_path)


def test_local_pool_survives_a_dying_worker(tmp_path: Path) -> None:
    from simn_sim.experiments.batch_local import run_local

    tasks = [
        _task(e, str(tmp_path / f"{e}.mark")) for e in ("a", "die-once", "b", "die-always", "c")
    ]
    got: dict[str, list[dict[str, Any]]] = {}
    run_local(
        tasks,
        2,
        lambda t, r: got.setdefault(r.record["episode_id"], []).append(r.record),
        fn=_flaky_task,
    )
    assert sorted(got) == ["a", "b", "c", "die-always", "die-once"]
    assert all(len(v) == 1 for v in got.values())  # exactly one record per episode
    assert got["die-once"][0]["error"] is None  # retried in a fresh pool
    err = got["die-always"][0]["error"]
    assert err is not None and "worker process died" in err and "alone 2 times" in err
    for e in ("a", "b", "c"):  # innocent bystanders of a dying worker still get a clean record
        assert got[e][0]["error"] is None


def test_local_pool_replaces_its_workers_after_episodes_per_worker(tmp_path: Path) -> None:
    from simn_sim.experiments.batch_local import run_local

    ids = ["a", "b", "c", "d", "e"]

    def pids_in_order(per_worker: int) -> list[int]:
        order: list[tuple[str, int]] = []
        run_local(
            [_task(e) for e in ids],
            1,
            lambda t, r: order.append((r.record["episode_id"], r.pid)),
            fn=_pid_task,
            per_worker=per_worker,
        )
        assert [e for e, _ in order] == ids  # one worker: the episodes run in order, all once
        return [p for _, p in order]

    for per_worker, groups in ((2, [2, 2, 1]), (0, [5])):
        pids = pids_in_order(per_worker)
        runs = [len(list(g)) for _, g in itertools.groupby(pids)]  # consecutive same process
        assert runs == groups and len(set(pids)) == len(groups)
    with pytest.raises(BatchError, match="episodes-per-worker"):
        BatchConfig(out=tmp_path, agent="oracle", n_episodes=1, episodes_per_worker=-1)


def _sleep_task(task: Any) -> Any:
    """Stands in for ``run_task``: writes this worker's pid to the task's ``rerun_path`` and
    sleeps (an episode still running when the batch process is killed)."""
    import os
    import time

    Path(task.rerun_path).write_text(str(os.getpid()))
    time.sleep(120)


def _alive(pid: int) -> bool:
    import os

    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")  # a zombie is dead too
    return not (stat.exists() and stat.read_text().split(") ")[-1].startswith("Z"))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_workers_end_when_the_batch_process_is_killed(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import time

    pidfile = tmp_path / "worker.pid"
    driver = f"""
import sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_batch import _sleep_task, _task
from simn_sim.experiments.batch_local import run_local
run_local([_task("a", {str(pidfile)!r})], 1, lambda t, r: None, fn=_sleep_task)
"""
    proc = subprocess.Popen([sys.executable, "-c", driver])
    try:
        t0 = time.monotonic()
        while not pidfile.exists() or not pidfile.read_text():
            assert time.monotonic() - t0 < 60, "the worker never started"
            assert proc.poll() is None, "the driver ended early"
            time.sleep(0.2)
        worker = int(pidfile.read_text())
        assert _alive(worker)
        proc.send_signal(signal.SIGKILL)  # no clean-up runs in the batch process
        proc.wait(10)
        t0 = time.monotonic()
        while _alive(worker) and time.monotonic() - t0 < 10:
            time.sleep(0.1)
        assert not _alive(worker), "the worker outlived the batch process"
    finally:
        if proc.poll() is None:
            proc.kill()
        if pidfile.exists() and pidfile.read_text() and _alive(int(pidfile.read_text())):
            os.kill(int(pidfile.read_text()), signal.SIGKILL)


def test_same_episode_id_with_another_spec_is_refused(tmp_path: Path) -> None:
    spec = EpisodeSet.load(regression_episode_file()).episodes[0]
    out = tmp_path / "run"
    out.mkdir()
    moved = EpisodeSpec(spec.episode_id, spec.layout_seed, spec.start, (1.0, 1.0), spec.seed)
    EpisodeSet("SimnOffice-v0", [moved]).save(out / "episode_set.json")
    (out / "episodes.jsonl").write_text(
        json.dumps({"episode_id": spec.episode_id, "agent": "oracle", "error": "x"}) + "\n"
    )
    f = tmp_path / "eps.json"
    EpisodeSet("SimnOffice-v0", [spec]).save(f)
    cfg = BatchConfig(out=out, agent="oracle", episode_file=f, workers=0, progress=False)
    with pytest.raises(BatchError, match="different spec"):
        run_batch(cfg)
    assert "error" in (out / "episodes.jsonl").read_text()  # nothing changed


def test_batch_config_is_frozen_and_checked(tmp_path: Path) -> None:
    import dataclasses

    cfg = BatchConfig(out=str(tmp_path), agent="oracle", n_episodes=2, env_config={"width": 64})
    assert cfg.out == tmp_path and isinstance(cfg.out, Path)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.workers = 3  # type: ignore[misc]
    cfg2 = cfg.replace(workers=0)
    assert cfg2.workers == 0 and cfg.workers == 1 and cfg2.env_config == {"width": 64}
    with pytest.raises(BatchError, match="exactly one"):
        BatchConfig(out=tmp_path, agent="oracle")
    with pytest.raises(BatchError, match="workers"):
        BatchConfig(out=tmp_path, agent="oracle", n_episodes=1, workers=-1)
    with pytest.raises(BatchError, match="'seed'"):  # a type error names the field
        BatchConfig(out=tmp_path, agent="oracle", n_episodes=1, seed="3")  # type: ignore[arg-type]
    with pytest.raises(BatchError, match="backend"):
        BatchConfig(out=tmp_path, agent="oracle", n_episodes=1, backend="slurm")


def test_cpu_model_names_family_model_stepping_and_vector_extensions():
    """Two CPUs sold under one model name ("AMD EPYC") round differently, so the record tells
    them apart by family / model / stepping, read from the cpuinfo text given."""
    from simn_sim.experiments.batch_files import cpu_model

    text = (
        "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
        "model name\t: AMD EPYC\nstepping\t: 1\nflags\t\t: fpu sse avx avx2 fma avx512f\n"
        "processor\t: 1\ncpu family\t: 26\nmodel\t\t: 2\nmodel name\t: AMD EPYC\n"
    )
    assert cpu_model(text) == "AMD EPYC (family 26, model 2, stepping 1) [avx avx2 fma avx512f]"
    zen4 = text.replace("cpu family\t: 26\nmodel\t\t: 2", "cpu family\t: 25\nmodel\t\t: 17", 1)
    assert cpu_model(zen4) != cpu_model(text) and "family 25, model 17" in cpu_model(zen4)
    # no identity fields, no flags: the name alone, said to have no AVX
    assert cpu_model("model name\t: Some CPU\n") == "Some CPU [no avx]"


def test_machine_summary_names_this_cpu_its_logical_cpus_and_architecture():
    import os
    import platform

    from simn_sim.experiments.batch_files import cpu_model, machine_summary

    line = machine_summary()
    assert line.startswith(cpu_model() or "unknown CPU")
    assert f", {os.cpu_count()} logical CPUs, {platform.machine()}" in line
