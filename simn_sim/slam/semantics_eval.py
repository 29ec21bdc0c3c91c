"""Precision / recall of the pipeline's geometric floor / obstacle labels against the
simulator's segmentation render (``seg/`` of a sequence recorded with ``segmentation=True``).

Truth per pixel: 1 floor, 2 obstacle, 4 person (counted as obstacle), 0 nothing. The pipeline
labels the points it back-projects (every ``stride``-th valid pixel) with the geometric
classifier at its *estimated* pose (floor = base plane). Obstacle figures are over points up to
the classifier's ``robot_height`` above the true floor: higher obstacle pixels (upper walls) are
OVERHEAD by design (the base drives under them), not misses.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from simn_sim.geometry.se3 import inv_T, transform_points
from simn_sim.io.tum import read_file_list, read_tum
from simn_sim.semantics import FLOOR, OBSTACLE, precision_recall
from simn_sim.slam.config import SlamConfig
from simn_sim.slam.pipeline import SimnSlam
from simn_sim.slam.record import read_base, read_odometry


def evaluate_classifier(
    folder: str | Path, cfg: SlamConfig | None = None, max_frames: int | None = None
) -> dict[str, Any]:
    """Run the pipeline on a recorded folder with ``seg/`` and pool the labels of all frames.

    Returns ``floor_precision``, ``floor_recall``, ``obstacle_precision``, ``obstacle_recall``
    (over points at most ``robot_height`` above the true floor), ``n_points``, ``frames``.
    """
    folder = Path(folder)
    if not (folder / "seg.txt").is_file():
        raise FileNotFoundError(f"{folder} has no seg.txt (record with segmentation=True)")
    cfg = cfg or SlamConfig(map_kind="points")
    seq = read_tum(folder)
    stamps, files = read_file_list(folder / "seg.txt")
    seg_of = {round(float(t), 6): folder / f[0] for t, f in zip(stamps, files, strict=True)}
    T_base_cam = read_base(folder)
    if T_base_cam is None:
        raise FileNotFoundError(f"{folder} has no base.yaml")
    odom = read_odometry(folder)
    slam = SimnSlam(cfg, seq.intrinsics, T_base_cam)
    pred_all, true_all, low_all = [], [], []
    n = len(seq) if max_frames is None else min(len(seq), max_frames)
    for k in range(n):
        fr = seq[k]
        prior = None if odom is None else odom.get(round(fr.timestamp, 6))
        out = slam.process(fr.timestamp, fr.rgb, fr.depth, prior)
        seg = cv2.imread(str(seg_of[round(fr.timestamp, 6)]), cv2.IMREAD_UNCHANGED)
        if seg is None or out.pixels is None:
            continue
        truth = seg[out.pixels[:, 0], out.pixels[:, 1]].astype(np.int64)
        truth = np.where(truth == 4, OBSTACLE, truth)
        # height above the true floor (z = 0 in the simulator's world)
        # height above the true floor (z = 0 in the simulator's world), from the true pose
        P = transform_points(inv_T(out.T_world_cam), out.points_world.astype(np.float64))
        h = transform_points(fr.T_world_cam, P)[:, 2]
        pred_all.append(out.labels.astype(np.int64))
        true_all.append(truth)
        low_all.append(h <= cfg.classifier.robot_height)
    pred = np.concatenate(pred_all)
    true = np.concatenate(true_all)
    low = np.concatenate(low_all)
    fp, fr_ = precision_recall(pred, true, FLOOR)
    op, orc = precision_recall(pred[low], true[low], OBSTACLE)
    return {
        "floor_precision": fp,
        "floor_recall": fr_,
        "obstacle_precision": op,
        "obstacle_recall": orc,
        "n_points": int(len(pred)),
        "frames": n,
    }
