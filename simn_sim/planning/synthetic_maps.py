"""Synthetic labelled point maps for planner tests and benchmarks (world x-y-z metres, z up).

Walls and boxes are sampled as vertical point sheets (spacing ``spacing``) from the floor to
``height`` and labelled obstacle (1); a sparse floor (label 0) is added so label filtering is
exercised. Each map also returns its obstacle footprints as shapely polygons (the exact geometry
the points were sampled from) for exact shortest-path references.
"""

from __future__ import annotations

import dataclasses

import numpy as np

FLOOR = 0
OBSTACLE = 1


@dataclasses.dataclass
class PointMap:
    """A labelled point map with its ground-truth footprints."""

    points: np.ndarray
    """(N, 3) float32 world points."""
    labels: np.ndarray
    """(N,) int labels: FLOOR or OBSTACLE."""
    footprints: list
    """Shapely polygons of the obstacle footprints (x-y)."""
    bounds: tuple[float, float, float, float]
    """(xmin, ymin, xmax, ymax) of the mapped area."""


def _segment_sheet(a, b, spacing: float, height: float) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(int(np.ceil(np.hypot(*(b - a)) / spacing)) + 1, 2)
    t = np.linspace(0.0, 1.0, n)
    xy = a + (b - a) * t[:, None]
    z = np.arange(spacing * 0.5, height, spacing * 2)
    return np.concatenate([np.column_stack([xy, np.full(n, zz)]) for zz in z])


def _rect_outline(x0, y0, x1, y1, spacing, height) -> np.ndarray:
    c = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
    return np.concatenate([_segment_sheet(c[i], c[i + 1], spacing, height) for i in range(4)])


def build_map(
    walls: list[tuple[tuple[float, float], tuple[float, float]]],
    boxes: list[tuple[float, float, float, float]],
    bounds: tuple[float, float, float, float],
    spacing: float = 0.04,
    height: float = 1.0,
    floor_spacing: float = 0.5,
) -> PointMap:
    """Walls as segments ((x0, y0), (x1, y1)) and boxes as (xmin, ymin, xmax, ymax)."""
    from shapely.geometry import LineString, box

    pts = [_segment_sheet(a, b, spacing, height) for a, b in walls]
    pts += [_rect_outline(*bx, spacing, height) for bx in boxes]
    obst = np.concatenate(pts) if pts else np.zeros((0, 3))
    gx, gy = np.meshgrid(
        np.arange(bounds[0], bounds[2], floor_spacing),
        np.arange(bounds[1], bounds[3], floor_spacing),
    )
    floor = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    points = np.concatenate([obst, floor]).astype(np.float32)
    labels = np.concatenate([np.full(len(obst), OBSTACLE), np.full(len(floor), FLOOR)])
    foot = [LineString([a, b]) for a, b in walls] + [box(*bx) for bx in boxes]
    return PointMap(points, labels, foot, bounds)


def doorway_map(door_width: float = 1.0) -> PointMap:
    """A 10 x 6 m room split by a wall at x = 5 with a doorway centred at y = 4."""
    y0, y1 = 4.0 - door_width / 2, 4.0 + door_width / 2
    walls = [((5.0, 0.0), (5.0, y0)), ((5.0, y1), (5.0, 6.0))]
    walls += [((0, 0), (10, 0)), ((10, 0), (10, 6)), ((10, 6), (0, 6)), ((0, 6), (0, 0))]
    return build_map(walls, [], (0.0, 0.0, 10.0, 6.0))


def u_trap_map() -> PointMap:
    """A U-shaped trap open towards -x around (5, 3); the goal lies behind it at x > 6.5."""
    walls = [((4.0, 1.5), (6.0, 1.5)), ((6.0, 1.5), (6.0, 4.5)), ((6.0, 4.5), (4.0, 4.5))]
    walls += [((0, 0), (10, 0)), ((10, 0), (10, 6)), ((10, 6), (0, 6)), ((0, 6), (0, 0))]
    return build_map(walls, [], (0.0, 0.0, 10.0, 6.0))


def box_field_map(rng: np.random.Generator, n_boxes: int = 12) -> PointMap:
    """10 x 8 m area with random boxes (0.4-1.0 m) away from x < 1.5 and x > 8.5."""
    boxes = []
    while len(boxes) < n_boxes:
        w, h = rng.uniform(0.4, 1.0, size=2)
        x, y = rng.uniform([1.5, 0.5], [8.5 - w, 7.5 - h])
        cand = (x, y, x + w, y + h)
        if all(
            cand[0] > b[2] + 0.8
            or cand[2] < b[0] - 0.8
            or cand[1] > b[3] + 0.8
            or cand[3] < b[1] - 0.8
            for b in boxes
        ):
            boxes.append(cand)
    walls = [((0, 0), (10, 0)), ((10, 0), (10, 8)), ((10, 8), (0, 8)), ((0, 8), (0, 0))]
    return build_map(walls, boxes, (0.0, 0.0, 10.0, 8.0))


def office_map(
    rng: np.random.Generator,
    nx: int = 3,
    ny: int = 2,
    room: float = 4.0,
    corridor: float = 2.0,
    door: float = 1.0,
    furniture: int = 2,
) -> PointMap:
    """Office-like layout: rows of rooms (``room`` m square) above and below a horizontal
    corridor, each room with a doorway onto the corridor at a random position and a few
    random furniture boxes. ``ny`` is 1 (rooms below only) or 2."""
    W = nx * room
    H = ny * room + corridor
    walls: list = [((0, 0), (W, 0)), ((W, 0), (W, H)), ((W, H), (0, H)), ((0, H), (0, 0))]
    boxes: list = []
    rows = [(0.0, room, room)]  # (y0, y1, corridor-side y)
    if ny == 2:
        rows.append((room + corridor, H, room + corridor))
    for y0, y1, yc in rows:
        for i in range(nx):
            x0, x1 = i * room, (i + 1) * room
            if i > 0:
                walls.append(((x0, y0), (x0, y1)))
            dx = rng.uniform(x0 + 0.4, x1 - 0.4 - door)
            walls += [((x0, yc), (dx, yc)), ((dx + door, yc), (x1, yc))]
            for _ in range(furniture):
                w, h = rng.uniform(0.5, 1.2, size=2)
                for _try in range(20):
                    bx = rng.uniform(x0 + 0.2, x1 - 0.2 - w)
                    by = rng.uniform(y0 + 0.2, y1 - 0.2 - h)
                    b = (bx, by, bx + w, by + h)
                    # keep 1.2 m in front of the doorway clear
                    if (
                        b[2] < dx - 0.6
                        or b[0] > dx + door + 0.6
                        or min(abs(b[1] - yc), abs(b[3] - yc)) > 1.5
                    ):
                        boxes.append(b)
                        break
    return build_map(walls, boxes, (0.0, 0.0, W, H))
