"""Synthetic labelled point maps for planner tests and benchmarks (world x-y-z metres, z up).

Walls and boxes are sampled as vertical point sheets (spacing ``spacing``) from the floor to
``height`` and labelled ``simn_sim.semantics.OBSTACLE``; a sparse floor (``FLOOR``) is added so
label filtering is exercised. Each map also returns its obstacle footprints as shapely polygons (the exact geometry
the points were sampled from) for exact shortest-path references.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import networkx
import numpy as np

from simn_sim.semantics import FLOOR, OBSTACLE  # labels shared with the mapper


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
    graph: networkx.Graph | None = None
    """Topological map analogue (office maps): nodes with ``anchor_xy`` and ``region``
    (xmin, ymin, xmax, ymax), edges with ``weight`` (anchor distance)."""

    def node_at(self, xy: np.ndarray) -> Any:
        """The graph node whose region contains xy (None if none or no graph)."""
        if self.graph is None:
            return None
        x, y = float(xy[0]), float(xy[1])
        best, best_d = None, np.inf
        for n, data in self.graph.nodes(data=True):
            x0, y0, x1, y1 = data["region"]
            if x0 <= x <= x1 and y0 <= y <= y1:
                d = float(np.hypot(*(np.asarray(data["anchor_xy"]) - (x, y))))
                if d < best_d:
                    best, best_d = n, d
        return best


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
    random furniture boxes. ``ny`` is 1 (rooms below only) or 2.

    The returned map has a topological graph: one node per room (anchor 0.8 m inside its
    doorway, region = the room) and one per doorway in the corridor (anchor on the corridor's
    centre line, region = the corridor slice up to the neighbouring doorways), room -- corridor
    edges through each doorway and corridor -- corridor edges along the corridor."""
    W = nx * room
    H = ny * room + corridor
    walls: list = [((0, 0), (W, 0)), ((W, 0), (W, H)), ((W, H), (0, H)), ((0, H), (0, 0))]
    boxes: list = []
    rows = [(0.0, room, room, 1.0)]  # (y0, y1, corridor-side y, direction into the corridor)
    if ny == 2:
        rows.append((room + corridor, H, room + corridor, -1.0))
    g = networkx.Graph()
    y_mid = room + corridor / 2
    door_x = []
    for r_i, (y0, y1, yc, sgn) in enumerate(rows):
        for i in range(nx):
            x0, x1 = i * room, (i + 1) * room
            if i > 0:
                walls.append(((x0, y0), (x0, y1)))
            dx = rng.uniform(x0 + 0.4, x1 - 0.4 - door)
            walls += [((x0, yc), (dx, yc)), ((dx + door, yc), (x1, yc))]
            cx = dx + door / 2
            g.add_node(
                ("room", r_i, i), anchor_xy=np.array([cx, yc - sgn * 0.8]), region=(x0, y0, x1, y1)
            )
            g.add_node(("door", r_i, i), anchor_xy=np.array([cx, y_mid]))
            g.add_edge(("room", r_i, i), ("door", r_i, i), weight=0.8 + corridor / 2)
            door_x.append((cx, ("door", r_i, i)))
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
    door_x.sort()
    xs = [x for x, _ in door_x]
    for k, (x, node) in enumerate(door_x):
        lo = 0.0 if k == 0 else 0.5 * (xs[k - 1] + x)
        hi = W if k == len(xs) - 1 else 0.5 * (x + xs[k + 1])
        g.nodes[node]["region"] = (lo, room, hi, room + corridor)
        if k > 0:
            g.add_edge(door_x[k - 1][1], node, weight=x - xs[k - 1])
    m = build_map(walls, boxes, (0.0, 0.0, W, H))
    m.graph = g
    return m


def open_office_map(
    rng: np.random.Generator,
    width: float = 30.0,
    height: float = 20.0,
    n_clusters: int = 14,
    n_pillars: int = 8,
    n_partitions: int = 5,
) -> PointMap:
    """Open-plan office hall: desk clusters (2 x 2 desks of 1.4 x 0.7 m, random orientation),
    pillars (0.4 m), and free-standing partition walls (2-4 m), kept >= 1.0 m apart."""
    boxes: list = []
    walls: list = [
        ((0, 0), (width, 0)),
        ((width, 0), (width, height)),
        ((width, height), (0, height)),
        ((0, height), (0, 0)),
    ]

    def clear(b, gap: float) -> bool:
        return all(
            b[0] > o[2] + gap or b[2] < o[0] - gap or b[1] > o[3] + gap or b[3] < o[1] - gap
            for o in boxes
        )

    for _ in range(n_clusters):
        for _try in range(50):
            w, h = (2.8, 1.4) if rng.random() < 0.5 else (1.4, 2.8)
            x, y = rng.uniform([1.0, 1.0], [width - 1.0 - w, height - 1.0 - h])
            b = (x, y, x + w, y + h)
            if clear(b, 1.2):
                boxes.append(b)
                break
    for _ in range(n_pillars):
        for _try in range(50):
            x, y = rng.uniform([1.5, 1.5], [width - 1.9, height - 1.9])
            b = (x, y, x + 0.4, y + 0.4)
            if clear(b, 1.0):
                boxes.append(b)
                break
    for _ in range(n_partitions):
        for _try in range(50):
            L = rng.uniform(2.0, 4.0)
            x, y = rng.uniform([1.5, 1.5], [width - 1.5, height - 1.5])
            if rng.random() < 0.5:
                a, b_ = (x, y), (min(x + L, width - 1.5), y)
            else:
                a, b_ = (x, y), (x, min(y + L, height - 1.5))
            bb = (min(a[0], b_[0]), min(a[1], b_[1]), max(a[0], b_[0]), max(a[1], b_[1]))
            if clear(bb, 1.0):
                walls.append((a, b_))
                boxes.append(bb)  # reserve its footprint for the spacing test
                break
    # partitions were reserved as degenerate boxes; keep only the real boxes as boxes
    real = [b for b in boxes if b[2] - b[0] > 1e-9 and b[3] - b[1] > 1e-9]
    return build_map(walls, real, (0.0, 0.0, width, height))
