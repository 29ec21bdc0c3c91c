"""Pinhole camera model and the MuJoCo <-> OpenCV camera-frame conversion.

Camera frames: the *OpenCV* optical frame (x right, y down, z forward) is the one used for all
points named ``points_cam``. MuJoCo's camera frame looks along its -z with y up; convert with
:data:`T_MJCAM_CV` in one place.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

# Maps points in the OpenCV optical frame to MuJoCo's camera frame (x right, y up, looking -z).
T_MJCAM_CV = np.diag([1.0, -1.0, -1.0, 1.0])

D435I_FOVY_DEG = 42.5


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; image of ``width`` x ``height``."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(
                f"Intrinsics: image size must be positive, got {self.width}x{self.height}"
            )
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise ValueError(f"Intrinsics.{name} must be finite, got {v}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(
                f"Intrinsics: focal lengths must be positive, got fx={self.fx}, fy={self.fy}"
            )

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float = D435I_FOVY_DEG) -> Intrinsics:
        """MuJoCo's pinhole: fx = fy = (H/2)/tan(fovy/2), principal point ((W-1)/2, (H-1)/2)."""
        if not 0.0 < fovy_deg < 180.0:
            raise ValueError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
        f = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def pixel_rays(intr: Intrinsics, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ray tables of every ``stride``-th pixel: (h, w) float32 ``(u - cx) / fx`` and
    ``(v - cy) / fy`` in full-image pixel coordinates (a point at depth z is (x z, y z, z))."""
    v, u = np.mgrid[0 : intr.height : stride, 0 : intr.width : stride]
    return (
        ((u - intr.cx) / intr.fx).astype(np.float32),
        ((v - intr.cy) / intr.fy).astype(np.float32),
    )


def backproject(depth: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(H, W) metric depth -> (H, W, 3) float32 points in the OpenCV camera frame (z = depth)."""
    h, w = depth.shape
    if (w, h) != (intr.width, intr.height):
        raise ValueError(f"depth is {w}x{h} but intrinsics are {intr.width}x{intr.height}")
    rx, ry = pixel_rays(intr)
    z = depth.astype(np.float32, copy=False)
    return np.stack([rx * z, ry * z, z], axis=-1)


def project(points_cam: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """(N, 3) OpenCV-frame points -> (N, 2) pixel coordinates (u, v)."""
    z = points_cam[:, 2]
    return np.stack(
        [intr.fx * points_cam[:, 0] / z + intr.cx, intr.fy * points_cam[:, 1] / z + intr.cy], axis=1
    )
