"""Rerun recordings read back: entity paths (= the README's table), one row per step, poses equal
the truth, everything in the world frame inside the building, the topological map's arcs end on
its nodes, local frames logged only when they change, a default blueprint; the demo's --out."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from simn_sim.env.episodes import EpisodeSet
from simn_sim.experiments.batch import make_env, regression_episode_file, resolve_env_config
from simn_sim.experiments.rrd import (
    entity_translations,
    main,
    read_recording,
    read_rows,
    world_positions,
)
from simn_sim.experiments.runner import run_episode
from simn_sim.viz import RerunRecorder

README = Path(__file__).resolve().parents[1] / "README.md"

EXPECTED = (
    "world/robot",
    "world/camera",
    "world/camera/image",
    "world/camera/image/rgb",
    "world/camera/image/depth",
    "world/trajectory/true",
    "world/planner/path",
    "world/floorplan",
    "world/goal",
)
PER_STEP = ("world/robot", "world/camera", "world/trajectory/true")
IMAGES = ("world/camera/image/rgb", "world/camera/image/depth")


def readme_entity_patterns() -> dict[str, re.Pattern]:
    """The entity paths of the README's "Rerun recordings" table (first column, back-quoted),
    as regular expressions (``<k>`` stands for an integer)."""
    text = README.read_text()
    section = text[text.index("## Rerun recordings") :]
    section = section[: section.index("\n## ", 1)]
    pats: dict[str, re.Pattern] = {}
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        first = line.split("|")[1]
        for name in re.findall(r"`([^`]+)`", first):
            rx = re.escape(name).replace(re.escape("<k>"), r"\d+")
            pats[name] = re.compile(rx + r"\Z")
    assert len(pats) >= 15, f"README entity table not found or too short: {sorted(pats)}"
    return pats


def unmatched(entities: list[str], pats: dict[str, re.Pattern]) -> list[str]:
    return [e for e in entities if not any(p.match(e) for p in pats.values())]


def assert_inside(
    path: Path, bounds: tuple[float, float, float, float], margin: float, skip: tuple = ()
) -> None:
    """Every world/ position of the recording (entities in ``skip`` aside) lies inside the
    bounds (x0, y0, x1, y1) widened by ``margin``."""
    x0, y0, x1, y1 = bounds
    out = []
    for e, rows in world_positions(path).items():
        assert e.startswith("world/"), e
        if e in skip:
            continue
        P = np.concatenate([p for _, p in rows])
        ok = (
            (P[:, 0] >= x0 - margin)
            & (P[:, 0] <= x1 + margin)
            & (P[:, 1] >= y0 - margin)
            & (P[:, 1] <= y1 + margin)
        )
        if not ok.all():
            out.append(f"{e}: {int((~ok).sum())} of {len(P)} outside, e.g. {P[~ok][0].round(2)}")
    assert not out, "positions outside the building:\n" + "\n".join(out)


def assert_arcs_on_nodes(path: Path) -> int:
    """Every topo arc's ends coincide with a topo node (latest-at the arc's step); returns the
    number of arc rows checked."""
    rows = read_rows(path, ["world/topo/nodes", "world/topo/arcs"], (":positions", ":strips"))
    nodes = rows.get("world/topo/nodes", [])
    n = 0
    for st, vals in rows.get("world/topo/arcs", []):
        cur = [v for s, v in nodes if s is None or (st is not None and s <= st)]
        assert cur, f"arcs at step {st} before any node"
        N = np.asarray(cur[-1]["Points3D:positions"], float)
        for strip in vals["LineStrips3D:strips"]:
            for end in np.asarray(strip, float)[[0, -1]]:
                d = np.min(np.linalg.norm(N - end, axis=1))
                assert d < 1e-4, f"step {st}: arc end {end.round(3)} is {d:.3f} m from every node"
        n += 1
    return n


def blueprint_views(path: Path) -> list[tuple[str, str, str, list[str]]]:
    """The default blueprint's views: (class, name, origin, contents queries)."""
    from rerun.chunk import RrdReader

    r = RrdReader(path)
    stores = r.blueprints()
    assert stores, f"{path}: no default blueprint"
    views: dict[str, dict] = {}
    for ch in r.stream(store=stores[0]):
        ent = ch.entity_path.strip("/")
        if not ent.startswith("view/"):
            continue
        rb = ch.to_record_batch()
        vid = "/".join(ent.split("/")[:2])
        for n in rb.schema.names:
            if n.split(":")[-1] in ("class_identifier", "display_name", "space_origin", "query"):
                views.setdefault(vid, {})[n.split(":")[-1]] = rb.column(n).to_pylist()[-1]
    return sorted(
        (
            v["class_identifier"][0],
            v["display_name"][0],
            v["space_origin"][0],
            v.get("query", []),
        )
        for v in views.values()
    )


def test_default_blueprint(tmp_path: Path) -> None:
    """A large 3-D view, rgb and depth in separate 2-D views, the timings in one plot (ms)."""
    rrd = tmp_path / "bp.rrd"
    _record_hand_made(rrd, _debug)
    views = blueprint_views(rrd)
    by_kind: dict[str, list] = {}
    for kind, name, origin, query in views:
        by_kind.setdefault(kind, []).append((name, origin, query))
    assert sorted(by_kind) == ["2D", "3D", "TimeSeries"], views
    assert sorted(q for _, _, q in by_kind["2D"]) == [["$origin/depth"], ["$origin/rgb"]]
    ((name, origin, _),) = by_kind["TimeSeries"]
    assert origin == "metrics" and "(ms)" in name
    ((_, origin, query),) = by_kind["3D"]
    assert origin == "world" and "- $origin/camera/image/depth" in query


# ----------------------------------------------------------------------------- oracle episode
def test_oracle_recording_has_entities_and_steps(tmp_path: Path) -> None:
    spec = next(
        e
        for e in EpisodeSet.load(regression_episode_file()).episodes
        if e.episode_id == "reg-ref-000"
    )
    env_cfg = resolve_env_config("SimnOffice-v0", {"width": 160, "height": 120})
    env = make_env("SimnOffice-v0", env_cfg)
    rrd = tmp_path / "rec" / "reg-ref-000.rrd"
    try:
        rec = run_episode(
            "SimnOffice-v0", env_cfg, "oracle", {}, episode=spec.to_dict(), rerun_path=rrd, env=env
        )
        bounds = env.unwrapped.layout.bounds
    finally:
        env.close()
    assert rec["error"] is None and rec["success"] is True
    n = rec["steps"]
    assert 20 < n < 200

    s = read_recording(rrd)
    assert s.recording_id == "reg-ref-000"
    missing = [e for e in EXPECTED if e not in s.entity_paths]
    assert not missing, f"missing entities {missing}; have {s.entity_paths}"
    assert {"world/floorplan", "world/goal", "world/camera/image"} <= set(s.static_entities)
    assert s.steps == list(range(n + 1))  # the reset frame plus one per env step
    for e in PER_STEP:
        assert s.steps_per_entity[e] == list(range(n + 1)), e
    for e in IMAGES:  # run_episode's default image_every = 2
        assert s.steps_per_entity[e] == list(range(0, n + 1, 2)), e
    assert "world/trajectory/estimated" not in s.entity_paths  # the oracle has no estimate
    assert not unmatched(s.entity_paths, readme_entity_patterns())

    steps, t = entity_translations(rrd, "world/robot")
    assert list(steps) == list(range(n + 1))
    np.testing.assert_allclose(t[0, :2], spec.start[:2], atol=1e-4)
    assert np.linalg.norm(t[-1, :2] - np.asarray(spec.goal)) <= 0.36 + 1e-3
    path = float(np.sum(np.linalg.norm(np.diff(t[:, :2], axis=0), axis=1)))
    assert path == pytest.approx(rec["path_length_m"], rel=0.01)
    assert "world/robot" in s.format()
    assert main([str(rrd)]) == 0

    # the robot body (static, base frame) is drawn around the true base position
    body = world_positions(rrd)["world/robot"]
    centre = {st: p[0] for st, p in body if len(p) == 2}  # cylinder centre + arrow origin
    assert set(centre) == set(range(n + 1))
    np.testing.assert_allclose(centre[n][:2], t[-1, :2], atol=1e-5)
    # walls are 0.15 m thick, centred on the building's outline
    assert_inside(rrd, bounds, margin=0.1)
    views = blueprint_views(rrd)
    assert sorted(v[0] for v in views) == ["2D", "2D", "3D", "TimeSeries"], views


def test_simn_recording_in_world_frame(tmp_path: Path) -> None:
    """A SLAM agent's recording: the topological map's arcs end on its nodes and everything it
    reports in its start frame lands inside the building (the planner tree excepted: RRT*
    samples unknown space, which reaches beyond the outer walls). Ideal sensing: the check is
    on frames, and D435i noise at range puts map points beyond the 0.1 m margin."""
    spec = next(
        e
        for e in EpisodeSet.load(regression_episode_file()).episodes
        if e.episode_id == "reg-ref-000"
    )
    env_cfg = resolve_env_config("SimnOffice-v0", {"width": 160, "height": 120, "sensing": "ideal"})
    env = make_env("SimnOffice-v0", env_cfg)
    rrd = tmp_path / "simn.rrd"
    try:
        rec = run_episode(
            "SimnOffice-v0", env_cfg, "simn", {}, episode=spec.to_dict(), rerun_path=rrd, env=env
        )
        bounds = env.unwrapped.layout.bounds
    finally:
        env.close()
    assert rec["error"] is None, rec["error"]
    s = read_recording(rrd)
    assert {"world/topo/nodes", "world/topo/arcs", "world/trajectory/estimated"} <= set(
        s.entity_paths
    )
    assert not unmatched(s.entity_paths, readme_entity_patterns())
    assert assert_arcs_on_nodes(rrd) > 0
    assert_inside(rrd, bounds, margin=0.1, skip=("world/planner/tree",))


# ----------------------------------------------------------------- hand-made agent debug data
def _yaw(theta: float, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, z)
    return T


def _frame_points(k: int) -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(0.0, 1.0, 4, dtype=np.float32)
    P = np.stack(np.meshgrid(g, g, [0.0, 0.5], indexing="ij"), -1).reshape(-1, 3) + k * 0.1
    lab = np.where(P[:, 2] > 0.1, 2, 1).astype(np.int8)
    return P.astype(np.float32), lab


N_STEPS = 11
T_WA = _yaw(np.pi / 2, 15.0, 8.0)  # the agent's start frame in the world
BOX = (0.0, 0.0, 24.0, 15.0)  # the hand-made floor plan's outline


def _debug(step: int) -> dict:
    """Agent debug data in the start frame: the robot drives along start-frame +x; frame 0
    (anchor at the start) until step 2, its anchor corrected at step 5 and gone from step 8;
    frame 1 (anchor at x = 2) from step 3, growing every step to the end."""
    nodes = [[0.0, 0.0, 1.0], [2.0, -3.0, 1.0]]
    arcs = [np.array([nodes[0], nodes[1]])]
    frames: dict[int, dict] = {}
    if step < 8:
        P, lab = _frame_points(0)
        frames[0] = {
            "T_anchor": _yaw(0.05, 0.1, -0.1) if step >= 5 else np.eye(4),
            "points": P,
            "labels": lab,
            "version": min(step, 2),
        }
    if step >= 3:
        P, lab = _frame_points(1)
        frames[1] = {"T_anchor": _yaw(0.0, 2.0), "points": P, "labels": lab, "version": step}
        nodes = nodes + [[2.0, 0.0, 1.0]]
        arcs = arcs + [np.array([nodes[1], nodes[2]])]
    return {
        "frame": "start",
        "T_world_base_est": _yaw(0.0, 0.3 * step),
        "path": np.array([[0.3 * step, 0.0], [3.0, -1.0], [4.0, -2.0]]),
        "tree_edges": np.array([[[0.0, 0.0], [1.0, -1.0]], [[1.0, -1.0], [2.0, -2.5]]])
        * (1.0 + (step >= 6)),
        "topo_nodes": np.array(nodes),
        "topo_arcs": arcs,
        "local_frames": frames,
        "plan_ms": 5.0 + step,
        "map_ms": 3.0,
        "track_ms": 2.0,
    }


def _record_hand_made(path: Path, debug) -> None:
    intr = SimpleNamespace(fx=50.0, fy=50.0, cx=32.0, cy=24.0, width=64, height=48)
    rec = RerunRecorder(path, intr, points_every=3)
    x0, y0, x1, y1 = BOX
    outline = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    rec.log_layout([outline], np.array([20.0, 12.0]), robot_radius=0.25, robot_z=(0.03, 0.95))
    rec.set_agent_frame(T_WA)
    rng = np.random.default_rng(0)
    for step in range(N_STEPS):
        T_wb = T_WA @ _yaw(0.0, 0.3 * step)
        info = {"T_world_base": T_wb, "T_world_cam": T_wb @ _yaw(0.0, 0.1, 0.0, 1.0)}
        obs = {
            "rgb": rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
            "depth": np.full((48, 64), 2.5, np.float32),
        }
        rec.log_step(step, obs, info, debug(step))
    rec.close()


def test_recorder_draws_agent_debug_in_world(tmp_path: Path) -> None:
    rrd = tmp_path / "hand.rrd"
    _record_hand_made(rrd, _debug)
    s = read_recording(rrd)

    # the entity list is exactly the README's table (with k = 0, 1)
    pats = readme_entity_patterns()
    assert not unmatched(s.entity_paths, pats), unmatched(s.entity_paths, pats)
    unused = [n for n, p in pats.items() if not any(p.match(e) for e in s.entity_paths)]
    assert not unused, f"README lists entities the recording lacks: {unused}"

    # world frame: arcs end on nodes, nothing outside the building (in the start frame the
    # node (2, -3) would lie at y = -3)
    assert assert_arcs_on_nodes(rrd) == 2  # logged at step 0 and when frame 1 came (step 3)
    assert_inside(rrd, BOX, margin=0.0)
    nodes = read_rows(rrd, ["world/topo/nodes"], (":positions",))["world/topo/nodes"]
    np.testing.assert_allclose(nodes[-1][1]["Points3D:positions"][1], [18.0, 10.0, 1.0], atol=1e-5)

    # local frames: transforms when the anchor moved, points when the version changed (the
    # growing frame at most every 3 steps, its last version written at close)
    assert s.steps_per_entity["world/local_frames/0"] == [0, 5, 8]  # 8: cleared (gone)
    assert s.steps_per_entity["world/local_frames/1"] == [3]
    assert s.steps_per_entity["world/local_frames/0/points"] == [0, 3]
    assert s.steps_per_entity["world/local_frames/1/points"] == [3, 6, 9, 10]
    wp = world_positions(rrd)
    P1, _ = _frame_points(1)
    want = (T_WA @ _yaw(0.0, 2.0) @ np.c_[P1, np.ones(len(P1))].T).T[:, :3]
    np.testing.assert_allclose(wp["world/local_frames/1/points"][-1][1], want, atol=1e-5)
    P0, _ = _frame_points(0)
    after = [p for st, p in wp["world/local_frames/0/points"] if st == 3]
    assert after  # mapped through the anchor as of step 3 (before the correction)
    np.testing.assert_allclose(after[0][0], (T_WA @ np.r_[P0[0], 1.0])[:3], atol=1e-5)
    T0 = [p for st, p in wp["world/local_frames/0"] if st == 5][0][0]
    np.testing.assert_allclose(T0, (T_WA @ _yaw(0.05, 0.1, -0.1))[:3, 3], atol=1e-6)

    # logged on change only: the tree twice, the path every step (it moves), timings every step
    assert s.steps_per_entity["world/planner/tree"] == [0, 6]
    assert s.steps_per_entity["world/planner/path"] == list(range(N_STEPS))
    for m in ("plan_ms", "map_ms", "track_ms"):
        assert s.steps_per_entity[f"metrics/{m}"] == list(range(N_STEPS))
    assert s.steps_per_entity["world/camera/image/rgb"] == list(range(0, N_STEPS, 2))
    strips = read_rows(rrd, ["world/trajectory/estimated"], (":strips",))
    last = np.asarray(strips["world/trajectory/estimated"][-1][1]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(last[-1], (T_WA @ _yaw(0.0, 3.0))[:3, 3], atol=1e-5)


def test_recorder_without_or_with_old_local_frames(tmp_path: Path) -> None:
    """No ``local_frames`` key, or its old shape ``{"current": (points, labels)}``: nothing is
    drawn for it, the rest is."""

    def old(step: int) -> dict:
        d = _debug(step)
        d["local_frames"] = {"current": (np.zeros((5, 3), np.float32), np.ones(5, np.int8))}
        return d

    def absent(step: int) -> dict:
        d = _debug(step)
        del d["local_frames"]
        return d

    for name, fn in (("old", old), ("absent", absent)):
        rrd = tmp_path / f"{name}.rrd"
        _record_hand_made(rrd, fn)
        s = read_recording(rrd)
        assert not [e for e in s.entity_paths if e.startswith("world/local_frames")], name
        assert "world/topo/arcs" in s.entity_paths
        assert_inside(rrd, BOX, margin=0.0)


# ------------------------------------------------------------------------------ the demo's CLI
@pytest.mark.parametrize("below", ["", "sub"])
def test_demo_out_is_an_existing_file(tmp_path: Path, capsys, below: str) -> None:
    """``--out`` naming an existing file (or a folder below one): a one-line error naming the
    path, exit code 2, the file untouched."""
    from simn_sim.cli import main as cli_main

    f = tmp_path / "taken"
    f.write_text("x")
    out = f / below if below else f
    rc = cli_main(["demo", "--out", str(out), "--agent", "oracle"])
    err = capsys.readouterr().err
    assert rc == 2
    assert str(out) in err and "Traceback" not in err
    assert "not a directory" in err.lower()
    assert f.read_text() == "x"


def test_unreadable_recording(tmp_path: Path) -> None:
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording")
    with pytest.raises(ValueError, match="not a readable rerun recording"):
        read_recording(bad)
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "none.rrd")
    assert main([str(bad)]) == 2
