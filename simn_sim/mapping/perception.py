"""Perception: RGB-D + intrinsics -> coloured points in the camera frame; voxel down-sampling;
normals of camera-frame points."""

from __future__ import annotations

import dataclasses

import numpy as np

from simn_sim.geometry.camera import Intrinsics, pixel_rays
from simn_sim.geometry.voxel import voxel_mean
from simn_sim.mapping.config import PerceptionConfig
from simn_sim.semantics import estimate_normals as semantic_normals


class EmptyFrameError(ValueError):
    """A frame has no usable point (empty input or every depth value invalid)."""


@dataclasses.dataclass(frozen=True)
class PointCloud:
    """Points of one frame.

    points: (N, 3) float32, OpenCV camera frame, metres.
    colors: (N, 3) float32 in [0, 1] (grey 0.5 when no image was given).
    labels: (N,) int16 semantic labels or None.
    n_invalid: how many pixels were dropped (0, NaN/inf, outside [min_depth, max_depth]).
    """

    points: np.ndarray
    colors: np.ndarray
    labels: np.ndarray | None
    n_invalid: int

    def __len__(self) -> int:
        return int(self.points.shape[0])


def _check_image(name: str, img: np.ndarray, hw: tuple[int, int], channels: int | None) -> None:
    if not isinstance(img, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(img).__name__}")
    shape = hw if channels is None else (*hw, channels)
    if img.shape != shape:
        raise ValueError(f"{name} has shape {img.shape}, expected {shape}")


def rgbd_to_points(
    depth: np.ndarray,
    intr: Intrinsics,
    rgb: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    cfg: PerceptionConfig | None = None,
) -> PointCloud:
    """Back-project a depth image (and optional colour / label image) to camera-frame points.

    depth: (H, W) float (metres) or unsigned int (scaled by ``cfg.depth_scale``).
    rgb: (H, W, 3) uint8 (0..255) or float in [0, 1]. labels: (H, W) integer.
    Invalid depth (0, NaN, inf, outside ``[min_depth, max_depth]``) is dropped and counted.
    Raises :class:`EmptyFrameError` when nothing valid remains.
    """
    cfg = cfg or PerceptionConfig()
    if not isinstance(depth, np.ndarray):
        raise TypeError(f"depth must be a numpy array, got {type(depth).__name__}")
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    if depth.size == 0:
        raise EmptyFrameError("depth image is empty")
    if not (
        np.issubdtype(depth.dtype, np.floating) or np.issubdtype(depth.dtype, np.unsignedinteger)
    ):
        raise TypeError(f"depth must be float (metres) or unsigned int, got dtype {depth.dtype}")
    h, w = depth.shape
    if (w, h) != (intr.width, intr.height):
        raise ValueError(f"depth is {w}x{h} but intrinsics are {intr.width}x{intr.height}")
    if rgb is not None:
        _check_image("rgb", rgb, (h, w), 3)
        if not (rgb.dtype == np.uint8 or np.issubdtype(rgb.dtype, np.floating)):
            raise TypeError(f"rgb must be uint8 or float, got dtype {rgb.dtype}")
    if labels is not None:
        _check_image("labels", labels, (h, w), None)
        if not np.issubdtype(labels.dtype, np.integer):
            raise TypeError(f"labels must be an integer image, got dtype {labels.dtype}")

    s = cfg.pixel_stride
    z = depth[::s, ::s].astype(np.float32) * np.float32(cfg.depth_scale)
    ok = np.isfinite(z) & (z >= cfg.min_depth) & (z <= cfg.max_depth) & (z > 0)
    n_invalid = int(ok.size - np.count_nonzero(ok))
    if not ok.any():
        raise EmptyFrameError(
            f"all {ok.size} depth values are invalid (0, NaN/inf or outside "
            f"[{cfg.min_depth}, {cfg.max_depth}] m)"
        )
    rx, ry = pixel_rays(intr, s)  # the loop's one ray model (perception.Frame uses it too)
    zv = z[ok]
    pts = np.stack([rx[ok] * zv, ry[ok] * zv, zv], axis=1)
    if rgb is None:
        cols = np.full((pts.shape[0], 3), 0.5, np.float32)
    else:
        c = rgb[::s, ::s][ok]
        cols = (c.astype(np.float32) / 255.0) if rgb.dtype == np.uint8 else c.astype(np.float32)
        cols = np.clip(cols, 0.0, 1.0)
    labs = None if labels is None else labels[::s, ::s][ok].astype(np.int16)
    if cfg.voxel_size > 0:
        pts, cols, labs = voxel_downsample(pts, cfg.voxel_size, cols, labs)
    return PointCloud(pts, cols, labs, n_invalid)


def voxel_downsample(
    points: np.ndarray,
    voxel_size: float,
    colors: np.ndarray | None = None,
    labels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One point per occupied voxel: the mean position and colour, the first point's label.

    points: (N, 3) float. Returns (M, 3) float32 points (M <= N) and the matching attributes,
    in order of first occurrence, so the result is deterministic.

    :func:`simn_sim.geometry.voxel.voxel_mean` does the grouping and averaging. The voxel of a
    point is ``floor(points / voxel_size)`` in the points' own precision (float32 for camera
    points, as this function always did; ``voxel_mean`` divides in float64, which puts a
    float32 point lying on a voxel boundary in the other voxel), so ``voxel_mean`` is given
    the voxel centres as positions and the points themselves (and the colours) as attributes.
    """
    if voxel_size <= 0:
        raise ValueError(f"voxel_size must be > 0, got {voxel_size}")
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if points.shape[0] == 0:
        return points.astype(np.float32), colors, labels
    centres = (np.floor(points / voxel_size).astype(np.float64) + 0.5) * voxel_size
    attrs = (
        points
        if colors is None
        else np.concatenate(
            [np.asarray(points, np.float64), np.asarray(colors, np.float64)], axis=1
        )
    )
    _, mean, labs = voxel_mean(centres, voxel_size, attrs, labels)
    pts = np.ascontiguousarray(mean[:, :3])
    cols = None if colors is None else np.ascontiguousarray(mean[:, 3:])
    return pts, cols, labs


def estimate_normals(points: np.ndarray, k: int = 8) -> np.ndarray:
    """(N, 3) float32 unit normals of camera-frame points by PCA of their ``k`` nearest,
    oriented towards the camera (origin); NaN where fewer than 3 points exist
    (:func:`simn_sim.semantics.estimate_normals` with the mapper's defaults)."""
    return semantic_normals(points, k, towards_origin=True).astype(np.float32)
