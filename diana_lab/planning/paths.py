"""Least-cost paths on a :class:`CostMap`: Dijkstra on the 8-connected grid, then any-angle smoothing.

Search: ``scipy.sparse.csgraph.dijkstra`` on a sparse graph built once per cost map and cached on it. An edge
joins 8-neighbours that are both traversable (a diagonal only when both cells it cuts past are traversable
too, see :mod:`diana_lab.planning.costmap`) and costs ``step length x mean cost of its two cells``. A full
single-source search is ~10 ms on the 257 x 257 Mars yard; a Python-heap A* is slower there even with a good
heuristic, because every pop costs microseconds of interpreter time. The last few searches are cached per
start cell, so many goals from one start (an episode sampler) cost one search. A map used for one question
only (a knowledge-limited expert's, new every step) is searched by the compiled, bounded
:func:`~diana_lab.core.grid_search.cost_to_go` instead (``next_waypoint(..., full_search=False)``): no
graph to build, and it stops once the cells asked about are settled.

Smoothing (:mod:`diana_lab.planning.smoothing`): grid paths turn only in 45 degree steps (up to 8.2 % too
long on open ground); a line-of-sight pass and corner tightening make them any-angle, within a few
centimetres of the taut string, never entering a cell the grid search could not use.

SPL: :func:`shortest_path_length` returns the geometric length of the smoothed least-cost path with
*uniform* cell costs (every traversable cell costs 1), i.e. of the shortest hazard-free, collision-free path:
the reference length SPL's definition asks for. The hazard-weighted path that the A* oracle drives
(``weighted=True``) is longer wherever it detours round slopes (on the Mars yard by ~4 % on median).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.sparse import csr_array
from scipy.sparse.csgraph import dijkstra

from diana_lab.core.grid_search import cost_to_go
from diana_lab.planning.costmap import CostMap
from diana_lab.planning.smoothing import corners, segment_costs, smooth_path

__all__ = ["Path", "WaypointChoice", "choose_waypoint", "next_waypoint", "plan", "shortest_path_length", "simplify"]

_NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))  # (diy, dix)
_SEARCH_CACHE = 4  # single-source results kept per cost map and metric


@dataclass(frozen=True)
class Path:
    """A planned path: ``points (K, 2)`` world x, y from the start to the goal (both exact, K >= 2).

    ``length`` is the geometric length of the polyline (metres); ``cost`` is the search's least cost of the
    grid path (metres weighted by cell cost; equal to the grid path length with uniform costs).
    """

    points: np.ndarray
    length: float
    cost: float


# ---------------------------------------------------------------------------------------------- the graph


def _cell_costs(costmap: CostMap, weighted: bool) -> np.ndarray:
    return costmap.cost if weighted else np.where(costmap.free, 1.0, np.inf)


@functools.lru_cache(maxsize=8)
def _grid_edges(shape: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """Every 8-connected edge of a ``shape`` grid, sorted by source cell: ``(src, dst, side_a, side_b,
    length_in_cells)``; ``side_a``/``side_b`` are the two cells a diagonal move cuts past (the source itself
    for straight moves). Cached per shape: the maps an episode's expert re-searches every step share it."""
    ny, nx = shape
    index = np.arange(ny * nx).reshape(ny, nx)
    parts = []
    for diy, dix in _NEIGHBOURS:
        src = _window(shape, -diy, -dix)  # cells whose neighbour (iy + diy, ix + dix) is on the grid
        dst = _window(shape, diy, dix)
        a, b = (index[dst[0], src[1]], index[src[0], dst[1]]) if diy and dix else (index[src], index[src])
        n = index[src].size
        parts.append((index[src].ravel(), index[dst].ravel(), a.ravel(), b.ravel(), np.full(n, math.hypot(diy, dix))))
    src, dst, a, b, length = (np.concatenate(p) for p in zip(*parts))
    order = np.argsort(src, kind="stable")
    return tuple(np.ascontiguousarray(x[order]) for x in (src, dst, a, b, length))


def _graph(costmap: CostMap, weighted: bool) -> csr_array:
    """The cached sparse search graph (both directions of every edge, no corner cutting)."""
    key = ("graph", weighted)
    if key in costmap._cache:
        return costmap._cache[key]
    free = costmap.free.ravel()
    cost = _cell_costs(costmap, weighted).ravel()
    src, dst, a, b, length = _grid_edges(costmap.shape)
    # a diagonal move needs (iy + diy, ix) and (iy, ix + dix) free too: no corner cutting
    ok = free[src] & free[dst] & free[a] & free[b]
    s, d = src[ok], dst[ok]
    weights = (costmap.resolution * 0.5) * length[ok] * (cost[s] + cost[d])
    n = free.size
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(s, minlength=n), out=indptr[1:])
    graph = csr_array((weights, d, indptr), shape=(n, n))  # edges are sorted by source already
    costmap._cache[key] = graph
    return graph


def _window(shape: tuple[int, int], diy: int, dix: int) -> tuple[slice, slice]:
    """The cells ``(iy + diy, ix + dix)`` for every cell whose such neighbour is on the grid."""
    ny, nx = shape
    return slice(max(diy, 0), ny + min(diy, 0)), slice(max(dix, 0), nx + min(dix, 0))


def _search(costmap: CostMap, source: int, weighted: bool) -> tuple[np.ndarray, np.ndarray]:
    """Distances and predecessors from one cell, cached for the last few sources."""
    cache: OrderedDict = costmap._cache.setdefault(("search", weighted), OrderedDict())
    if source in cache:
        cache.move_to_end(source)
        return cache[source]
    dist, pred = dijkstra(_graph(costmap, weighted), directed=True, indices=source, return_predecessors=True)
    cache[source] = (dist, pred)
    if len(cache) > _SEARCH_CACHE:
        cache.popitem(last=False)
    return dist, pred


def _cell_of(costmap: CostMap, xy: np.ndarray, snap: float) -> int | None:
    """Flat index of the traversable cell for a world point (snapped within ``snap`` metres), else None."""
    ix, iy = costmap.world_to_cell(xy[0], xy[1])
    if not costmap.inside(ix, iy):
        return None
    flat = int(np.ravel_multi_index((int(iy), int(ix)), costmap.shape))
    if costmap.free.flat[flat]:
        return flat
    if snap <= 0.0:
        return None
    dist, nearest = costmap.nearest_free
    return int(nearest.flat[flat]) if dist.flat[flat] <= snap else None


def _endpoints(
    costmap: CostMap, start_xy: np.ndarray, goal_xy: np.ndarray, snap: float, caller: str
) -> tuple[np.ndarray, np.ndarray, int | None, int | None]:
    """Start and goal as float x, y (finite, else ValueError naming ``caller``) and their cells (or None)."""
    start = np.asarray(start_xy, dtype=np.float64).ravel()[:2]
    goal = np.asarray(goal_xy, dtype=np.float64).ravel()[:2]
    if not (np.all(np.isfinite(start)) and np.all(np.isfinite(goal))):
        raise ValueError(f"{caller}: start and goal must be finite x, y, got {start} and {goal}")
    return start, goal, _cell_of(costmap, start, snap), _cell_of(costmap, goal, snap)


# ---------------------------------------------------------------------------------------------- public API


def plan(
    costmap: CostMap,
    start_xy: np.ndarray,
    goal_xy: np.ndarray,
    *,
    weighted: bool = True,
    smooth: bool = True,
    snap: float = 0.0,
) -> Path | None:
    """The least-cost path from ``start_xy`` to ``goal_xy``, or None when none exists.

    ``weighted=False`` treats every traversable cell alike (shortest hazard-free path). ``smooth`` runs the
    line-of-sight pass (any-angle result); without it the path visits cell centres. ``snap`` (m) lets a start
    or goal that lies in an untraversable cell (e.g. a rover that drifted into the inflation band) use the
    nearest traversable cell within that distance. Start and goal outside the map give None.
    """
    start, goal, s, g = _endpoints(costmap, start_xy, goal_xy, snap, "plan")
    if s is None or g is None:
        return None
    dist, pred = _search(costmap, s, weighted)
    if not np.isfinite(dist[g]):
        return None
    chain = [g]
    while chain[-1] != s:
        chain.append(int(pred[chain[-1]]))
    iy, ix = np.unravel_index(np.asarray(chain[::-1]), costmap.shape)
    cx, cy = costmap.cell_to_world(ix, iy)
    pts = np.column_stack([cx, cy]).astype(np.float64)
    pts = np.vstack([start, pts[1:-1], goal]) if len(pts) > 1 else np.vstack([start, goal])
    if smooth and len(pts) > 2:
        pts = smooth_path(_cell_costs(costmap, weighted), costmap, pts)
    length = float(np.hypot(*np.diff(pts, axis=0).T).sum())
    return Path(points=pts, length=length, cost=float(dist[g]))


@dataclass(frozen=True)
class WaypointChoice:
    """What :func:`choose_waypoint` decided: the ``waypoint`` (world x, y) and, when it chose among given
    candidates, ``costs``: each candidate's segment cost plus cost to go (``inf`` where it has no way to the goal
    or lies off the map), in the candidates' order, the chosen one's lowered to the least (see
    :func:`choose_waypoint`). ``None`` without given candidates."""

    waypoint: np.ndarray
    costs: np.ndarray | None = None


def next_waypoint(
    costmap: CostMap,
    start_xy: np.ndarray,
    goal_xy: np.ndarray,
    reach: float,
    **kwargs: Any,
) -> np.ndarray | None:
    """The best next waypoint within ``reach`` of ``start_xy`` on the way to ``goal_xy``, or None: the waypoint
    of :func:`choose_waypoint` (the same arguments)."""
    choice = choose_waypoint(costmap, start_xy, goal_xy, reach, **kwargs)
    return None if choice is None else choice.waypoint


def choose_waypoint(
    costmap: CostMap,
    start_xy: np.ndarray,
    goal_xy: np.ndarray,
    reach: float,
    *,
    weighted: bool = True,
    snap: float = 0.0,
    angles: int = 72,
    rings: int = 4,
    candidates: np.ndarray | None = None,
    full_search: bool = True,
) -> WaypointChoice | None:
    """The best next waypoint within ``reach`` of ``start_xy`` on the way to ``goal_xy``, or None.

    Candidates lie on ``rings`` circles up to ``reach`` (``angles`` per circle, plus the goal when within
    reach); the best minimises the exact cost of the straight segment to it plus the least cost from its
    cell to the goal -- a one-step any-angle look-ahead on the cost-to-go field -- unless the straight line to
    the goal costs no more, which is then followed. Given ``candidates`` (world points, ``(n, 2)``: a
    discrete action space's waypoints), the best of exactly those is returned (``reach`` unused), so an
    expert labels with an action the learner can take, not the nearest one to a waypoint it cannot; the
    choice then carries every candidate's cost too. When the straight line to the goal wins, the candidate chosen along
    it may cost a little more on the grid than the least (the grid's cost to go overestimates off-axis ways), so
    its cost is lowered to the least: the expert's choice is always among the cheapest.

    Why not :func:`plan`: an expert asked for the next waypoint from every state an episode visits (DAgger
    labels the learner's states, not its own) would run a search and a smoothing per step (10-30 ms on the
    Mars yard). The edge costs are symmetric, so one search from the *goal* (cached) serves every start of
    the episode, and a step costs one batch of segment integrals (about a millisecond). With
    ``full_search=False`` the map is searched only until the start and the candidates are settled
    (:func:`~diana_lab.core.grid_search.cost_to_go`, nothing cached): the choice for a map that changes
    every step (an expert that knows only what the rover has seen), the same waypoint.
    """
    if not reach > 0.0:
        raise ValueError(f"next_waypoint: reach must be positive, got {reach!r}")
    start, goal, s, g = _endpoints(costmap, start_xy, goal_xy, snap, "next_waypoint")
    if s is None or g is None:
        return None
    if candidates is None:
        theta = np.arange(angles) * (2.0 * math.pi / angles)
        radius = reach * np.arange(1, rings + 1) / rings
        cand = start + (radius[:, None, None] * np.stack([np.cos(theta), np.sin(theta)], axis=-1)).reshape(-1, 2)
    else:
        cand = np.asarray(candidates, dtype=np.float64).reshape(-1, 2)
    index = np.arange(len(cand))  # each remaining candidate's row among those given
    ix, iy = costmap.world_to_cell(cand[:, 0], cand[:, 1])
    inside = costmap.inside(ix, iy)
    cand, index, ix, iy = cand[inside], index[inside], np.asarray(ix)[inside], np.asarray(iy)[inside]
    cand_cells = np.ravel_multi_index((iy, ix), costmap.shape)
    if full_search:
        to_go, _ = _search(costmap, g, weighted)
        start_to_go, remaining = to_go[s], to_go[cand_cells]
    else:  # the start first: the search is bounded towards it
        found = cost_to_go(_cell_costs(costmap, weighted), costmap.resolution, g, np.append(s, cand_cells))
        start_to_go, remaining = found[0], found[1:]
    if not np.isfinite(start_to_go):
        return None
    if candidates is None and math.dist(start, goal) <= reach:
        cand, remaining = np.vstack([cand, goal]), np.append(remaining, 0.0)
    finite = np.isfinite(remaining)
    cand, remaining = cand[finite], remaining[finite]
    if not len(cand):
        return None
    cells = _cell_costs(costmap, weighted)
    total = segment_costs(cells, costmap, np.broadcast_to(start, cand.shape), cand) + remaining
    best = int(np.argmin(total))
    if not np.isfinite(total[best]):
        return None
    # the grid's cost-to-go overestimates off-axis paths (by up to 8 %), which would bend the way round
    # open ground towards the grid axes; when the straight line to the goal is no dearer, take it (the
    # slack: a candidate inside the goal's cell counts nothing for the rest of that cell) -- or, among
    # given candidates, the traversable one nearest to where that line would lead
    direct = float(segment_costs(cells, costmap, start[None], goal[None])[0])
    if direct <= total[best] + costmap.resolution * float(cells.flat[g]):
        d = math.dist(start, goal)
        if candidates is None:
            return WaypointChoice(goal.copy() if d <= reach else start + (goal - start) * (reach / d))
        far = float(np.max(np.hypot(*(cand - start).T)))
        aim = goal if d <= far else start + (goal - start) * (far / d)
        gaps = np.where(np.isfinite(total), np.hypot(*(cand - aim).T), np.inf)
        best_total, best = float(total[best]), int(np.argmin(gaps))
        total = total.copy()
        total[best] = min(float(total[best]), best_total)
    if candidates is None:
        return WaypointChoice(cand[best].copy())
    costs = np.full(len(np.asarray(candidates).reshape(-1, 2)), np.inf)
    costs[index[finite]] = total
    return WaypointChoice(cand[best].copy(), costs)


def shortest_path_length(
    costmap: CostMap, start_xy: np.ndarray, goal_xy: np.ndarray, *, weighted: bool = False
) -> float:
    """Geometric length (m) of the shortest traversable path (``inf`` if none): SPL's reference length.

    By default the search uses uniform costs, so this is the length of the shortest hazard-free path (after
    the line-of-sight pass: within a fraction of a cell of the true any-angle optimum on open ground, exact on
    a straight line). ``weighted=True`` measures the hazard-weighted least-cost path instead.
    """
    path = plan(costmap, start_xy, goal_xy, weighted=weighted, smooth=True)
    return float("inf") if path is None else path.length


def simplify(path: Path, max_segment: float) -> np.ndarray:
    """Waypoints ``(M, 2)`` for the position controller: the path's corners, at most ``max_segment`` apart.

    Collinear vertices are dropped (the controller would stop and re-turn at each) and longer segments are
    split evenly. The start is left out (the rover is there); the last waypoint is the exact goal.
    """
    if not max_segment > 0.0:
        raise ValueError(f"simplify: max_segment must be positive, got {max_segment!r}")
    pts = corners(np.asarray(path.points, dtype=np.float64))
    if len(pts) == 1:
        return pts.copy()
    out = []
    for p, q in itertools.pairwise(pts):
        n = max(1, int(np.ceil(np.hypot(*(q - p)) / max_segment - 1e-9)))
        out.append(p + (q - p) * (np.arange(1, n + 1) / n)[:, None])
    return np.vstack(out)
