"""Tracking maps built at the ground-truth poses: how far each SDF is from the surface it maps.

Tracking error mixes two things: how good the map is, and how the registration and the
prediction use it. This script separates the first. It runs :class:`~simn_sim.slam.SimnSlam` on
a TUM folder with its ``groundtruth.txt`` as the prior and every registration rejected
(``track_max_correction_m`` = 1e-9), so every local frame's maps (surface store, learned map) are built
at the true poses. Every ``--every``-th frame, before it is integrated, its registration points are
placed at their true pose in the current local frame and checked against the SDF that tracking
would use (``SimnSlam._sdf_of``, per the config's ``track_sdf``):

* ``|sdf| at truth``: median |SDF| of the points at the true pose (0 for a perfect map and
  exact depth; with noisy depth it includes the frame's own noise);
* ``LM error``: registration (the config's tracking settings) from the true pose perturbed by
  ``--perturb-cm`` / ``--perturb-deg`` per axis (seeded), error of the result to the truth.

One row per config (YAML as for ``simn-sim slam --config``; the file name is the row label).

    MUJOCO_GL=egl .venv/bin/python scripts/sdf_at_truth.py /tmp/seq/desk_d435i \
        --configs store.yaml learned.yaml
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from simn_sim.geometry.se3 import inv_T, pose_error, se3_exp
from simn_sim.io.tum import read_tum
from simn_sim.slam.pipeline import SimnSlam
from simn_sim.slam.presets import load_slam_config
from simn_sim.slam.record import read_base
from simn_sim.tracking.registration import register


def evaluate(
    folder: Path,
    config: Path | None,
    every: int,
    start: int,
    cm: float,
    deg: float,
    camera: str | None = None,
):
    cfg = load_slam_config(config, track_max_correction_m=1e-9, revisits=False)
    seq = read_tum(folder, camera)
    if seq[0].T_world_cam is None:
        raise SystemExit(f"{folder}: needs groundtruth.txt")
    slam = SimnSlam(cfg, seq.intrinsics, read_base(folder))
    rng = np.random.default_rng(0)
    rows = []
    for k in range(len(seq)):
        fr = seq[k]
        if k >= start and (k - start) % every == 0:
            fid = slam.current_frame_id
            sdf = slam.tracker.sdf_of(fid)
            if sdf is not None:
                T_true = inv_T(slam.topo.anchor(fid)) @ fr.T_world_cam
                frame = slam.perception(fr.rgb, fr.depth)
                pts = slam.tracker.track_points(frame.points).astype(np.float64)
                x = pts @ T_true[:3, :3].T + T_true[:3, 3]
                s = np.asarray(sdf(x)[0], dtype=np.float64)
                ok = np.isfinite(s)
                at = register(pts, sdf, T_true, slam.tracker.reg_cfg)
                slam.tracker.update_rms(at.final_rms)  # the running RMS the adaptive kernel uses
                xi = np.concatenate(
                    [rng.choice([-1, 1], 3) * np.radians(deg), rng.choice([-1, 1], 3) * cm / 100]
                )
                res = register(pts, sdf, T_true @ se3_exp(xi), slam.tracker.reg_cfg)
                et, er = pose_error(T_true, res.pose)
                rows.append(
                    (np.median(np.abs(s[ok])), ok.mean(), et, np.degrees(er), res.iterations)
                )
        slam.process(fr.timestamp, fr.rgb, fr.depth, fr.T_world_cam)
    a = np.asarray(rows, dtype=np.float64)
    return {
        "checks": len(a),
        "sdf_at_truth_mm": 1000 * float(np.median(a[:, 0])),
        "valid_fraction": float(np.mean(a[:, 1])),
        "lm_err_mm_median": 1000 * float(np.median(a[:, 2])),
        "lm_err_mm_p90": 1000 * float(np.percentile(a[:, 2], 90)),
        "lm_err_deg_median": float(np.median(a[:, 3])),
        "lm_iterations_median": float(np.median(a[:, 4])),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("tum", type=Path, help="TUM folder with groundtruth.txt")
    ap.add_argument("--configs", type=Path, nargs="+", required=True, help="SlamConfig YAMLs")
    ap.add_argument("--every", type=int, default=3)
    ap.add_argument("--start", type=int, default=6, help="first checked frame")
    ap.add_argument("--perturb-cm", type=float, default=1.0)
    ap.add_argument("--perturb-deg", type=float, default=0.5)
    ap.add_argument("--camera", default=None, help="fr1|fr2|fr3 for folders without camera.yaml")
    a = ap.parse_args()
    print(f"{a.tum}: maps at the true poses; perturbation {a.perturb_cm} cm, {a.perturb_deg} deg")
    print(
        "| config | checks | median abs sdf at truth (mm) | valid | LM error median / p90 (mm) "
        "| LM error (deg) | LM iterations |"
    )
    print("|---|---|---|---|---|---|---|")
    for c in a.configs:
        r = evaluate(a.tum, c, a.every, a.start, a.perturb_cm, a.perturb_deg, a.camera)
        print(
            f"| {c.stem} | {r['checks']} | {r['sdf_at_truth_mm']:.2f} | {r['valid_fraction']:.2f} "
            f"| {r['lm_err_mm_median']:.2f} / {r['lm_err_mm_p90']:.2f} "
            f"| {r['lm_err_deg_median']:.3f} | {r['lm_iterations_median']:.0f} |",
            flush=True,
        )
        print(json.dumps({"config": str(c), **r}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
