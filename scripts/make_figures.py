"""README pictures: a rendered RGB-D frame and a top-down map of a layout with an exact geodesic path.

Writes docs/images/rgbd.png (colour | depth, colour-mapped) and docs/images/layout.png
(overview render | footprint map: inflated free space, start, goal, shortest path). The frame
is rendered with ideal sensing (exact depth, as the committed images were made).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np

import simn_sim  # noqa: F401
from simn_sim.env.scene import ROBOT_RADIUS, ROBOT_Z_BAND


def depth_colour(depth: np.ndarray, dmax: float = 8.0) -> np.ndarray:
    d = np.clip(depth / dmax, 0, 1)
    img = cv2.applyColorMap((255 * (1 - d)).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[depth <= 0] = 0
    return img


def footprint_map(env, start, goal, path, px_per_m: float = 40.0) -> np.ndarray:
    lay = env.layout
    W, H = lay.size
    img = np.full((int(H * px_per_m), int(W * px_per_m), 3), 255, np.uint8)

    def to_px(xy):
        xy = np.atleast_2d(xy)
        return np.c_[xy[:, 0] * px_per_m, (H - xy[:, 1]) * px_per_m].astype(np.int32)

    yy, xx = np.mgrid[0 : img.shape[0] : 2, 0 : img.shape[1] : 2]
    pts = np.c_[xx.ravel() / px_per_m, H - yy.ravel() / px_per_m]
    free = env.free_space.is_free(pts).reshape(xx.shape)
    shade = np.where(free, 255, 215).astype(np.uint8)
    img[:] = cv2.resize(shade, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_NEAREST)[
        ..., None
    ]
    for fp in lay.footprints(ROBOT_Z_BAND):
        cv2.fillPoly(img, [to_px(fp)], (70, 70, 70))
    if path is not None:
        cv2.polylines(img, [to_px(path)], False, (40, 160, 40), 3)
    cv2.circle(img, tuple(to_px(start[:2])[0]), int(ROBOT_RADIUS * px_per_m), (200, 90, 20), -1)
    cv2.circle(img, tuple(to_px(goal)[0]), 8, (20, 20, 220), -1)
    return img


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "images"
    )
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    env = gym.make("SimnOfficeIdeal-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=a.seed)
    u = env.unwrapped
    for _ in range(3):
        obs, *_ = env.step(np.array([0.3, 0.0], np.float32))
    rgbd = np.concatenate([obs["rgb"][..., ::-1], depth_colour(obs["depth"])], axis=1)
    cv2.imwrite(str(a.out / "rgbd.png"), rgbd)
    spec = info["episode_spec"]
    path = u.free_space.shortest_path(np.asarray(spec["start"][:2]), np.asarray(spec["goal"]))
    top = footprint_map(u, np.asarray(spec["start"]), np.asarray(spec["goal"]), path)
    over = env.render()[..., ::-1]
    over = cv2.resize(over, (int(over.shape[1] * top.shape[0] / over.shape[0]), top.shape[0]))
    cv2.imwrite(str(a.out / "layout.png"), np.concatenate([over, top], axis=1))
    env.close()
    print(f"wrote {a.out / 'rgbd.png'} and {a.out / 'layout.png'}")


if __name__ == "__main__":
    main()
