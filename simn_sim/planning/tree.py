"""Inspectable planning tree (nodes, parents, costs, children) with a spatial index.

The nearest-neighbour index is log-structured: a static ``scipy.spatial.cKDTree`` over most
nodes plus a small buffer of recent nodes (at most a quarter of the tree) that is searched
vectorised; the KD-tree is rebuilt when the buffer fills, so rebuilds happen at geometrically
spaced sizes (amortised O(log n) per insert) and no query scans the whole tree.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree


class NodeIndex:
    """Incremental nearest / radius queries over 2-D points (planning frame x-y metres)."""

    def __init__(self, min_buffer: int = 64, buffer_fraction: float = 0.25) -> None:
        self.min_buffer = min_buffer
        self.buffer_fraction = buffer_fraction
        self._pts = np.zeros((0, 2))
        self._n = 0
        self._kd: cKDTree | None = None
        self._n_static = 0
        self.rebuilds = 0

    def reset(self, pts: np.ndarray) -> None:
        """Point the index at the tree's (capacity, 2) node storage (first n rows valid)."""
        self._pts = pts
        self._n = 0
        self._kd = None
        self._n_static = 0

    def add(self, pts: np.ndarray, n: int) -> None:
        """The storage is now ``pts`` with ``n`` valid rows (appended at the end)."""
        self._pts = pts
        self._n = n
        if n - self._n_static > max(self.min_buffer, int(self.buffer_fraction * self._n_static)):
            self._kd = cKDTree(pts[:n].copy())
            self._n_static = n
            self.rebuilds += 1

    def nearest(self, q: np.ndarray) -> tuple[int, float]:
        """Index and distance of the nearest stored point to q (2,)."""
        best_i, best_d = -1, np.inf
        if self._kd is not None:
            d, i = self._kd.query(q)
            best_i, best_d = int(i), float(d)
        if self._n > self._n_static:
            buf = self._pts[self._n_static : self._n]
            d2 = np.einsum("ij,ij->i", buf - q, buf - q)
            k = int(np.argmin(d2))
            d = float(np.sqrt(d2[k]))
            if d < best_d:
                best_i, best_d = self._n_static + k, d
        return best_i, best_d

    def within(self, q: np.ndarray, radius: float) -> np.ndarray:
        """Indices (int64) of stored points with ``||p - q|| <= radius``."""
        parts = []
        if self._kd is not None:
            parts.append(np.asarray(self._kd.query_ball_point(q, radius), dtype=np.int64))
        if self._n > self._n_static:
            buf = self._pts[self._n_static : self._n]
            d2 = np.einsum("ij,ij->i", buf - q, buf - q)
            parts.append(np.nonzero(d2 <= radius * radius)[0] + self._n_static)
        if not parts:
            return np.zeros(0, dtype=np.int64)
        return np.concatenate(parts) if len(parts) > 1 else parts[0]


class Tree:
    """RRT/RRT* tree in the planning frame.

    Public arrays (views of the first ``n`` nodes):
        xy: (n, 2) float64 node positions (x-y metres).
        parent: (n,) int64, -1 for the root.
        cost: (n,) float64 cost-to-come (path length from the root).
    ``children[i]`` lists node i's children. Node 0 is the root.

    Besides the arrays, positions and costs are mirrored in Python lists and the nodes are
    hashed into square cells of ``cell_size`` (the planner's rewiring radius), so that the
    per-insertion work of RRT* (:meth:`near_dist`, costs of a few neighbours) runs without
    NumPy calls in small neighbourhoods.
    """

    def __init__(self, root: np.ndarray, capacity: int = 1024, cell_size: float = 1.0) -> None:
        if not (math.isfinite(cell_size) and cell_size > 0):
            raise ValueError(f"cell_size must be finite and > 0: {cell_size}")
        self._xy = np.zeros((capacity, 2))
        self._parent = np.full(capacity, -1, dtype=np.int64)
        self._cost = np.zeros(capacity)
        self.children: list[list[int]] = []
        self.n = 0
        self.index = NodeIndex()
        self.index.reset(self._xy)
        self.n_rewires = 0
        self.cell_size = float(cell_size)
        self._inv_cell = 1.0 / self.cell_size
        self._cells: dict[tuple[int, int], list[int]] = {}
        self.xs: list[float] = []
        """Node x coordinates (Python floats; same values as ``xy[:, 0]``)."""
        self.ys: list[float] = []
        self.costs: list[float] = []
        """Cost-to-come per node (Python floats; same values as ``cost``)."""
        self.add(np.asarray(root, dtype=np.float64), -1, 0.0)

    @property
    def xy(self) -> np.ndarray:
        return self._xy[: self.n]

    @property
    def parent(self) -> np.ndarray:
        return self._parent[: self.n]

    @property
    def cost(self) -> np.ndarray:
        return self._cost[: self.n]

    def __len__(self) -> int:
        return self.n

    def add(self, xy: np.ndarray, parent: int, edge_cost: float) -> int:
        """Append a node under ``parent`` with the given edge length; returns its index."""
        if self.n == len(self._xy):
            cap = 2 * len(self._xy)
            self._xy = np.concatenate([self._xy, np.zeros((cap - self.n, 2))])
            self._parent = np.concatenate([self._parent, np.full(cap - self.n, -1, np.int64)])
            self._cost = np.concatenate([self._cost, np.zeros(cap - self.n)])
        i = self.n
        x, y = float(xy[0]), float(xy[1])
        c = 0.0 if parent < 0 else self.costs[parent] + edge_cost
        self._xy[i] = x, y
        self._parent[i] = parent
        self._cost[i] = c
        self.xs.append(x)
        self.ys.append(y)
        self.costs.append(c)
        key = (math.floor(x * self._inv_cell), math.floor(y * self._inv_cell))
        cell = self._cells.get(key)
        if cell is None:
            self._cells[key] = [i]
        else:
            cell.append(i)
        self.children.append([])
        if parent >= 0:
            self.children[parent].append(i)
        self.n += 1
        self.index.add(self._xy, self.n)
        return i

    def rewire(self, child: int, new_parent: int, edge_cost: float) -> None:
        """Re-parent ``child`` under ``new_parent``; the cost change propagates to its subtree.

        Callers only rewire when the new cost is lower, so no node's cost increases."""
        old = int(self._parent[child])
        costs = self.costs
        delta = (costs[new_parent] + edge_cost) - costs[child]
        if old >= 0:
            self.children[old].remove(child)
        self.children[new_parent].append(child)
        self._parent[child] = new_parent
        sub = [child]
        children = self.children
        for k in sub:  # grows while iterating: the whole subtree
            costs[k] += delta
            sub.extend(children[k])
        self._cost[sub] = [costs[k] for k in sub]
        self.n_rewires += 1

    def nearest(self, q: np.ndarray) -> int:
        return self.index.nearest(q)[0]

    def near(self, q: np.ndarray, radius: float) -> np.ndarray:
        return self.index.within(q, radius)

    DENSE = 40
    """More candidates than this in the 3 x 3 cells: :meth:`near_dist` answers in arrays."""

    def near_dist(self, x: float, y: float, radius: float) -> tuple:
        """Nodes within ``radius`` of (x, y) in increasing index order, and their distances:
        two lists, or two arrays (int64, float64) in dense parts of the tree (more than
        ``DENSE`` nodes in the 3 x 3 cells around the query; callers should switch to NumPy
        there). Scans the cells when ``radius <= cell_size``, else the spatial index."""
        ci = math.floor(x * self._inv_cell)
        cj = math.floor(y * self._inv_cell)
        cells = self._cells
        near = [
            cell
            for cell in (
                cells.get((a, b)) for a in (ci - 1, ci, ci + 1) for b in (cj - 1, cj, cj + 1)
            )
            if cell is not None
        ]
        if radius > self.cell_size or sum(map(len, near)) > self.DENSE:
            idx = np.sort(self.index.within(np.array([x, y]), radius))
            p = self._xy[idx]
            return idx, np.hypot(p[:, 0] - x, p[:, 1] - y)
        cand = [i for cell in near for i in cell]
        cand.sort()
        r2 = radius * radius
        xs, ys = self.xs, self.ys
        out_i: list[int] = []
        out_d: list[float] = []
        hypot = math.hypot
        for j in cand:
            dx = xs[j] - x
            dy = ys[j] - y
            if dx * dx + dy * dy <= r2:
                out_i.append(j)
                out_d.append(hypot(dx, dy))
        return out_i, out_d

    def path_to(self, i: int) -> np.ndarray:
        """(M, 2) node positions from the root to node i."""
        idx = []
        while i >= 0:
            idx.append(i)
            i = int(self._parent[i])
        return self._xy[idx[::-1]].copy()

    def recomputed_costs(self) -> np.ndarray:
        """(n,) cost-to-come recomputed from parents and positions (for invariant checks)."""
        out = np.full(self.n, np.nan)
        out[0] = 0.0
        order = [0]
        for k in order:
            for c in self.children[k]:
                out[c] = out[k] + float(np.linalg.norm(self._xy[c] - self._xy[k]))
                order.append(c)
        return out
