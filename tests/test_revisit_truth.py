"""Closed-loop revisits judged against true poses (simn_sim.eval.revisits), on trajectories
whose ground truth is known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simn_sim.eval.revisits import revisit_truth
from simn_sim.geometry.se3 import inv_T


def _cam(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """A level camera at (x, y, 0.5) looking along the heading ``yaw_deg`` (OpenCV axes: z
    forward, y down)."""
    a = math.radians(yaw_deg)
    f = np.array([math.cos(a), math.sin(a), 0.0])  # optical axis
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, f)
    T = np.eye(4)
    T[:3, :3] = np.stack([right, down, f], axis=1)
    T[:3, 3] = [x, y, 0.5]
    return T


def _square_loop() -> list[np.ndarray]:
    """A 4 m square driven counter-clockwise at 0.25 m per observation, back to the start
    with the start heading: 64 observations plus the closing one."""
    poses = []
    for x0, y0, yaw in [(0, 0, 0), (4, 0, 90), (4, 4, 180), (0, 4, 270)]:
        dx, dy = round(math.cos(math.radians(yaw))), round(math.sin(math.radians(yaw)))
        for k in range(16):
            poses.append(_cam(x0 + dx * 0.25 * k, y0 + dy * 0.25 * k, yaw))
    poses.append(_cam(0.0, 0.0, 360.0))
    return poses


def test_a_closing_loop_is_one_opportunity_and_an_exact_arc_is_correct():
    poses = _square_loop()
    frame_obs = list(range(0, 65, 8))  # frames 0..8; frame 8 opens back at the start
    truth = inv_T(poses[0]) @ poses[64]
    off = inv_T(poses[8]) @ poses[64]
    off[:3, 3] += [0.3, 0.0, 0.0]  # an arc to frame 1, 0.3 m off: a wrong revisit
    out = revisit_truth(frame_obs, [(8, 0, truth), (8, 1, off)], poses, exclude_recent=3)
    # only frame 8 opens within 0.75 m / 30 deg of an earlier frame (frame 0, 8 frames back)
    assert out["revisit_opportunities"] == 1
    assert out["revisits_correct"] == 1 and out["revisit_opportunities_closed"] == 1
    assert out["revisits_off_fine"] == 0  # the 0.3 m arc is wrong, not "correct but off"
    # an arc 0.12 m off: correct at 0.2 m, off at 0.05 m
    near = truth.copy()
    near[:3, 3] += [0.0, 0.12, 0.0]
    fine = revisit_truth(frame_obs, [(8, 0, near)], poses, exclude_recent=3)
    assert fine["revisits_correct"] == 1 and fine["revisits_off_fine"] == 1
    assert revisit_truth(frame_obs, [(8, 0, near)], poses, fine_m=0.15)["revisits_off_fine"] == 0
    # errors of the two arcs: 0 and 0.3 m -> median 0.15 m, rotations exact
    assert out["revisit_err_m_median"] == pytest.approx(0.15, abs=1e-9)
    assert out["revisit_err_deg_median"] == pytest.approx(0.0, abs=1e-6)


def test_a_wrong_arc_alone_closes_no_opportunity():
    poses = _square_loop()
    frame_obs = list(range(0, 65, 8))
    truth = inv_T(poses[0]) @ poses[64]
    turned = truth.copy()
    a = math.radians(8.0)  # 8 deg about the camera's y axis: over the 5 deg tolerance
    Ry = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    turned[:3, :3] = truth[:3, :3] @ Ry
    out = revisit_truth(frame_obs, [(8, 0, turned)], poses)
    assert out["revisits_correct"] == 0 and out["revisit_opportunities"] == 1
    assert out["revisit_opportunities_closed"] == 0
    assert out["revisit_err_deg_median"] == pytest.approx(8.0, abs=1e-6)


def test_recent_frames_are_not_opportunities_and_headings_count():
    # standing still: every frame opens at the same pose
    poses = [_cam(1.0, 2.0, 45.0)] * 10
    out = revisit_truth([0, 2, 4, 6, 8], [], poses, exclude_recent=3)
    # frames 3 and 4 have frame 0 / frame 1 at least 3 frames back
    assert out["revisit_opportunities"] == 2
    assert revisit_truth([0, 2, 4, 6, 8], [], poses, exclude_recent=1)["revisit_opportunities"] == 4
    # the same place seen the opposite way is no opportunity: frames 0-2 look one way, 3-4
    # the other; frame 3 has only frames looking away before it
    back = [_cam(1.0, 2.0, 45.0)] * 5 + [_cam(1.0, 2.0, 225.0)] * 5
    assert revisit_truth([0, 2, 4, 6, 8], [], back, exclude_recent=1)["revisit_opportunities"] == 3
    assert revisit_truth([0], [], poses)["revisit_err_m_median"] is None


def test_bad_input_is_named():
    poses = [_cam(0.0, 0.0, 0.0)] * 3
    with pytest.raises(ValueError, match="frame 1 opened at observation 7"):
        revisit_truth([0, 7], [], poses)
    with pytest.raises(ValueError, match="revisit 5 -> 0 names an unknown frame"):
        revisit_truth([0, 1], [(5, 0, np.eye(4))], poses)
    with pytest.raises(ValueError, match="tol_m must be > 0"):
        revisit_truth([0], [], poses, tol_m=0.0)


def test_revisit_report_pools_counts_over_episodes(tmp_path, load_script):
    """``scripts/revisit_report.py``: precision and recall from summed counts, not a mean of
    per-episode ratios; records without the judged fields (other agents, old runs) skipped."""
    import json

    mod = load_script("revisit_report")
    base = {"agent": "simn", "seed": 0}
    recs = [
        {**base, "episode_id": "a", "revisits": 3, "revisits_correct": 2,
         "revisit_opportunities": 4, "revisit_opportunities_closed": 1,
         "revisit_err_m_median": 0.05, "revisit_err_deg_median": 1.0},
        {**base, "episode_id": "b", "revisits": 1, "revisits_correct": 1,
         "revisit_opportunities": 0, "revisit_opportunities_closed": 0,
         "revisit_err_m_median": 0.01, "revisit_err_deg_median": 0.5},
        {**base, "episode_id": "c", "revisits": 2, "revisits_correct": None},
    ]  # fmt: skip
    p = mod.pooled(recs)
    assert p["episodes"] == 2 and p["accepted"] == 4 and p["correct"] == 3
    assert p["precision"] == 0.75 and p["recall"] == 0.25  # 3/4 and 1/4
    assert p["err_m_median"] == pytest.approx(0.03)
    assert p["off_fine"] is None  # these records predate revisits_off_fine
    recs[0]["revisits_off_fine"], recs[1]["revisits_off_fine"] = 1, 0
    assert mod.pooled(recs)["off_fine"] == 1
    (tmp_path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    assert mod.main([str(tmp_path)]) == 0
