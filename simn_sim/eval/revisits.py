"""Revisits in the closed loop judged against the simulator's true poses.

A local frame's coordinates are those of the camera when the frame opened (its anchor), so an
accepted revisit's loop arc ``T_cand_query`` (the query frame's anchor in the candidate frame)
has a ground truth that world drift does not enter: ``inv(T_true(c)) @ T_true(q)``, the true
camera poses at the two frames' openings.

* **correct**: the arc is within ``tol_m`` / ``tol_deg`` of that truth (precision = correct /
  accepted);
* **off**: a correct arc more than ``fine_m`` from that truth (``revisits_off_fine``): wrong
  enough to move the estimate by more than the front-end's typical ATE (0.05-0.08 m in the
  closed loop), yet inside the 0.2 m tolerance;
* **opportunity**: a frame opened within ``near_m`` / ``near_deg`` (camera position, viewing
  direction) of the true anchor of a frame the revisit check may consider, i.e. one opened at
  least ``exclude_recent`` frames earlier (``LoopClosureConfig.exclude_recent``); recall =
  opportunities closed by a correct revisit / opportunities. Pose proximity stands in for
  view overlap, which needs the maps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from simn_sim.geometry.se3 import inv_T, pose_error

__all__ = ["revisit_truth"]


def _view_angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Angle between two cameras' optical axes (+z of the OpenCV camera frame), degrees."""
    c = float(np.clip(T_a[:3, 2] @ T_b[:3, 2], -1.0, 1.0))
    return math.degrees(math.acos(c))


def revisit_truth(
    frame_obs: Sequence[int],
    accepted: Sequence[tuple[int, int, np.ndarray]],
    T_world_cam_true: Sequence[np.ndarray],
    exclude_recent: int = 3,
    tol_m: float = 0.2,
    tol_deg: float = 5.0,
    near_m: float = 0.75,
    near_deg: float = 30.0,
    fine_m: float = 0.05,
) -> dict[str, Any]:
    """Judge an episode's revisits against the true camera poses.

    frame_obs: for each local frame id (0, 1, ...), the index into ``T_world_cam_true`` of the
    observation it opened at. accepted: ``(query frame, candidate frame, T_cand_query (4, 4))``
    per accepted revisit. T_world_cam_true: the true camera pose of every observation.
    Returns counts for the episode record (``revisits_correct``, ``revisits_off_fine``,
    ``revisit_opportunities``, ``revisit_opportunities_closed``) and the arcs' median errors
    (None without revisits).
    """
    for name, v in (("tol_m", tol_m), ("tol_deg", tol_deg), ("near_m", near_m), ("fine_m", fine_m)):
        if not v > 0:
            raise ValueError(f"revisit_truth: {name} must be > 0, got {v}")
    n_obs = len(T_world_cam_true)
    for fid, i in enumerate(frame_obs):
        if not 0 <= int(i) < n_obs:
            raise ValueError(
                f"revisit_truth: frame {fid} opened at observation {i}, outside 0..{n_obs - 1}"
            )
    anchors = [np.asarray(T_world_cam_true[int(i)], float) for i in frame_obs]
    errs_m, errs_deg = [], []
    correct_q = set()
    n_correct = n_off_fine = 0
    for q, c, T in accepted:
        if not (0 <= q < len(anchors) and 0 <= c < len(anchors)):
            raise ValueError(f"revisit_truth: revisit {q} -> {c} names an unknown frame")
        truth = inv_T(anchors[c]) @ anchors[q]
        dt, dr = pose_error(truth, np.asarray(T, float))
        errs_m.append(dt)
        errs_deg.append(math.degrees(dr))
        if dt <= tol_m and math.degrees(dr) <= tol_deg:
            correct_q.add(q)
            n_correct += 1
            n_off_fine += int(dt > fine_m)
    opp = []
    for q in range(len(anchors)):
        for c in range(q - exclude_recent + 1):
            far = np.linalg.norm(anchors[q][:3, 3] - anchors[c][:3, 3]) > near_m
            if not far and _view_angle_deg(anchors[q], anchors[c]) <= near_deg:
                opp.append(q)
                break
    return {
        "revisits_correct": n_correct,
        "revisits_off_fine": n_off_fine,
        "revisit_opportunities": len(opp),
        "revisit_opportunities_closed": sum(1 for q in opp if q in correct_q),
        "revisit_err_m_median": float(np.median(errs_m)) if errs_m else None,
        "revisit_err_deg_median": float(np.median(errs_deg)) if errs_deg else None,
    }
