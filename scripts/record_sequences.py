"""Record the simulated SLAM sequences, run ``simn-sim slam`` on each, write the table.

Sequences: desk, corridor, loop (``simn_sim.slam.record``), each noise-free and with the D435i
depth-noise model (ideal actuation and the recorder's odometry drift: ``record_sequence``'s
sensing), at 320x240, plus the real 9-frame TUM fr1/desk clip when present. Each is
run with the given SLAM config (default: ``map_kind=points``: tracking is the same with the
learned map, see docs/slam.md; ``--implicit`` also runs the learned map on the desk sequences
to report its cost). The results table replaces the block between the ``results`` markers in
``docs/slam.md`` (and is printed).

    MUJOCO_GL=egl .venv/bin/python scripts/record_sequences.py --root /tmp/simn_slam
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
from simn_sim.slam.record import record_sequence  # noqa: E402
from simn_sim.slam.semantics_eval import evaluate_classifier  # noqa: E402

TUM9 = Path(__file__).resolve().parents[1] / "tests" / "data" / "tum_fr1_desk_9"
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def _cm(x) -> str:
    return "-" if x is None else f"{100 * x:.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", type=Path, default=Path("/tmp/simn_slam_seqs"))
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--trajectories", nargs="+", default=["desk", "corridor", "loop"])
    ap.add_argument("--implicit", action="store_true", help="also run the learned map (desk)")
    ap.add_argument("--doc", type=Path, default=Path(__file__).parents[1] / "docs" / "slam.md")
    ap.add_argument("--no-doc", action="store_true")
    a = ap.parse_args()
    rows = []
    cfg = SlamConfig(map_kind="points")
    for traj in a.trajectories:
        for noise in ("none", "d435i"):
            folder = a.root / f"{traj}_{noise}"
            if not (folder / "rgb.txt").is_file():
                t = time.perf_counter()
                rec = record_sequence(
                    folder, traj, noise, a.width, a.height, segmentation=(traj == "desk")
                )
                print(
                    f"recorded {folder}: {rec['frames']} frames in {time.perf_counter() - t:.0f} s"
                )
            runs = [("points", cfg)]
            if a.implicit and traj == "desk":
                runs.append(("implicit", SlamConfig()))
            for name, c in runs:
                for prior in ("odometry", "const. velocity"):
                    if traj == "desk" and prior == "odometry":
                        continue  # hand-held-like: no wheels
                    out = a.root / "out" / f"{traj}_{noise}_{name}_{prior.split()[0].strip('.')}"
                    m = run_slam(
                        folder, out, cfg=c, progress=False, use_odometry=(prior == "odometry")
                    )
                    rows.append((f"{traj} ({noise})", name, prior, m))
                    print(json.dumps({k: v for k, v in m.items() if k != "revisit_log"}))
    if TUM9.is_dir():
        m = run_slam(TUM9, a.root / "out" / "tum_fr1_desk_9", "fr1", cfg, progress=False)
        rows.append(("TUM fr1/desk 9 frames (real)", "points", "const. velocity", m))
    sem = None
    seg = a.root / "desk_none"
    if (seg / "seg.txt").is_file():
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
