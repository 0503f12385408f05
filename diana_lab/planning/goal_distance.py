"""The path distance to an episode's goal from anywhere on the map: the potential of the ``path_progress`` reward.

Why: the ``progress`` term pays metres gained on the straight line to the goal, so a drive into a dead end or up to
a wall pays as well as one round it, and only the discount tells the detour that SPL rewards from the one it
punishes. Embodied-navigation benchmarks (Habitat's PointNav) pay the change in *geodesic* distance instead: a
potential-based shaping (Ng, Harada and Russell, 1999; undiscounted, as ``progress`` is), which tells the learner
at every step whether the drive brought the goal nearer along a way the rover can drive. The field is
training-time knowledge only (the reward); nothing the policy observes or runs on changes.

The field is the least cost from every cell to the goal on the planner's cost map, coarsened by ``stride`` cells
(the mean over each block of 1 for a traversable cell and ``untraversable_cost`` for any other), 8-connected, and
read between cell centres by bilinear interpolation, so the rover's every position has a finite, continuous
distance (it may stand on a cell the cost map calls untraversable: the map is conservative). One search per
episode, over the whole coarse grid, into buffers kept between searches.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from diana_lab.planning.costmap import CostMap

__all__ = ["GoalDistance"]

_SQRT2 = math.sqrt(2.0)


class GoalDistance:
    """Goal-distance fields on a cost map, coarsened by ``stride`` cells a side.

    Args:
        costmap: the planner's cost map (traversable cells finite).
        stride: fine cells per coarse cell along each axis (>= 1).
        untraversable_cost: what a metre across an untraversable cell costs, in metres of open ground (>= 1):
            large enough to go round what can be gone round, finite so that every position has a distance.
    """

    def __init__(self, costmap: CostMap, stride: int = 2, untraversable_cost: float = 10.0) -> None:
        if int(stride) != stride or stride < 1:
            raise ValueError(f"stride: expected a whole number of cells >= 1, got {stride}")
        if not math.isfinite(untraversable_cost) or untraversable_cost < 1.0:
            raise ValueError(f"untraversable_cost: expected a finite cost >= 1, got {untraversable_cost}")
        s = int(stride)
        fine = np.where(costmap.free, 1.0, float(untraversable_cost))
        ny, nx = fine.shape
        cy, cx = -(-ny // s), -(-nx // s)
        padded = np.full((cy * s, cx * s), float(untraversable_cost))
        padded[:ny, :nx] = fine
        self.cost = np.ascontiguousarray(padded.reshape(cy, s, cx, s).mean(axis=(1, 3)))
        self.resolution = costmap.resolution * s
        self.x0 = costmap.x_min + 0.5 * (s - 1) * costmap.resolution  # centre of coarse cell (0, 0)
        self.y0 = costmap.y_min + 0.5 * (s - 1) * costmap.resolution
        # the search runs on a copy framed by one cell that no path enters (its distance -1 is never improved
        # on), so that it needs no bounds checks
        self._dist = np.full((cy + 2, cx + 2), -1.0)
        self._cost = np.zeros((cy + 2, cx + 2))
        self._cost[1:-1, 1:-1] = self.cost
        w = cx + 2
        self._offsets = np.array([1, w, -1, -w, w + 1, w - 1, -w + 1, -w - 1], dtype=np.int64)
        self._half_steps = 0.5 * self.resolution * np.array([1.0] * 4 + [_SQRT2] * 4)
        entries = 8 * cy * cx + 8  # a cell is queued at most once per neighbour that improves it, 8 at most
        self._keys = np.empty(entries)
        self._items, self._next = np.empty(entries, np.int64), np.empty(entries, np.int64)
        self._heads = np.empty(int(math.ceil(_SQRT2 * self.cost.max())) + 2, np.int64)

    @property
    def shape(self) -> tuple[int, int]:
        return self.cost.shape

    def field(self, goal: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The least cost (metres of open ground) from every coarse cell to ``goal`` (x, y): ``(ny, nx)``."""
        if out is None:
            out = np.empty(self.shape)
        _search(
            self._cost,
            self._dist,
            self.resolution,
            (float(goal[0]) - self.x0) / self.resolution,
            (float(goal[1]) - self.y0) / self.resolution,
            self._offsets,
            self._half_steps,
            self._heads,
            self._next,
            self._items,
            self._keys,
        )
        out[...] = self._dist[1:-1, 1:-1]
        return out

    def at(self, field: np.ndarray, x: float, y: float) -> float:
        """The field's distance at world ``(x, y)`` (bilinear between cell centres, clamped at the edges)."""
        return float(_bilinear(field, (x - self.x0) / self.resolution, (y - self.y0) / self.resolution))

    def at_rows(self, fields: np.ndarray, rows: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """``at(fields[r], *xy[r])`` for every ``r`` of ``rows``: ``(len(rows),)``."""
        return _bilinear_rows(fields, np.asarray(rows, dtype=np.int64), xy, self.x0, self.y0, self.resolution)


@njit(cache=True, nogil=True)
def _bilinear_rows(fields, rows, xy, x0, y0, res):  # pragma: no cover (numba)
    out = np.empty(rows.shape[0])
    for j in range(rows.shape[0]):
        r = rows[j]
        out[j] = _bilinear(fields[r], (xy[r, 0] - x0) / res, (xy[r, 1] - y0) / res)
    return out


@njit(cache=True, nogil=True)
def _bilinear(field, u, v):  # pragma: no cover (numba)
    ny, nx = field.shape
    u = min(max(u, 0.0), nx - 1.0)
    v = min(max(v, 0.0), ny - 1.0)
    i0, j0 = min(int(u), nx - 2) if nx > 1 else 0, min(int(v), ny - 2) if ny > 1 else 0
    i1, j1 = min(i0 + 1, nx - 1), min(j0 + 1, ny - 1)
    fu, fv = u - i0, v - j0
    top = field[j0, i0] * (1.0 - fu) + field[j0, i1] * fu
    bottom = field[j1, i0] * (1.0 - fu) + field[j1, i1] * fu
    return top * (1.0 - fv) + bottom * fv


@njit(cache=True, nogil=True, inline="always")
def _queue(heads, nxt, items, keys, n, cell, d, res):  # pragma: no cover (numba)
    """Queue entry ``n`` (``cell`` at distance ``d``) in its bucket of the ring ``heads``; the next free entry."""
    b = int(d / res) % heads.shape[0]
    items[n], keys[n], nxt[n], heads[b] = cell, d, heads[b], n
    return n + 1


@njit(cache=True, nogil=True)
def _search(cost, dist, res, gu, gv, offsets, half_steps, heads, nxt, items, keys):  # pragma: no cover (numba)
    """Dijkstra over the framed grid from the goal at (unframed) cell coordinates ``(gu, gv)``: the (up to four)
    cell centres round it start at their straight-line distance to it, weighted by their cost.

    The queue is Dial's: buckets ``res`` wide (no edge is shorter, as no cell costs less than 1), kept in a ring
    of ``len(heads)`` buckets (more than the longest edge spans). Cells in one bucket cannot improve each other,
    so the order within a bucket does not matter and the distances are Dijkstra's, exactly; a push and a pop
    cost O(1), not a heap's O(log n). A popped entry whose key is above its cell's distance is stale (lazy
    deletion); a settled cell is never improved on, so it needs no mark, and the frame's -1 never is."""
    ny, nx = cost.shape[0] - 2, cost.shape[1] - 2
    w = nx + 2
    flat_cost, flat = cost.ravel(), dist.ravel()
    for j in range(1, ny + 1):
        flat[j * w + 1 : j * w + 1 + nx] = np.inf
    ring = heads.shape[0]
    heads[:] = -1
    n, popped = 0, 0  # entries queued, and taken out
    iu = min(max(int(math.floor(gu)), 0), nx - 1)
    iv = min(max(int(math.floor(gv)), 0), ny - 1)
    for dj in range(2):
        for di in range(2):
            i, j = min(iu + di, nx - 1), min(iv + dj, ny - 1)
            c = (j + 1) * w + i + 1
            d = math.hypot(i - gu, j - gv) * res * flat_cost[c]
            if d < flat[c]:
                flat[c] = d
                n = _queue(heads, nxt, items, keys, n, c, d, res)
    k = 0
    while popped < n:
        b = k % ring
        while heads[b] >= 0:
            e = heads[b]
            heads[b] = nxt[e]
            popped += 1
            u, key = items[e], keys[e]
            if key > flat[u]:
                continue
            cu = flat_cost[u]
            for m in range(8):
                v = u + offsets[m]
                d = key + half_steps[m] * (cu + flat_cost[v])
                if d < flat[v]:
                    flat[v] = d
                    n = _queue(heads, nxt, items, keys, n, v, d, res)
        k += 1
