"""Revisit candidates with and without the learned key-point features: precision and recall on
recorded loop sequences, before and after registration verifies them.

Each sequence is run through :class:`~simn_sim.slam.SimnSlam` (the learned map, wheel-odometry
prior, revisits closed with the ``--runs`` ranking, ``SlamConfig.revisit_features``). When a
local frame opens, all three rankings (``learned``: key points matched by their learned
features; ``keypoints``: the same without the features; ``geometric``: pooled descriptors) are
computed on the same maps and poses, and each ranking's candidates are verified in order by the
check's registration (:meth:`~simn_sim.slam.revisit.Revisits.verify`, which adds no loop):
*before verification* counts all its candidates, *after verification* the first one that passes
(what the check would accept; the pose graph's robust loss is not applied). ``accepted`` is what
the run itself accepted.

Ground truth (the simulator's poses): an earlier frame ``c`` is a true revisit of the frame
``q`` being opened when at least ``--gt-overlap`` of the observation the check registers
(``q``'s first frame's registration points), placed at its true pose, lies within
``--gt-radius`` of ``c``'s surface points placed through ``c``'s true anchor (overlap is what
the registration check needs). Only frames the check may consider count
(not the ``loop.exclude_recent`` newest).

* precision: true candidates / candidates (pairs);
* recall: opened frames with a true revisit that got at least one true candidate / opened
  frames with a true revisit; pair recall: true candidates / true pairs.

    MUJOCO_GL=egl .venv/bin/python scripts/bench_revisits.py --record /tmp/simn_revisits \
        --json /tmp/simn_revisits/bench.json
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from simn_sim.eval.trajectory import ate_rpe  # noqa: E402
from simn_sim.experiments.batch_files import machine_summary
from simn_sim.geometry.se3 import transform_points  # noqa: E402
from simn_sim.io.tum import read_tum  # noqa: E402
from simn_sim.slam import SimnSlam  # noqa: E402
from simn_sim.slam.presets import load_slam_config  # noqa: E402
from simn_sim.slam.record import read_base, read_odometry, record_sequence  # noqa: E402
from simn_sim.slam.revisit import RANKINGS  # noqa: E402

# (name, layout_seed, seed): the reference office and two generated layouts
SEQUENCES = [("ref_s0", None, 0), ("ref_s1", None, 1), ("layout3_s0", 3, 0)]


def run_one(folder: Path, ranking: str, config: Path | None, max_frames: int | None) -> dict:
    """One SLAM run; returns per opened frame the rankings of all three kinds, the observation
    (camera frame), the true poses and the surface points of every frame."""
    seq = read_tum(folder)
    odom = read_odometry(folder)
    cfg = load_slam_config(config, revisit_features=ranking)
    slam = SimnSlam(cfg, seq.intrinsics, read_base(folder))
    rv = slam.revisits
    ranks: dict[int, dict[str, list]] = {}
    verified: dict[int, dict[str, int | None]] = {}
    observed: dict[int, np.ndarray] = {}
    rank_ms: dict[str, list[float]] = {r: [] for r in RANKINGS}
    orig = rv.on_open

    def hook(fid, pts, T_world_cam):
        observed[fid] = np.asarray(pts, np.float64)  # what the check registers (camera frame)
        ranks[fid], verified[fid], ok = {}, {}, {}
        for r in RANKINGS:
            t0 = time.perf_counter()
            ranks[fid][r] = rv.candidates(fid, pts, T_world_cam, r)
            rank_ms[r].append((time.perf_counter() - t0) * 1e3)
            # as the check: the first candidate (in ranked order) that registration verifies
            verified[fid][r] = None
            for c, _ in ranks[fid][r]:
                if c not in ok:
                    ok[c] = rv.verify(c, pts, T_world_cam)
                if ok[c]:
                    verified[fid][r] = c
                    break
        return orig(fid, pts, T_world_cam)

    rv.on_open = hook
    gt, opened, queries = [], {0: 0}, {}
    t0 = time.perf_counter()
    for i, fr in enumerate(seq):
        if max_frames and i >= max_frames:
            break
        out = slam.process(fr.timestamp, fr.rgb, fr.depth, odom[round(fr.timestamp, 6)])
        gt.append((fr.timestamp, fr.T_world_cam))
        if out.new_local_frame and out.frame_id > 0:
            opened[out.frame_id] = i
            if out.frame_id in observed:
                queries[out.frame_id] = transform_points(fr.T_world_cam, observed[out.frame_id])
    wall = time.perf_counter() - t0
    surf = {
        f: transform_points(gt[opened[f]][1], st.surface.surface.points.astype(np.float64))
        for f, st in slam.frames.states.items()
        if len(st.surface.surface)
    }
    accepted = {e["frame"]: e.get("accepted") for e in slam.loop_log if "accepted" in e}
    return {
        "ranks": ranks,
        "verified": verified,
        "rank_ms": rank_ms,
        "queries": queries,
        "surfaces": surf,
        "accepted": accepted,
        "n_frames": len(gt),
        "local_frames": len(slam.frames),
        "revisits_accepted": slam.n_revisits,
        "ate_online_cm": 100 * ate_rpe(slam.trajectory(corrected=False), gt)["ate_rmse_m"],
        "ate_final_cm": 100 * ate_rpe(slam.trajectory(), gt)["ate_rmse_m"],
        "s_per_frame": wall / max(len(gt), 1),
        "exclude_recent": cfg.loop.exclude_recent,
        "share_decoder": cfg.share_decoder,
    }


def truth(run: dict, radius: float, min_overlap: float) -> dict[int, set[int]]:
    """Per opened frame, the earlier frames it truly revisits (see the module docstring)."""
    trees = {f: cKDTree(P) for f, P in run["surfaces"].items()}
    out = {}
    for q, Pq in run["queries"].items():
        true = set()
        for c, tree in trees.items():
            if c > q - run["exclude_recent"]:
                continue
            d, _ = tree.query(Pq, distance_upper_bound=radius)
            if np.isfinite(d).mean() >= min_overlap:
                true.add(c)
        out[q] = true
    return out


def score(pairs: dict[int, list[int]], true: dict[int, set[int]]) -> dict:
    """Precision / recall of the candidates ``pairs`` (per opened frame) against ``true``."""
    prop = sum(len(v) for v in pairs.values())
    tp = sum(len(set(v) & true.get(q, set())) for q, v in pairs.items())
    pos = [q for q, t in true.items() if t]
    hit = sum(1 for q in pos if set(pairs.get(q, [])) & true[q])
    n_true = sum(len(true[q]) for q in pos)
    return {
        "candidates": prop,
        "true_candidates": tp,
        "precision": tp / prop if prop else float("nan"),
        "frames_with_revisit": len(pos),
        "recall": hit / len(pos) if pos else float("nan"),
        "true_pairs": n_true,
        "pair_recall": tp / n_true if n_true else float("nan"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("folders", nargs="*", type=Path, help="recorded loop sequences (TUM folders)")
    ap.add_argument("--record", type=Path, help="record the default loop sequences under here")
    ap.add_argument("--size", default="160x120", help="recording size (default 160x120)")
    ap.add_argument("--odom-noise", type=float, nargs=2, default=(0.1, 0.1),
                    help="recorded wheel odometry noise (scale, heading), as tests/test_slam_loop.py")  # fmt: skip
    ap.add_argument("--runs", nargs="+", default=["learned"], choices=RANKINGS,
                    help="the ranking each SLAM run closes its loops with (one run each)")  # fmt: skip
    ap.add_argument("--gt-radius", type=float, default=0.05)
    ap.add_argument("--gt-overlap", type=float, default=0.5)
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--config", type=Path, help="SlamConfig YAML (default: SlamConfig())")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--merge", type=Path, nargs="+", help="pool the given bench JSONs and exit")
    args = ap.parse_args()
    if args.merge:
        summarize([json.loads(p.read_text()) for p in args.merge])
        return
    torch.set_num_threads(1)
    folders = list(args.folders)
    if args.record:
        w, h = (int(v) for v in args.size.split("x"))
        for name, layout, seed in SEQUENCES:
            f = args.record / name
            if not (f / "groundtruth.txt").exists():
                record_sequence(
                    f, "loop", width=w, height=h, layout_seed=layout, seed=seed,
                    odom_noise=tuple(args.odom_noise), overwrite=True,
                )  # fmt: skip
            folders.append(f)
    if not folders:
        ap.error("give loop folders or --record DIR")
    results: dict = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": f"{machine_summary()}, load {os.getloadavg()[0]:.1f}",
        "gt_radius_m": args.gt_radius,
        "gt_overlap": args.gt_overlap,
        "config": None if args.config is None else args.config.read_text(),
        "sequences": {},
    }
    for folder in folders:
        seq_res = {}
        for run_kind in args.runs:
            t0 = time.perf_counter()
            run = run_one(folder, run_kind, args.config, args.max_frames or None)
            true = truth(run, args.gt_radius, args.gt_overlap)
            seq_res[run_kind] = {
                **{k: run[k] for k in ("n_frames", "local_frames", "revisits_accepted",
                                       "ate_online_cm", "ate_final_cm", "s_per_frame",
                                       "share_decoder")},
                "rank_ms_mean": {r: float(np.mean(v)) if v else None for r, v in run["rank_ms"].items()},
                "wall_s": time.perf_counter() - t0,
                "true_revisits": {int(q): sorted(int(c) for c in t) for q, t in true.items() if t},
                "ranked": {int(q): v for q, v in run["ranks"].items()},
                "verified": {int(q): v for q, v in run["verified"].items()},
                "accepted": {int(q): a for q, a in run["accepted"].items()},
            }  # fmt: skip
            stages = stage_scores(seq_res[run_kind])
            seq_res[run_kind]["scores"] = stages
            brief = {
                k: [round(v["precision"], 2), round(v["recall"], 2)] for k, v in stages.items()
            }
            print(f"{folder.name} run={run_kind}: precision/recall {brief}; accepted "
                  f"{run['revisits_accepted']}, ATE online/final {run['ate_online_cm']:.2f}/"
                  f"{run['ate_final_cm']:.2f} cm, {run['s_per_frame']:.2f} s/frame", flush=True)  # fmt: skip
        results["sequences"][folder.name] = seq_res
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=float))
        print("wrote", args.json)
    summarize([results])


def _pairs(seq: dict) -> dict[str, tuple[dict, dict]]:
    """Per stage name, (candidates per opened frame, truth) of one run's record."""
    true = {int(q): set(v) for q, v in seq["true_revisits"].items()}
    out = {}
    for r in RANKINGS:
        b = {int(q): [c for c, _ in v[r]] for q, v in seq["ranked"].items()}
        a = {int(q): [] if v[r] is None else [v[r]] for q, v in seq["verified"].items()}
        out[f"{r}|before"], out[f"{r}|after"] = (b, true), (a, true)
    acc = {int(q): [] if a is None else [a] for q, a in seq["accepted"].items()}
    out["run|accepted"] = (acc, true)
    return out


def stage_scores(seq: dict) -> dict[str, dict]:
    return {k: score(*v) for k, v in _pairs(seq).items()}


def summarize(results_list: list[dict]) -> dict:
    """Pool the sequences of ``results_list`` (bench JSONs) per run kind and stage; print the
    table."""
    pools: dict[tuple[str, str], list[tuple[dict, dict]]] = {}
    n_seq = set()
    for res in results_list:
        for name, seq_res in res["sequences"].items():
            n_seq.add(name)
            for run_kind, seq in seq_res.items():
                for k, v in _pairs(seq).items():
                    pools.setdefault((run_kind, k), []).append(v)

    def pooled(items):
        P, T = {}, {}
        for k, (p, t) in enumerate(items):
            P.update({(k, q): v for q, v in p.items()})
            T.update({(k, q): v for q, v in t.items()})
        return score(P, T)

    out = {f"{run}|{k}": pooled(v) for (run, k), v in pools.items()}
    print(f"\nPooled over {len(n_seq)} sequences:")
    print("| run | ranking | stage | precision | recall | pair recall | candidates (true) |")
    print("|---|---|---|---|---|---|---|")
    for key, m in out.items():
        run, r, stage = key.split("|")
        print(f"| {run} | {r if r != 'run' else run} | {stage} | {m['precision']:.2f} | "
              f"{m['recall']:.2f} | {m['pair_recall']:.2f} | {m['candidates']} "
              f"({m['true_candidates']}) |")  # fmt: skip
    return out


if __name__ == "__main__":
    main()
