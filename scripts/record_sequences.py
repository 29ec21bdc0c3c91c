"""Record the simulated SLAM sequences, run ``simn-sim slam`` on each, write the table.

Sequences: desk, corridor, loop (``simn_sim.slam.record``), each noise-free and with the D435i
depth-noise model (ideal actuation and the recorder's odometry drift: ``record_sequence``'s
sensing), at 320x240, in the reference office or seeded layouts (``--layouts ref 1 2``), plus
the real 9-frame TUM fr1/desk clip when present.

``--map points`` (default) runs the surface-store config (``map_kind=points``) with both priors
(wheel odometry, constant velocity; the desk has no wheels) and replaces the block between the
``results`` markers in ``docs/slam.md``. ``--map learned`` runs ``simn-sim slam``'s default, the
``learned_tracking`` preset (tracking on the learned map), with one prior per trajectory
(desk: constant velocity, the others: odometry) and replaces the ``results-learned`` block. The
table is printed too.

    MUJOCO_GL=egl .venv/bin/python scripts/record_sequences.py --root /tmp/simn_slam
    MUJOCO_GL=egl .venv/bin/python scripts/record_sequences.py --root /tmp/simn_slam \\
        --map learned --layouts ref 1 2 --trajectories desk corridor
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from simn_sim.slam.cli import run_slam  # noqa: E402
from simn_sim.slam.config import SlamConfig  # noqa: E402
from simn_sim.slam.presets import load_slam_config  # noqa: E402
from simn_sim.slam.record import record_sequence  # noqa: E402
from simn_sim.slam.semantics_eval import evaluate_classifier  # noqa: E402

TUM9 = Path(__file__).resolve().parents[1] / "tests" / "data" / "tum_fr1_desk_9"
MARKERS = {
    "points": ("<!-- results:begin -->", "<!-- results:end -->"),
    "learned": ("<!-- results-learned:begin -->", "<!-- results-learned:end -->"),
}


def _cm(x) -> str:
    return "-" if x is None else f"{100 * x:.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", type=Path, default=Path("/tmp/simn_slam_seqs"))
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--trajectories", nargs="+", default=["desk", "corridor", "loop"])
    ap.add_argument("--implicit", action="store_true", help="also run the learned map (desk)")
    ap.add_argument("--map", choices=["points", "learned"], default="points")
    ap.add_argument(
        "--layouts", nargs="+", default=["ref"], help="'ref' (the reference office) or seeds"
    )
    ap.add_argument("--doc", type=Path, default=Path(__file__).parents[1] / "docs" / "slam.md")
    ap.add_argument("--no-doc", action="store_true")
    a = ap.parse_args()
    rows = []
    learned = a.map == "learned"
    BEGIN, END = MARKERS[a.map]
    cfg = load_slam_config(None, "learned_tracking") if learned else SlamConfig(map_kind="points")
    name0 = "learned" if learned else "points"
    for lay in a.layouts:
        seed = None if lay == "ref" else int(lay)
        tag = "" if seed is None else f"L{seed}_"
        where = "ref" if seed is None else f"layout {seed}"
        for traj in a.trajectories:
            for noise in ("none", "d435i"):
                folder = a.root / f"{tag}{traj}_{noise}"
                if not (folder / "rgb.txt").is_file():
                    t = time.perf_counter()
                    rec = record_sequence(
                        folder, traj, noise, a.width, a.height, layout_seed=seed,
                        segmentation=(traj == "desk" and seed is None),
                    )  # fmt: skip
                    print(f"recorded {folder}: {rec['frames']} frames in "
                          f"{time.perf_counter() - t:.0f} s")  # fmt: skip
                runs = [(name0, cfg)]
                if a.implicit and traj == "desk" and not learned:
                    runs.append(("implicit", SlamConfig()))
                priors = ["odometry", "const. velocity"]
                if traj == "desk":
                    priors = ["const. velocity"]  # hand-held-like: no wheels
                elif learned:
                    priors = ["odometry"]
                for name, c in runs:
                    for prior in priors:
                        short = prior.split()[0].strip(".")
                        out = a.root / "out" / f"{tag}{traj}_{noise}_{name}_{short}"
                        m = run_slam(
                            folder, out, cfg=c, progress=False, use_odometry=(prior == "odometry")
                        )
                        seq = f"{traj} ({noise})" if seed is None else f"{traj} ({noise}), {where}"
                        rows.append((seq, name, prior, m))
                        print(json.dumps({k: v for k, v in m.items() if k != "revisit_log"}))
    if TUM9.is_dir():
        m = run_slam(TUM9, a.root / "out" / f"tum_fr1_desk_9_{name0}", "fr1", cfg, progress=False)
        rows.append(("TUM fr1/desk 9 frames (real)", name0, "const. velocity", m))
    sem = None
    seg = a.root / "desk_none"
    if (seg / "seg.txt").is_file() and not learned:
        sem = evaluate_classifier(seg, cfg)
        print(json.dumps(sem))
    lines = [
        BEGIN,
        "",
        f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on "
        f"{platform.machine()} ({os.cpu_count()} cores, shared; timings +-30-50 %), "
        f"{a.width}x{a.height}, `scripts/record_sequences.py`.",
        "",
        "| sequence | map | prior | frames | local frames | revisits | ATE online (cm) | "
        "ATE final (cm) | RPE (mm / deg) | track ms (median) | map ms (median / mean) | "
        "ms / frame |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for seq, name, prior, m in rows:
        rpe = m.get("rpe") or {}
        rpe_s = (
            f"{1000 * rpe['rpe_trans_rmse_m']:.1f} / {rpe['rpe_rot_rmse_deg']:.2f}" if rpe else "-"
        )
        lines.append(
            f"| {seq} | {name} | {prior} | {m['frames']} | {m['local_frames']} | "
            f"{m['revisits_accepted']} | {_cm(m.get('ate_online_rmse_m'))} | "
            f"{_cm(m.get('ate_rmse_m'))} | {rpe_s} | {m['track_ms_median']:.0f} | "
            f"{m['map_ms_median']:.0f} / {m['map_ms_mean']:.0f} | {m['ms_per_frame']:.0f} |"
        )
    if sem is not None:
        lines += [
            "",
            f"Geometric labels against the simulator's segmentation (desk, noise-free, "
            f"{sem['frames']} frames, {sem['n_points']} points): floor precision / recall "
            f"{sem['floor_precision']:.3f} / {sem['floor_recall']:.3f}; obstacle (points up to "
            f"the robot height) {sem['obstacle_precision']:.3f} / {sem['obstacle_recall']:.3f}.",
        ]
    lines += ["", END]
    block = "\n".join(lines)
    print(block)
    if not a.no_doc:
        doc = a.doc.read_text() if a.doc.is_file() else f"# SLAM\n\n{BEGIN}\n{END}\n"
        if BEGIN in doc and END in doc:
            pre, rest = doc.split(BEGIN, 1)
            _, post = rest.split(END, 1)
            doc = pre + block + post
        else:
            doc = doc.rstrip() + "\n\n" + block + "\n"
        a.doc.write_text(doc)
        print(f"updated {a.doc}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
