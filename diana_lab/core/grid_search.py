"""A goal-rooted least-cost search on the cost-map grid that stops once the cells asked about are settled.

Why it exists: an expert that only knows the ground near the rover (``astar_memory``, ``astar_seen``: the
imitation experts) sees a different cost map at every step, so :func:`~diana_lab.planning.next_waypoint`
cannot reuse one search per episode. With ``scipy.sparse.csgraph.dijkstra`` a step then built the sparse
graph of the whole map (~19 ms on the 257 x 257 Mars yard) and searched all of it (~20 ms), and labelling
was nearly all of a DAgger iteration's time. This search walks the grid itself (no graph), from the goal
towards the rover with an A* bound, and stops when the start and every candidate waypoint are settled.
The slope shield's detour (:mod:`diana_lab.shield.detour`) searches its own map with it, onboard too: this module
needs numpy and numba only (it sits outside :mod:`diana_lab.planning`, whose cost maps need the simulator's
worlds).

Same graph, same costs: an edge joins 8-neighbours that are both traversable (a diagonal only when the two
cells it cuts past are traversable too) and costs ``(resolution / 2) * step length * (cost_a + cost_b)``
in the very order of floating-point operations of the scipy graph in :mod:`diana_lab.planning.paths`, so a
settled cell's distance is the same least cost. The bound is ``c_min * resolution`` times the distance (in
cells) from a cell to the disc around the start holding every target, ``c_min`` the cheapest traversable
cell: no edge costs less per cell of length, so the bound is consistent and a cell is final when popped.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["cost_to_go"]

_SQRT2 = math.hypot(1, 1)  # as in the scipy graph's edge lengths


def cost_to_go(cost: np.ndarray, resolution: float, source: int, targets: np.ndarray) -> np.ndarray:
    """Least cost from cell ``source`` (flat index into ``cost``) to each of ``targets`` (flat indices).

    ``cost`` is a ``(ny, nx)`` grid of cell costs (``inf``: untraversable). Returns ``(len(targets),)``
    float64, ``inf`` for targets that cannot be reached (or are untraversable, as is every target when the
    source is). Equal to ``dijkstra`` over :mod:`~diana_lab.planning.paths`'s graph at those cells. Any order
    of ``targets`` is exact; the search is bounded towards the first (put the rover's cell first: the other
    targets lie around it), so targets far from each other make it search more.
    """
    cost = np.ascontiguousarray(cost, dtype=np.float64)
    if cost.ndim != 2:
        raise ValueError(f"cost_to_go: expected a 2-D cost grid, got shape {cost.shape}")
    targets = np.ascontiguousarray(targets, dtype=np.int64).ravel()
    n = cost.size
    if not 0 <= source < n or (targets.size and (targets.min() < 0 or targets.max() >= n)):
        raise ValueError(f"cost_to_go: cell indices must lie in [0, {n}), got source {source} and targets {targets}")
    finite = cost[np.isfinite(cost)]
    if not targets.size or not np.isfinite(cost.flat[source]) or not finite.size:  # the kernel reads targets[0]
        return np.full(targets.shape, np.inf)
    return _search(cost, float(resolution), int(source), targets, float(finite.min()))


@njit(cache=True, nogil=True, inline="always")
def _push(keys, items, size, key, item):  # pragma: no cover (numba)
    """Add ``(key, item)`` to the binary min-heap in ``keys[:size]``, ``items[:size]``; the new size."""
    i = size
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= key:
            break
        keys[i], items[i] = keys[parent], items[parent]
        i = parent
    keys[i], items[i] = key, item
    return size + 1


@njit(cache=True, nogil=True, inline="always")
def _pop(keys, items, size):  # pragma: no cover (numba)
    """Remove the heap's least entry (the caller read it at index 0); the new size."""
    size -= 1
    key, item = keys[size], items[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if key <= keys[child]:
            break
        keys[i], items[i] = keys[child], items[child]
        i = child
    keys[i], items[i] = key, item
    return size


@njit(cache=True, nogil=True)
def _search(cost, res, source, targets, c_min):  # pragma: no cover (numba)
    ny, nx = cost.shape
    flat = cost.ravel()
    dist = np.full(ny * nx, np.inf)
    done = np.zeros(ny * nx, np.bool_)
    wanted = np.zeros(ny * nx, np.bool_)
    left = 0
    # every target lies within `reach` cells of the focus (the first target: the caller's start cell)
    fy, fx = targets[0] // nx, targets[0] % nx
    reach = 0.0
    for t in targets:
        if np.isfinite(flat[t]) and not wanted[t]:
            wanted[t] = True
            left += 1
        reach = max(reach, math.hypot(t // nx - fy, t % nx - fx))
    scale = c_min * res * (1.0 - 1e-12)  # a hair under: rounding never makes the bound inconsistent
    # a cell enters the heap at most once per neighbour that improves it (lazy deletion): 8 per cell at most
    keys = np.empty(8 * ny * nx + 1)
    items = np.empty(8 * ny * nx + 1, np.int64)
    dist[source] = 0.0
    size = _push(keys, items, 0, 0.0, source)
    while size > 0 and left > 0:
        u = items[0]
        size = _pop(keys, items, size)
        if done[u]:
            continue
        done[u] = True
        if wanted[u]:
            left -= 1
        uy, ux = u // nx, u % nx
        for k in range(8):
            dy = (0, 1, 0, -1, 1, 1, -1, -1)[k]
            dx = (1, 0, -1, 0, 1, -1, 1, -1)[k]
            vy, vx = uy + dy, ux + dx
            if vy < 0 or vy >= ny or vx < 0 or vx >= nx:
                continue
            v = vy * nx + vx
            if done[v] or not np.isfinite(flat[v]):
                continue
            if k >= 4:
                if not (np.isfinite(flat[vy * nx + ux]) and np.isfinite(flat[uy * nx + vx])):
                    continue
                length = _SQRT2
            else:
                length = 1.0
            d = dist[u] + (res * 0.5) * length * (flat[u] + flat[v])  # the scipy graph's weight, as it computes it
            if d < dist[v]:
                dist[v] = d
                bound = max(0.0, math.hypot(vy - fy, vx - fx) - reach) * scale
                size = _push(keys, items, size, d + bound, v)
    out = np.empty(targets.shape[0])
    for i in range(targets.shape[0]):
        t = targets[i]
        out[i] = dist[t] if done[t] else np.inf
    return out
