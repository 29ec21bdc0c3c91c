"""Procedural office layouts as plain data.

A :class:`Layout` is a list of boxes (walls and furniture parts) plus the rooms and doorways that
produced them. It is generated from a ``layout_seed`` by :func:`generate_layout` and can be saved
to / loaded from JSON (``envs/office_reference.json`` is the fixed reference office). The MuJoCo
scene is built from a layout by :mod:`simn_sim.env.scene`; the exact 2-D free space (for geodesic
distances and start/goal sampling) from :meth:`Layout.footprints`.

World frame: x east, y north, z up, metres. The floor is z = 0.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull

LAYOUT_FORMAT = "simn-sim-layout/1"

WALL_THICKNESS = 0.15
WALL_HEIGHT = 2.6


@dataclasses.dataclass(frozen=True)
class Box:
    """An axis-aligned box rotated by ``yaw`` about z. ``half`` are half extents (m)."""

    name: str
    kind: str  # wall | desk | table | chair | shelf | cabinet | box
    item: int  # furniture item id (-1 for walls): the boxes of one item share it
    center: tuple[float, float, float]
    half: tuple[float, float, float]
    yaw: float
    rgba: tuple[float, float, float, float]

    @property
    def z_range(self) -> tuple[float, float]:
        return self.center[2] - self.half[2], self.center[2] + self.half[2]

    def corners_xy(self) -> np.ndarray:
        """(4, 2) footprint corners in the world x-y plane."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hx, hy = self.half[0], self.half[1]
        local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
        R = np.array([[c, -s], [s, c]])
        return local @ R.T + np.array(self.center[:2])


@dataclasses.dataclass(frozen=True)
class Room:
    name: str
    xmin: float
    ymin: float
    xmax: float
    ymax: float


@dataclasses.dataclass(frozen=True)
class Door:
    """A doorway: the gap centre and its width, in a wall along ``axis`` ('x' or 'y')."""

    center: tuple[float, float]
    width: float
    axis: str


@dataclasses.dataclass
class Layout:
    layout_seed: int
    size: tuple[float, float]  # (width along x, depth along y); the office spans [0,W]x[0,H]
    rooms: list[Room]
    doors: list[Door]
    boxes: list[Box]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return (0.0, 0.0, float(self.size[0]), float(self.size[1]))

    def footprints(self, z_band: tuple[float, float]) -> list[np.ndarray]:
        """Footprint polygons ((K, 2) arrays) of everything that blocks a body spanning ``z_band``.

        Walls give one rectangle each; a furniture item gives the convex hull of its boxes that
        overlap the band (a table's top covers its legs, a chair's seat its legs).
        """
        lo, hi = z_band
        items: dict[int, list[np.ndarray]] = {}
        out: list[np.ndarray] = []
        for b in self.boxes:
            z0, z1 = b.z_range
            if z1 < lo or z0 > hi:
                continue
            if b.item < 0:
                out.append(b.corners_xy())
            else:
                items.setdefault(b.item, []).append(b.corners_xy())
        for pts in items.values():
            allp = np.concatenate(pts)
            hull = ConvexHull(allp)
            out.append(allp[hull.vertices])
        return out

    # ---- serialisation -------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": LAYOUT_FORMAT,
            "layout_seed": self.layout_seed,
            "size": list(self.size),
            "rooms": [dataclasses.asdict(r) for r in self.rooms],
            "doors": [dataclasses.asdict(d) for d in self.doors],
            "boxes": [dataclasses.asdict(b) for b in self.boxes],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "<dict>") -> Layout:
        if not isinstance(d, dict) or d.get("format") != LAYOUT_FORMAT:
            raise ValueError(f"{source}: not a simn-sim layout (expected format '{LAYOUT_FORMAT}')")
        try:
            return cls(
                layout_seed=int(d["layout_seed"]),
                size=(float(d["size"][0]), float(d["size"][1])),
                rooms=[Room(**r) for r in d["rooms"]],
                doors=[
                    Door(center=tuple(x["center"]), width=float(x["width"]), axis=x["axis"])
                    for x in d["doors"]
                ],
                boxes=[
                    Box(
                        name=b["name"],
                        kind=b["kind"],
                        item=int(b["item"]),
                        center=tuple(float(v) for v in b["center"]),
                        half=tuple(float(v) for v in b["half"]),
                        yaw=float(b["yaw"]),
                        rgba=tuple(float(v) for v in b["rgba"]),
                    )
                    for b in d["boxes"]
                ],
            )
        except (KeyError, TypeError, IndexError) as e:
            raise ValueError(f"{source}: corrupt layout file ({type(e).__name__}: {e})") from e

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> Layout:
        p = Path(path)
        try:
            d = json.loads(p.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{p}: corrupt layout file (invalid JSON: {e})") from e
        return cls.from_dict(d, source=str(p))


# ---- generation ---------------------------------------------------------------------------

_PALETTE = np.array(
    [
        [0.80, 0.36, 0.25],
        [0.25, 0.45, 0.75],
        [0.30, 0.62, 0.35],
        [0.85, 0.72, 0.30],
        [0.55, 0.35, 0.65],
        [0.20, 0.65, 0.65],
        [0.60, 0.45, 0.30],
        [0.70, 0.70, 0.72],
        [0.90, 0.55, 0.60],
        [0.35, 0.35, 0.40],
    ]
)
_WALL_COLOURS = np.array(
    [[0.93, 0.90, 0.82], [0.82, 0.88, 0.93], [0.88, 0.93, 0.84], [0.95, 0.86, 0.80]]
)


def _rgba(c: np.ndarray) -> tuple[float, float, float, float]:
    return (float(c[0]), float(c[1]), float(c[2]), 1.0)


def _split(lo: float, hi: float, n: int, min_w: float, rng: np.random.Generator) -> list[float]:
    """Split [lo, hi] into n parts each at least min_w wide; returns the n+1 edges."""
    free = (hi - lo) - n * min_w
    w = rng.dirichlet(np.full(n, 3.0)) * free + min_w
    edges = [lo]
    for x in w:
        edges.append(edges[-1] + float(x))
    edges[-1] = hi
    return edges


def _wall_with_doors(
    axis: str, fixed: float, lo: float, hi: float, gaps: list[tuple[float, float]], rgba, name: str
) -> list[Box]:
    """Wall segments along ``axis`` at coordinate ``fixed`` from lo to hi, minus door gaps."""
    pieces = []
    cur = lo
    for g0, g1 in sorted(gaps):
        if g0 > cur:
            pieces.append((cur, g0))
        cur = max(cur, g1)
    if hi > cur:
        pieces.append((cur, hi))
    out = []
    t = WALL_THICKNESS / 2
    for i, (a, b) in enumerate(pieces):
        if b - a < 1e-3:
            continue
        m, h = (a + b) / 2, (b - a) / 2
        if axis == "x":
            center, half = (m, fixed, WALL_HEIGHT / 2), (h + t, t, WALL_HEIGHT / 2)
        else:
            center, half = (fixed, m, WALL_HEIGHT / 2), (t, h + t, WALL_HEIGHT / 2)
        out.append(Box(f"{name}_{i}", "wall", -1, center, half, 0.0, rgba))
    return out


def _furniture(kind: str, item: int, x: float, y: float, yaw: float, rng) -> list[Box]:
    """The boxes of one furniture item centred at (x, y) with heading ``yaw``."""
    col = _rgba(_PALETTE[rng.integers(len(_PALETTE))])
    wood = _rgba(np.array([0.55, 0.40, 0.25]) * rng.uniform(0.8, 1.2))
    metal = _rgba(np.array([0.45, 0.45, 0.48]))
    c, s = math.cos(yaw), math.sin(yaw)

    def at(dx, dy, z, half, rgba, part):
        return Box(
            f"{kind}{item}_{part}",
            kind,
            item,
            (x + c * dx - s * dy, y + s * dx + c * dy, z),
            half,
            yaw,
            rgba,
        )

    boxes: list[Box] = []
    if kind in ("desk", "table"):
        if kind == "desk":
            hx, hy, h = rng.uniform(0.6, 0.8), rng.uniform(0.33, 0.4), 0.75
        else:
            hx, hy, h = rng.uniform(0.5, 0.9), rng.uniform(0.45, 0.6), rng.uniform(0.7, 0.76)
        boxes.append(at(0, 0, h - 0.02, (hx, hy, 0.02), wood, "top"))
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
            boxes.append(
                at(
                    sx * (hx - 0.05),
                    sy * (hy - 0.05),
                    (h - 0.04) / 2,
                    (0.025, 0.025, (h - 0.04) / 2),
                    metal,
                    f"leg{i}",
                )
            )
        if kind == "desk" and rng.random() < 0.6:  # a monitor
            boxes.append(
                at(
                    0,
                    hy * 0.5,
                    h + 0.2,
                    (0.25, 0.02, 0.16),
                    _rgba(np.array([0.1, 0.1, 0.12])),
                    "monitor",
                )
            )
    elif kind == "chair":
        hs, hseat = 0.22, 0.45
        boxes.append(at(0, 0, hseat, (hs, hs, 0.025), col, "seat"))
        boxes.append(at(-hs + 0.025, 0, hseat + 0.25, (0.025, hs, 0.23), col, "back"))
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
            boxes.append(
                at(
                    sx * (hs - 0.03),
                    sy * (hs - 0.03),
                    hseat / 2,
                    (0.02, 0.02, hseat / 2),
                    metal,
                    f"leg{i}",
                )
            )
    elif kind == "shelf":
        hx, hy, h = rng.uniform(0.4, 0.6), 0.18, rng.uniform(1.5, 2.0)
        boxes.append(at(hx - 0.015, 0, h / 2, (0.015, hy, h / 2), wood, "side0"))
        boxes.append(at(-hx + 0.015, 0, h / 2, (0.015, hy, h / 2), wood, "side1"))
        boxes.append(at(0, -hy + 0.01, h / 2, (hx, 0.01, h / 2), wood, "backp"))
        n = 4
        for i in range(n + 1):
            boxes.append(at(0, 0, 0.02 + i * (h - 0.04) / n, (hx, hy, 0.015), wood, f"board{i}"))
        for i in range(n):  # books
            bc = _rgba(_PALETTE[rng.integers(len(_PALETTE))])
            boxes.append(
                at(
                    rng.uniform(-0.2, 0.2) * hx,
                    0,
                    0.04 + i * (h - 0.04) / n + 0.11,
                    (hx * 0.5, hy * 0.7, 0.1),
                    bc,
                    f"books{i}",
                )
            )
    elif kind == "cabinet":
        hx, hy, h = rng.uniform(0.3, 0.45), rng.uniform(0.25, 0.3), rng.uniform(0.8, 1.3)
        boxes.append(at(0, 0, h / 2, (hx, hy, h / 2), col, "body"))
    elif kind == "box":
        hx, hy, h = rng.uniform(0.15, 0.3), rng.uniform(0.15, 0.3), rng.uniform(0.15, 0.4)
        boxes.append(
            at(
                0,
                0,
                h / 2,
                (hx, hy, h / 2),
                _rgba(np.array([0.72, 0.56, 0.36]) * rng.uniform(0.85, 1.1)),
                "body",
            )
        )
    else:
        raise ValueError(f"unknown furniture kind '{kind}'")
    return boxes


class _Raster:
    """Coarse occupancy raster used while placing furniture, to keep free space connected."""

    def __init__(self, size: tuple[float, float], res: float = 0.1):
        self.res = res
        self.shape = (int(math.ceil(size[1] / res)), int(math.ceil(size[0] / res)))
        self.occ = np.zeros(self.shape, bool)
        yy, xx = np.mgrid[: self.shape[0], : self.shape[1]]
        self.cx = (xx + 0.5) * res
        self.cy = (yy + 0.5) * res

    def mask_of(self, poly: np.ndarray, inflate: float) -> np.ndarray:
        """Cells whose centre lies within ``inflate`` of the convex polygon ``poly`` (CCW or CW)."""
        x0, y0 = poly.min(0) - inflate
        x1, y1 = poly.max(0) + inflate
        sel = (self.cx >= x0) & (self.cx <= x1) & (self.cy >= y0) & (self.cy <= y1)
        m = np.zeros(self.shape, bool)
        if not sel.any():
            return m
        px, py = self.cx[sel], self.cy[sel]
        # signed distance to a convex polygon: max over edge half-planes (outward normals)
        ctr = poly.mean(0)
        d = np.full(px.shape, -np.inf)
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            e = b - a
            n = np.array([e[1], -e[0]]) / np.hypot(*e)
            if np.dot(ctr - a, n) > 0:
                n = -n
            d = np.maximum(d, (px - a[0]) * n[0] + (py - a[1]) * n[1])
        m[sel] = d <= inflate
        return m


def generate_layout(layout_seed: int, size: tuple[float, float] | None = None) -> Layout:
    """Generate an office: a corridor, 4-6 rooms with doorways, and furniture in every room.

    Deterministic for a given ``layout_seed`` (numpy PCG64).
    """
    if not isinstance(layout_seed, (int, np.integer)) or layout_seed < 0:
        raise ValueError(f"layout_seed must be a non-negative integer, got {layout_seed!r}")
    rng = np.random.default_rng([int(layout_seed), 0x51A7])
    if size is None:
        W = float(np.round(rng.uniform(22.0, 26.0), 1))
        H = float(np.round(rng.uniform(14.0, 17.0), 1))
    else:
        W, H = float(size[0]), float(size[1])
        if W < 20.0 or H < 14.0:
            raise ValueError(f"office size must be at least 20 x 14 m, got {W} x {H}")
    cw = float(rng.uniform(1.8, 2.4))  # corridor width
    yc = float(H / 2 + rng.uniform(-1.0, 1.0))
    y_lo, y_hi = yc - cw / 2, yc + cw / 2
    wall_rgba = _rgba(_WALL_COLOURS[rng.integers(len(_WALL_COLOURS))])
    boxes: list[Box] = []
    rooms: list[Room] = []
    doors: list[Door] = []
    # outer walls
    boxes += _wall_with_doors("x", 0.0, 0.0, W, [], wall_rgba, "outer_s")
    boxes += _wall_with_doors("x", H, 0.0, W, [], wall_rgba, "outer_n")
    boxes += _wall_with_doors("y", 0.0, 0.0, H, [], wall_rgba, "outer_w")
    boxes += _wall_with_doors("y", W, 0.0, H, [], wall_rgba, "outer_e")
    corridor_gaps: dict[str, list[tuple[float, float]]] = {"s": [], "n": []}
    for row, (r0, r1) in (("s", (0.0, y_lo)), ("n", (y_hi, H))):
        n_rooms = int(rng.integers(2, 4))
        edges = _split(0.0, W, n_rooms, 5.0, rng)
        room_rgba = _rgba(_WALL_COLOURS[rng.integers(len(_WALL_COLOURS))] * rng.uniform(0.9, 1.0))
        for i in range(n_rooms):
            a, b = edges[i], edges[i + 1]
            rooms.append(Room(f"room_{row}{i}", a, r0, b, r1))
            dw = float(rng.uniform(1.0, 1.3))
            dc = float(rng.uniform(a + 0.6 + dw / 2, b - 0.6 - dw / 2))
            corridor_gaps[row].append((dc - dw / 2, dc + dw / 2))
            doors.append(Door((dc, y_lo if row == "s" else y_hi), dw, "x"))
            if i > 0:  # wall between rooms, sometimes with a connecting door
                gaps = []
                if rng.random() < 0.5:
                    dw2 = float(rng.uniform(0.95, 1.2))
                    dc2 = float(rng.uniform(r0 + 0.6 + dw2 / 2, r1 - 0.6 - dw2 / 2))
                    gaps.append((dc2 - dw2 / 2, dc2 + dw2 / 2))
                    doors.append(Door((a, dc2), dw2, "y"))
                boxes += _wall_with_doors("y", a, r0, r1, gaps, room_rgba, f"part_{row}{i}")
    boxes += _wall_with_doors("x", y_lo, 0.0, W, corridor_gaps["s"], wall_rgba, "corr_s")
    boxes += _wall_with_doors("x", y_hi, 0.0, W, corridor_gaps["n"], wall_rgba, "corr_n")

    # furniture, placed by rejection sampling on a coarse raster that keeps free space connected
    raster = _Raster((W, H))
    for b in boxes:
        raster.occ |= raster.mask_of(b.corners_xy(), 0.0)
    clear_r = 0.32  # robot radius + margin: free space must stay connected for this disc
    keepout = np.zeros(raster.shape, bool)
    for d in doors:
        r = d.width / 2 + 0.9
        keepout |= np.hypot(raster.cx - d.center[0], raster.cy - d.center[1]) < r
    dil = int(math.ceil(clear_r / raster.res))
    n_free0 = ndimage.label(~ndimage.binary_dilation(raster.occ, iterations=dil))[1]
    item = 0
    kinds = ["desk", "desk", "table", "chair", "chair", "shelf", "shelf", "cabinet", "box"]
    for room in rooms:
        area = (room.xmax - room.xmin) * (room.ymax - room.ymin)
        target = int(area / 3.0)
        tries = 0
        placed = 0
        while placed < target and tries < target * 15:
            tries += 1
            kind = kinds[rng.integers(len(kinds))]
            m = 0.45
            x = float(rng.uniform(room.xmin + m, room.xmax - m))
            y = float(rng.uniform(room.ymin + m, room.ymax - m))
            if kind in ("shelf", "cabinet") and rng.random() < 0.8:
                # against a wall, facing into the room
                side = int(rng.integers(4))
                if side == 0:
                    y, yaw = room.ymin + 0.3, math.pi / 2
                elif side == 1:
                    y, yaw = room.ymax - 0.3, -math.pi / 2
                elif side == 2:
                    x, yaw = room.xmin + 0.3, 0.0
                else:
                    x, yaw = room.xmax - 0.3, math.pi
            elif kind == "chair":
                yaw = float(rng.uniform(-math.pi, math.pi))
            else:
                yaw = float(rng.integers(4)) * math.pi / 2 + float(rng.normal(0, 0.05))
            parts = _furniture(kind, item, x, y, yaw, rng)
            pts = np.concatenate([p.corners_xy() for p in parts])
            poly = pts[ConvexHull(pts).vertices]
            if (
                poly[:, 0].min() < room.xmin + WALL_THICKNESS / 2 + 0.02
                or poly[:, 0].max() > room.xmax - WALL_THICKNESS / 2 - 0.02
                or poly[:, 1].min() < room.ymin + WALL_THICKNESS / 2 + 0.02
                or poly[:, 1].max() > room.ymax - WALL_THICKNESS / 2 - 0.02
            ):
                continue
            fp = raster.mask_of(poly, 0.05)
            if (fp & (raster.occ | keepout)).any():
                continue
            # connectivity: free cells for the robot disc must stay one component
            occ2 = raster.occ | fp
            free = ~ndimage.binary_dilation(occ2, iterations=dil)
            if ndimage.label(free)[1] > n_free0:
                continue
            raster.occ = occ2
            boxes += parts
            item += 1
            placed += 1
    return Layout(int(layout_seed), (W, H), rooms, doors, boxes)
