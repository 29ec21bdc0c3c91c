"""``simn-sim slam`` and ``simn-sim record`` entry points (wired into ``simn_sim.cli``).

``slam_main``: run :class:`~simn_sim.slam.pipeline.SimnSlam` on a TUM RGB-D folder (simulated or
real) and write ``OUT/trajectory.txt`` (TUM format, poses re-expressed through the final
anchors), ``OUT/trajectory_online.txt`` (the estimates as produced frame by frame),
``OUT/metrics.json`` and ``OUT/config.json``; with ``--rerun`` also ``OUT/slam.rrd``; with
``--save-maps`` also ``OUT/maps.pt``, the local frames' learned maps (a decoder shared by the
frames written once; read with ``ImplicitMap.load_frames``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from simn_sim.config import ConfigError
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.presets import load_slam_config
from simn_sim.slam.record import read_base, read_odometry, record_main

__all__ = ["record_main", "run_slam", "slam_main"]


def _median(x: list[float]) -> float:
    return float(np.median(x)) if x else float("nan")


def run_slam(
    folder: str | Path,
    out: str | Path,
    camera: str | None = None,
    cfg: SlamConfig | None = None,
    max_frames: int | None = None,
    rerun: bool = False,
    progress: bool = True,
    use_odometry: bool = True,
    save_maps: bool = False,
) -> dict[str, Any]:
    """Run the pipeline on a TUM folder and write the outputs; returns the metrics dict.

    With ``use_odometry`` and an ``odometry.txt`` in the folder (written by ``simn-sim record``:
    wheel odometry, as the navigation agent has it), its increments are the motion prior;
    otherwise constant velocity.

    Raises :class:`~simn_sim.io.tum.TumFormatError` for a missing or malformed folder.
    """
    from simn_sim.eval.trajectory import ate_rpe, write_tum_trajectory
    from simn_sim.io.tum import read_tum
    from simn_sim.slam.pipeline import SimnSlam

    cfg = cfg or SlamConfig()
    seq = read_tum(folder, camera)
    n = len(seq) if max_frames is None else min(len(seq), int(max_frames))
    T_base_cam = read_base(folder)
    odom = read_odometry(folder) if use_odometry else None
    slam = SimnSlam(cfg, seq.intrinsics, T_base_cam)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rec = None
    if rerun:
        import rerun as rr

        rec = rr.RecordingStream("simn_sim_slam", recording_id=out.name)
        rec.save(str(out / "slam.rrd"))
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    gt: list[tuple[float, np.ndarray]] = []
    track_ms, map_ms, iters = [], [], []
    failures = 0
    it = range(n)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=f"slam {Path(folder).name}", unit="frame", file=sys.stderr)
    t_wall = time.perf_counter()
    for k in it:
        fr = seq[k]
        prior = None if odom is None else odom.get(round(fr.timestamp, 6))
        res = slam.process(fr.timestamp, fr.rgb, fr.depth, prior)
        track_ms.append(res.track_ms)
        map_ms.append(res.map_ms)
        iters.append(res.iterations)
        failures += int(not res.success)
        if fr.T_world_cam is not None:
            gt.append((fr.timestamp, fr.T_world_cam))
        if rec is not None:
            _log_rerun(rec, k, fr, res, slam, seq.intrinsics)
    wall = time.perf_counter() - t_wall
    traj = slam.trajectory(corrected=True)
    online = slam.trajectory(corrected=False)
    write_tum_trajectory(out / "trajectory.txt", [t for t, _ in traj], [T for _, T in traj])
    write_tum_trajectory(
        out / "trajectory_online.txt", [t for t, _ in online], [T for _, T in online]
    )
    metrics: dict[str, Any] = {
        "sequence": str(folder),
        **slam.stats(),
        "track_ms_median": _median(track_ms),
        "track_ms_p90": float(np.percentile(track_ms, 90)) if track_ms else float("nan"),
        "map_ms_median": _median(map_ms),
        "map_ms_mean": float(np.mean(map_ms)) if map_ms else float("nan"),
        "ms_per_frame": 1e3 * wall / max(n, 1),
        "iterations_median": _median(iters),
        "tracking_failures": failures,
        "torch_threads": cfg.torch_threads,
        "prior": "wheel odometry" if odom is not None else "constant velocity",
    }
    if len(gt) >= 2:
        m = ate_rpe(traj, gt)
        metrics["ate_rmse_m"] = m["ate_rmse_m"]
        metrics["rpe"] = {k: m[k] for k in ("rpe_trans_rmse_m", "rpe_rot_rmse_deg")}
        metrics["ate_online_rmse_m"] = ate_rpe(online, gt)["ate_rmse_m"]
    metrics["revisit_log"] = slam.loop_log
    (out / "metrics.json").write_text(json.dumps(_jsonable(metrics), indent=2))
    (out / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
    if save_maps and slam.frames.implicit_maps():
        slam.frames.save_maps(out / "maps.pt")
    if rec is not None:
        rec.flush()
        rec.disconnect()
    return metrics


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _log_rerun(rec, k: int, fr, res, slam, intr) -> None:
    import rerun as rr

    from simn_sim.viz import LABEL_COLOURS

    rec.set_time("frame", sequence=int(k))
    T = res.T_world_cam
    rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
    rec.log(
        "world/camera/image",
        rr.Pinhole(
            focal_length=[intr.fx, intr.fy],
            principal_point=[intr.cx, intr.cy],
            resolution=[intr.width, intr.height],
            camera_xyz=rr.ViewCoordinates.RDF,
        ),
    )
    rec.log("world/camera/image/rgb", rr.Image(fr.rgb))
    rec.log("world/camera/image/depth", rr.DepthImage(fr.depth, meter=1.0))
    lab = np.clip(res.labels, 0, len(LABEL_COLOURS) - 1)
    rec.log("world/points", rr.Points3D(res.points_world, colors=LABEL_COLOURS[lab], radii=[0.01]))
    est = np.array([Tw[:3, 3] for _, Tw in slam.trajectory(corrected=False)])
    rec.log("world/trajectory/estimated", rr.LineStrips3D([est], colors=[[255, 120, 40]]))
    dbg = slam.debug()
    rec.log("world/topo/nodes", rr.Points3D(dbg["topo_nodes"], colors=[[255, 0, 255]], radii=0.05))
    if dbg["topo_arcs"]:
        cols = [[0, 200, 255] if kd == "loop" else [200, 0, 200] for kd in dbg["topo_arc_kinds"]]
        rec.log("world/topo/arcs", rr.LineStrips3D(dbg["topo_arcs"], colors=cols))
    rec.log("metrics/track_ms", rr.Scalars(float(res.track_ms)))
    rec.log("metrics/map_ms", rr.Scalars(float(res.map_ms)))


def slam_main(argv: list[str] | None = None) -> int:
    """``simn-sim slam --tum DIR --out OUT [--camera fr1|fr2|fr3|PATH] [--rerun]
    [--max-frames N] [--config YAML] [--save-maps]``. Returns the exit status (0 ok, 2 bad input)."""
    from simn_sim.io.tum import TumFormatError

    ap = argparse.ArgumentParser(
        prog="simn-sim slam", description="Run the SIMN front-end on a TUM RGB-D folder."
    )
    ap.add_argument("--tum", required=True, type=Path, help="TUM RGB-D folder")
    ap.add_argument("--out", required=True, type=Path, help="output folder")
    ap.add_argument(
        "--camera", default=None, help="fr1|fr2|fr3 or a camera YAML (if no camera.yaml)"
    )
    ap.add_argument("--rerun", action="store_true", help="also write OUT/slam.rrd")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument(
        "--config",
        type=Path,
        default=None,
        help="SlamConfig YAML; without a top-level 'preset' it changes the learned_tracking "
        "preset (tracking on the learned map); 'preset: point_tracking' tracks on the point store",
    )
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument(
        "--save-maps",
        action="store_true",
        help="also write OUT/maps.pt (the learned local-frame maps, a shared decoder once)",
    )
    ap.add_argument(
        "--no-odometry", action="store_true", help="ignore odometry.txt (constant-velocity prior)"
    )
    a = ap.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    if a.max_frames is not None and a.max_frames < 1:
        print("simn-sim slam: error: --max-frames must be >= 1", file=sys.stderr)
        return 2
    try:
        cfg = load_slam_config(a.config, default_preset="learned_tracking")
        m = run_slam(
            a.tum, a.out, a.camera, cfg, a.max_frames, a.rerun, not a.no_progress,
            not a.no_odometry, a.save_maps,
        )  # fmt: skip
    except (TumFormatError, ConfigError) as e:
        print(f"simn-sim slam: error: {e}", file=sys.stderr)
        return 2
    ate = m.get("ate_rmse_m")
    msg = (
        f"{m['frames']} frames, {m['local_frames']} local frames, "
        f"{m['revisits_accepted']} revisits, track {m['track_ms_median']:.1f} ms, "
        f"map {m['map_ms_median']:.1f} ms (median)"
    )
    if ate is not None:
        msg += f", ATE {100 * ate:.2f} cm"
    print(msg)
    extra = ", maps.pt" if (a.out / "maps.pt").is_file() and a.save_maps else ""
    print(f"wrote {a.out}/trajectory.txt, metrics.json, config.json{extra}")
    return 0


if __name__ == "__main__":
    raise SystemExit(slam_main())
