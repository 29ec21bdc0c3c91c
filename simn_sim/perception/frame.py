"""One RGB-D image -> one :class:`Frame`: points, normals, colours, pixels, labels, validity.

Everything downstream of the sensor (tracking, mapping, local-frame stores, carving, semantics,
occlusion shadows) takes the same :class:`Frame`, made once per step by :class:`Perception`.

Back-projection (OpenCV camera frame, z = depth along the optical axis): every ``stride``-th
pixel ``(u, v)`` of the full image gives ``x = (u - cx) / fx * z``, ``y = (v - cy) / fy * z``
(the ray tables of :func:`simn_sim.geometry.camera.pixel_rays`). A pixel is valid when its depth
is finite, > 0 and within ``[min_depth, max_depth]``.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from simn_sim.config import Config, require
from simn_sim.geometry.camera import Intrinsics, pixel_rays
from simn_sim.semantics import normals_from_organized

__all__ = ["Frame", "Perception", "PerceptionConfig"]


@dataclasses.dataclass(frozen=True)
class PerceptionConfig(Config):
    """Which pixels become points, and how their normals are estimated.

    stride: every ``stride``-th pixel in both directions (0: automatic, about 160 columns).
    normal_smooth_px: normals from the depth box-blurred over (2 k + 1)^2 pixels (noisy stereo
    depth gives useless central-difference normals); 0: raw central differences; -1: no normals.
    map_normal_smooth_px: a second set of normals for the learned map's geometric prior
    (-1: none; equal to ``normal_smooth_px``: the same array).
    """

    stride: int = 0
    min_depth: float = 0.28
    max_depth: float = 6.0
    normal_smooth_px: int = 1
    map_normal_smooth_px: int = -1

    def validate(self) -> None:
        n = type(self).__name__
        require(self.stride >= 0, n, "stride", "must be >= 0 (0: automatic)")
        require(
            np.isfinite(self.max_depth) and 0 <= self.min_depth < self.max_depth,
            n,
            "max_depth",
            "need 0 <= min_depth < max_depth",
        )
        require(self.normal_smooth_px >= -1, n, "normal_smooth_px", "must be >= -1 (-1: none)")
        require(self.map_normal_smooth_px >= -1, n, "map_normal_smooth_px", "must be >= -1")


@dataclasses.dataclass
class Frame:
    """One perceived RGB-D image (N valid pixels, row-major order).

    points: (N, 3) float32, OpenCV camera frame. normals: (N, 3) float32 camera frame, NaN where
    unknown (None when not estimated). map_normals: (N, 3) float32 for the learned map's prior,
    or None. colors: (N, 3) float32 in [0, 1] (0.5 grey without an image). pixels: (N, 2) int64
    (row, column) in the full-resolution image. depth: (h, w) float32 strided depth image, 0 where
    invalid. valid: (h, w) bool. labels: (N,) int8 semantic labels (0 unknown, 1 floor,
    2 obstacle, 3 overhead; :mod:`simn_sim.semantics`), None until classified.
    """

    points: np.ndarray
    normals: np.ndarray | None
    map_normals: np.ndarray | None
    colors: np.ndarray
    pixels: np.ndarray
    depth: np.ndarray
    valid: np.ndarray
    stride: int
    intrinsics: Intrinsics
    n_invalid: int = 0
    labels: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    def select(self, keep: np.ndarray) -> Frame:
        """The frame with only the points where ``keep`` ((N,) bool) is True; the depth image
        and its validity stay whole (they are the image, not the points)."""
        keep = np.asarray(keep)
        if keep.dtype != bool or keep.shape != (len(self),):
            raise ValueError(
                f"keep must be a ({len(self)},) bool mask, got {keep.dtype} {keep.shape}"
            )

        def sub(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[keep]

        return dataclasses.replace(
            self,
            points=self.points[keep],
            normals=sub(self.normals),
            map_normals=sub(self.map_normals),
            colors=self.colors[keep],
            pixels=self.pixels[keep],
            labels=sub(self.labels),
        )

    def with_labels(self, labels: np.ndarray) -> Frame:
        labels = np.asarray(labels, np.int8)
        if labels.shape != (len(self),):
            raise ValueError(f"labels must be ({len(self)},), got {labels.shape}")
        return dataclasses.replace(self, labels=labels)


class Perception:
    """Makes :class:`Frame` s from RGB-D images of one camera (ray tables computed once)."""

    def __init__(self, intrinsics: Intrinsics, cfg: PerceptionConfig | None = None) -> None:
        self.cfg = cfg or PerceptionConfig()
        self.intr = intrinsics
        self.stride = self.cfg.stride or max(1, int(round(intrinsics.width / 160)))
        self._ray_x, self._ray_y = pixel_rays(intrinsics, self.stride)

    def __call__(self, rgb: np.ndarray | None, depth: np.ndarray) -> Frame:
        """rgb: (H, W, 3) uint8 (or float in [0, 1]) or None. depth: (H, W) float metres, 0 or
        NaN where invalid. Raises ``ValueError`` for a wrong shape or dtype."""
        depth = np.asarray(depth)
        h, w = self.intr.height, self.intr.width
        if depth.shape != (h, w):
            raise ValueError(f"depth is {depth.shape}, intrinsics are {w}x{h}")
        if not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"depth must be float metres, got dtype {depth.dtype}")
        s, c = self.stride, self.cfg
        z = depth[::s, ::s].astype(np.float32)
        ok = np.isfinite(z) & (z > 0) & (z >= c.min_depth) & (z <= c.max_depth)
        zz = np.where(ok, z, 0.0).astype(np.float32)
        P = np.stack([self._ray_x * zz, self._ray_y * zz, zz], axis=2)
        pts = P[ok]
        nrm = map_nrm = None
        if c.normal_smooth_px >= 0:
            nrm = self._normals(P, zz, ok, c.normal_smooth_px)[ok].astype(np.float32)
        if c.map_normal_smooth_px >= 0:
            if c.map_normal_smooth_px == c.normal_smooth_px:
                map_nrm = nrm
            else:
                map_nrm = self._normals(P, zz, ok, c.map_normal_smooth_px)[ok].astype(np.float32)
        if rgb is not None:
            rgb = np.asarray(rgb)
            if rgb.shape != (h, w, 3):
                raise ValueError(f"rgb is {rgb.shape}, expected ({h}, {w}, 3)")
            col = rgb[::s, ::s][ok]
            col = col.astype(np.float32) / 255.0 if rgb.dtype == np.uint8 else col
            col = np.clip(col.astype(np.float32), 0, 1)
        else:
            col = np.full((len(pts), 3), 0.5, np.float32)
        rows, cols = np.nonzero(ok)
        pix = np.stack([rows * s, cols * s], axis=1)
        return Frame(
            points=pts,
            normals=nrm,
            map_normals=map_nrm,
            colors=col,
            pixels=pix,
            depth=zz,
            valid=ok,
            stride=s,
            intrinsics=self.intr,
            n_invalid=int(ok.size - ok.sum()),
        )

    def _normals(self, P: np.ndarray, zz: np.ndarray, ok: np.ndarray, k_px: int) -> np.ndarray:
        """(h, w, 3) normals of the organised points; with ``k_px`` > 0 from a normalised-
        convolution box blur of the depth over (2 k_px + 1)^2 pixels; the points themselves keep
        the raw depth."""
        if k_px <= 0:
            return normals_from_organized(np.where(ok[..., None], P, np.nan))
        k = 2 * k_px + 1
        wsum = cv2.blur(ok.astype(np.float32), (k, k))
        zs = cv2.blur(zz, (k, k)) / np.maximum(wsum, 1e-6)
        Ps = np.stack([self._ray_x * zs, self._ray_y * zs, zs], axis=2)
        return normals_from_organized(np.where(ok[..., None], Ps, np.nan))
