"""TUM RGB-D benchmark folders: reader, timestamp association and writer.

Layout (Sturm et al., IROS 2012): ``rgb/`` (8-bit colour PNG), ``depth/`` (16-bit PNG, metres =
value / depth_factor, 0 = no reading), ``rgb.txt`` and ``depth.txt`` (``timestamp filename`` per
line, ``#`` comments), optional ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, the pose
``T_world_cam`` of the optical centre). We add an optional ``camera.yaml``
(``width height fx fy cx cy depth_factor``) so folders written by :class:`TumWriter` are
self-describing.

Frames are associated like the benchmark's ``associate.py``: all (rgb, depth) pairs closer than
``max_diff`` seconds are candidates; they are taken greedily by increasing time difference, each
stamp used at most once. Ground truth is then associated to the frame (rgb) stamps the same way.
Lens distortion is kept by default; ``undistort=True`` remaps colour (bilinear) and depth (nearest
neighbour, so no depth is invented across edges) with the published coefficients, keeping ``K``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from simn_sim.geometry.camera import Intrinsics
from simn_sim.tracking.lie import check_pose

TUM_DEPTH_FACTOR = 5000.0

# Published Freiburg calibrations (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats).
TUM_CAMERAS: dict[str, dict] = {
    "fr1": dict(fx=517.3, fy=516.5, cx=318.6, cy=255.3,
                distortion=[0.2624, -0.9531, -0.0054, 0.0026, 1.1633]),
    "fr2": dict(fx=520.9, fy=521.0, cx=325.1, cy=249.7,
                distortion=[0.2312, -0.7849, -0.0033, -0.0001, 0.9172]),
    "fr3": dict(fx=535.4, fy=539.2, cx=320.1, cy=247.6, distortion=[0.0, 0.0, 0.0, 0.0, 0.0]),
}  # fmt: skip


class TumFormatError(ValueError):
    """A TUM folder or file is missing, malformed, or cannot be associated."""


@dataclasses.dataclass(frozen=True)
class TumCamera:
    """Intrinsics, depth scale and (unused) distortion of a TUM sequence."""

    intrinsics: Intrinsics
    depth_factor: float = TUM_DEPTH_FACTOR
    distortion: tuple[float, ...] = ()


@dataclasses.dataclass(frozen=True)
class TumFrame:
    """One associated frame.

    timestamp: the rgb stamp (s). rgb: (H, W, 3) uint8 RGB. depth: (H, W) float32 metres, 0 =
    invalid. T_world_cam: (4, 4) float64 ground truth (OpenCV optical frame) or None.
    """

    timestamp: float
    depth_timestamp: float
    rgb: np.ndarray
    depth: np.ndarray
    T_world_cam: np.ndarray | None
    rgb_path: Path
    depth_path: Path


def associate(
    stamps_a: Sequence[float] | np.ndarray,
    stamps_b: Sequence[float] | np.ndarray,
    max_diff: float = 0.02,
    offset: float = 0.0,
) -> list[tuple[int, int]]:
    """Indices ``(i, j)`` of associated stamps, as TUM's ``associate.py``.

    Candidates are pairs with ``|a_i - (b_j + offset)| < max_diff``; they are accepted greedily by
    increasing difference, each index at most once. Result sorted by ``i``. O((n + m) log m).
    """
    a = np.asarray(stamps_a, dtype=np.float64).reshape(-1)
    b = np.asarray(stamps_b, dtype=np.float64).reshape(-1) + offset
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("timestamps must be finite")
    if max_diff <= 0:
        raise ValueError(f"max_diff must be > 0, got {max_diff}")
    if a.size == 0 or b.size == 0:
        return []
    order = np.argsort(b, kind="stable")
    bs = b[order]
    lo = np.searchsorted(bs, a - max_diff, side="left")
    hi = np.searchsorted(bs, a + max_diff, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(a.size), counts)
    if ia.size == 0:
        return []
    start = np.repeat(lo - np.cumsum(counts) + counts, counts)
    jb_sorted = np.arange(ia.size) + start
    jb = order[jb_sorted]
    diff = np.abs(a[ia] - b[jb])
    keep = diff < max_diff
    ia, jb, diff = ia[keep], jb[keep], diff[keep]
    sel = np.lexsort((jb, ia, diff))
    used_a = np.zeros(a.size, dtype=bool)
    used_b = np.zeros(b.size, dtype=bool)
    out = []
    for i, j in zip(ia[sel].tolist(), jb[sel].tolist(), strict=True):
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            out.append((i, j))
    out.sort()
    return out


def read_file_list(path: Path, n_values: int | None = None) -> tuple[np.ndarray, list[list[str]]]:
    """Parse a TUM list file: stamps (N,) float64 and the remaining fields of each line.

    ``n_values``: exact number of fields after the stamp (None: at least one). Comment (``#``)
    and blank lines are skipped; anything else malformed raises :class:`TumFormatError`.
    """
    path = Path(path)
    if not path.is_file():
        raise TumFormatError(f"missing file {path}")
    stamps, rest = [], []
    for k, line in enumerate(path.read_text().splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").replace("\t", " ").split()
        try:
            t = float(parts[0])
        except ValueError:
            raise TumFormatError(f"{path}:{k}: bad timestamp {parts[0]!r}") from None
        if not math.isfinite(t):
            raise TumFormatError(f"{path}:{k}: non-finite timestamp")
        fields = parts[1:]
        if (n_values is None and len(fields) < 1) or (
            n_values is not None and len(fields) != n_values
        ):
            want = "at least 1" if n_values is None else str(n_values)
            raise TumFormatError(f"{path}:{k}: expected {want} field(s) after the timestamp")
        stamps.append(t)
        rest.append(fields)
    return np.array(stamps, dtype=np.float64), rest


def pose_from_tum(values: Sequence[float]) -> np.ndarray:
    """``tx ty tz qx qy qz qw`` -> (4, 4) float64."""
    v = np.asarray(values, dtype=np.float64)
    q = v[3:7]
    n = np.linalg.norm(q)
    if not np.isfinite(v).all() or n < 1e-6:
        raise ValueError(f"invalid TUM pose {values}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q / n).as_matrix()
    T[:3, 3] = v[:3]
    return T


def pose_to_tum(T: np.ndarray) -> np.ndarray:
    """(4, 4) -> ``tx ty tz qx qy qz qw`` (7,)."""
    T = check_pose(T)
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_quat()])


def read_groundtruth(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (N,) and poses (N, 4, 4) from a TUM trajectory file."""
    stamps, rest = read_file_list(path, n_values=7)
    poses = np.empty((len(rest), 4, 4))
    for k, fields in enumerate(rest):
        try:
            poses[k] = pose_from_tum([float(x) for x in fields])
        except ValueError as e:
            raise TumFormatError(f"{path}: entry {k}: {e}") from None
    return stamps, poses


def _camera_from_dict(d: dict, source: str) -> TumCamera:
    try:
        intr = Intrinsics(
            int(d.get("width", 640)), int(d.get("height", 480)),
            float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
        )  # fmt: skip
        factor = float(d.get("depth_factor", TUM_DEPTH_FACTOR))
        dist = tuple(float(x) for x in d.get("distortion", ()) or ())
    except (KeyError, TypeError, ValueError) as e:
        raise TumFormatError(f"{source}: bad camera description ({e!r})") from None
    if not (math.isfinite(factor) and factor > 0):
        raise TumFormatError(f"{source}: depth_factor must be > 0, got {factor}")
    return TumCamera(intr, factor, dist)


def load_camera(spec: str | Path) -> TumCamera:
    """``"fr1" | "fr2" | "fr3"`` (published calibration, 640x480) or a path to a camera YAML."""
    if isinstance(spec, str) and spec.lower() in TUM_CAMERAS:
        return _camera_from_dict(TUM_CAMERAS[spec.lower()], spec)
    path = Path(spec)
    if not path.is_file():
        raise TumFormatError(
            f"camera {str(spec)!r} is neither one of {sorted(TUM_CAMERAS)} nor a YAML file"
        )
    try:
        d = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise TumFormatError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(d, dict):
        raise TumFormatError(f"{path}: expected a mapping with fx, fy, cx, cy")
    return _camera_from_dict(d, str(path))


def _same_camera(a: TumCamera, b: TumCamera) -> bool:
    ia, ib = a.intrinsics, b.intrinsics
    va = [ia.width, ia.height, ia.fx, ia.fy, ia.cx, ia.cy, a.depth_factor]
    vb = [ib.width, ib.height, ib.fx, ib.fy, ib.cx, ib.cy, b.depth_factor]
    return bool(np.allclose(va, vb, rtol=0, atol=1e-6))


def read_depth_png(path: Path, depth_factor: float = TUM_DEPTH_FACTOR) -> np.ndarray:
    """16-bit single-channel PNG -> (H, W) float32 metres (0 = invalid)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise TumFormatError(f"cannot read depth image {path}")
    if img.dtype != np.uint16 or img.ndim != 2:
        raise TumFormatError(
            f"depth image {path} is {img.dtype} with shape {img.shape}; "
            "expected a 16-bit single-channel PNG"
        )
    return img.astype(np.float32) / np.float32(depth_factor)


def read_rgb_png(path: Path) -> np.ndarray:
    """8-bit colour image -> (H, W, 3) uint8 RGB."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise TumFormatError(f"cannot read colour image {path}")
    if img.dtype != np.uint8:
        raise TumFormatError(f"colour image {path} is {img.dtype}; expected 8-bit")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(img[:, :, ::-1])


class TumSequence(Sequence[TumFrame]):
    """Associated frames of a TUM RGB-D folder; indexing/iteration loads images lazily.

    camera: ``"fr1" | "fr2" | "fr3"`` or a camera YAML path; needed unless the folder has a
    ``camera.yaml`` (when both are given they must agree). Missing calibration is an error.
    """

    def __init__(
        self,
        folder: str | Path,
        camera: str | Path | None = None,
        max_diff: float = 0.02,
        undistort: bool = False,
    ) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise TumFormatError(f"TUM folder {self.folder} does not exist")
        own = self.folder / "camera.yaml"
        cams = []
        if own.is_file():
            cams.append(load_camera(own))
        if camera is not None:
            cams.append(load_camera(camera))
        if not cams:
            raise TumFormatError(
                f"no calibration for {self.folder}: it has no camera.yaml; pass camera='fr1', "
                "'fr2', 'fr3' or a camera YAML path"
            )
        if len(cams) == 2 and not _same_camera(*cams):
            raise TumFormatError(f"camera {camera!r} disagrees with {own}")
        self.camera: TumCamera = cams[0]
        self.intrinsics: Intrinsics = self.camera.intrinsics
        self._maps = None
        if undistort and any(abs(d) > 0 for d in self.camera.distortion):
            intr = self.intrinsics
            self._maps = cv2.initUndistortRectifyMap(
                intr.K, np.asarray(self.camera.distortion, dtype=np.float64), None, intr.K,
                (intr.width, intr.height), cv2.CV_32FC1,
            )  # fmt: skip

        t_rgb, f_rgb = read_file_list(self.folder / "rgb.txt")
        t_dep, f_dep = read_file_list(self.folder / "depth.txt")
        pairs = associate(t_rgb, t_dep, max_diff)
        if not pairs:
            raise TumFormatError(
                f"{self.folder}: no rgb/depth stamps within {max_diff} s of each other "
                f"({len(t_rgb)} rgb, {len(t_dep)} depth)"
            )
        self.gt_stamps: np.ndarray | None = None
        self.gt_poses: np.ndarray | None = None
        gt_of: dict[int, int] = {}
        gt_file = self.folder / "groundtruth.txt"
        if gt_file.is_file():
            self.gt_stamps, self.gt_poses = read_groundtruth(gt_file)
            frame_t = t_rgb[[i for i, _ in pairs]]
            gt_of = dict(associate(frame_t, self.gt_stamps, max_diff))
        self._items = []
        for k, (i, j) in enumerate(pairs):
            rp, dp = self.folder / f_rgb[i][0], self.folder / f_dep[j][0]
            for p in (rp, dp):
                if not p.is_file():
                    raise TumFormatError(f"{self.folder}: listed image {p} does not exist")
            self._items.append((float(t_rgb[i]), float(t_dep[j]), rp, dp, gt_of.get(k)))

    def __len__(self) -> int:
        return len(self._items)

    @property
    def timestamps(self) -> np.ndarray:
        """(N,) frame (rgb) stamps."""
        return np.array([it[0] for it in self._items])

    def ground_truth(self, k: int) -> np.ndarray | None:
        g = self._items[k][4]
        return None if g is None or self.gt_poses is None else self.gt_poses[g].copy()

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        t, td, rp, dp, _ = self._items[k]
        rgb = read_rgb_png(rp)
        depth = read_depth_png(dp, self.camera.depth_factor)
        w, h = self.intrinsics.width, self.intrinsics.height
        for p, img in ((rp, rgb), (dp, depth)):
            if img.shape[:2] != (h, w):
                raise TumFormatError(f"image {p} is {img.shape[1]}x{img.shape[0]}, camera {w}x{h}")
        if self._maps is not None:
            m1, m2 = self._maps
            rgb = cv2.remap(rgb, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            depth = cv2.remap(depth, m1, m2, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
        return TumFrame(t, td, rgb, depth, self.ground_truth(k), rp, dp)

    def __iter__(self) -> Iterator[TumFrame]:
        for k in range(len(self)):
            yield self[k]


def read_tum(
    folder: str | Path,
    camera: str | Path | None = None,
    max_diff: float = 0.02,
    undistort: bool = False,
) -> TumSequence:
    """Open a TUM RGB-D folder; see :class:`TumSequence`."""
    return TumSequence(folder, camera, max_diff, undistort)


class TumWriter:
    """Write frames as a TUM RGB-D folder (plus ``camera.yaml``).

    ``add(timestamp, rgb (H, W, 3) uint8 RGB, depth (H, W) float32 metres, T_world_cam (4, 4))``
    writes ``rgb/<t>.png``, ``depth/<t>.png`` (uint16 = round(depth * depth_factor), 0 for
    invalid/non-finite/non-positive depth) and appends to ``rgb.txt``, ``depth.txt``,
    ``groundtruth.txt`` (flushed per frame). Stamps must increase.
    """

    def __init__(
        self,
        folder: str | Path,
        intrinsics: Intrinsics,
        depth_factor: float = TUM_DEPTH_FACTOR,
        overwrite: bool = False,
    ) -> None:
        self.folder = Path(folder)
        self.intrinsics = intrinsics
        if not (math.isfinite(depth_factor) and depth_factor > 0):
            raise ValueError(f"depth_factor must be > 0, got {depth_factor}")
        self.depth_factor = float(depth_factor)
        if (self.folder / "rgb.txt").exists() and not overwrite:
            raise FileExistsError(f"{self.folder} already holds a TUM sequence (overwrite=False)")
        (self.folder / "rgb").mkdir(parents=True, exist_ok=True)
        (self.folder / "depth").mkdir(parents=True, exist_ok=True)
        cam = dict(dataclasses.asdict(intrinsics), depth_factor=self.depth_factor)
        (self.folder / "camera.yaml").write_text(yaml.safe_dump(cam, sort_keys=False))
        hdr = "# written by simn_sim.io.tum.TumWriter\n"
        for name, cols in (
            ("rgb.txt", "timestamp filename"),
            ("depth.txt", "timestamp filename"),
            ("groundtruth.txt", "timestamp tx ty tz qx qy qz qw"),
        ):
            (self.folder / name).write_text(f"# {name[:-4]}\n{hdr}# {cols}\n")
        self._last = -math.inf
        self.n_frames = 0

    def add(self, timestamp: float, rgb: np.ndarray, depth: np.ndarray, T_world_cam: np.ndarray):
        t = float(timestamp)
        if not math.isfinite(t) or t <= self._last:
            raise ValueError(
                f"timestamps must be finite and increasing, got {t} after {self._last}"
            )
        h, w = self.intrinsics.height, self.intrinsics.width
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.shape != (h, w, 3):
            raise ValueError(f"rgb must be uint8 ({h}, {w}, 3), got {rgb.dtype} {rgb.shape}")
        depth = np.asarray(depth)
        if depth.shape != (h, w) or not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(
                f"depth must be float ({h}, {w}) metres, got {depth.dtype} {depth.shape}"
            )
        T = check_pose(T_world_cam, "T_world_cam")
        d = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float64)
        q = np.round(d * self.depth_factor)
        if q.max(initial=0) > 65535:
            raise ValueError(
                f"depth {d.max():.3f} m exceeds the 16-bit range at factor {self.depth_factor}"
            )
        name = f"{t:.6f}.png"
        if not cv2.imwrite(str(self.folder / "rgb" / name), np.ascontiguousarray(rgb[:, :, ::-1])):
            raise OSError(f"could not write {self.folder / 'rgb' / name}")
        if not cv2.imwrite(str(self.folder / "depth" / name), q.astype(np.uint16)):
            raise OSError(f"could not write {self.folder / 'depth' / name}")
        with open(self.folder / "rgb.txt", "a") as f:
            f.write(f"{t:.6f} rgb/{name}\n")
        with open(self.folder / "depth.txt", "a") as f:
            f.write(f"{t:.6f} depth/{name}\n")
        with open(self.folder / "groundtruth.txt", "a") as f:
            f.write(f"{t:.6f} " + " ".join(f"{x:.9f}" for x in pose_to_tum(T)) + "\n")
        self._last = t
        self.n_frames += 1

    def __enter__(self) -> TumWriter:
        return self

    def __exit__(self, *exc) -> None:
        return None
