"""The slope shield's detour: a rover that has stopped gaining on its goal drives round what blocks it.

Why it exists: a goal behind a wall (a trench, a crater rim) keeps the policy choosing drives at the wall, the shield
vetoing them and the rover wandering along it. The shield's own map already shows the wall; a least-cost search over
that map, rooted at the goal, with unseen ground taken as drivable (the free-space assumption of D* Lite-style
navigation), tells which allowed candidate leads round it.

The rule (:class:`Detour`): once ``after`` decisions, each from a new place, have passed without the rover coming
``progress`` metres nearer the goal than ever, the shield drives the allowed candidate with the least drive length
plus cost to go from its end (those ending away from places stood on first); once the rover gains again, the policy
drives again.

The search (:meth:`Detour.costs_to_go`) covers the map within ``margin`` of the box spanning the rover and the goal.
A map cell is untraversable where no heading of 0, 45, 90 or 135 degrees crosses it within the tilt check's limit;
the search's cells are as wide as the rover's track and drivable only when every map cell in them is (a gap
narrower than the rover is no way through), and not within ``hazard_radius`` of a hazard felt; cells near the goal
are drivable. With ``relief`` the relief hazards are walls too. :func:`diana_lab.core.grid_search.cost_to_go`
searches it (numba; onboard too).

The slope cost (:class:`SlopeCost`): a drivable cell steeper than ``from_deg`` costs its length times
``1 + weight * e**2`` (``e`` the excess over the span up to ``to_deg``, at most 1), as the A* oracle charges pitch.
The route rule (:meth:`Detour.route`): at every decision, only the allowed drives within ``tolerance`` metres of
the least score are open to the policy. The site map (:attr:`Detour.site_map`): where the shield's map gives no
slope, the search takes the site map's. What each bought: docs/reference_policy.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from diana_lab.core.height_memory import HeightMemory
from diana_lab.shield.relief import ReliefLimits, relief_hazards
from diana_lab.shield.site_map import SiteMap

__all__ = ["GOAL_CLEARANCE", "Detour", "SlopeCost"]

GOAL_CLEARANCE = 0.6  # m (per axis, in whole cells) around the goal's cell that the search takes as drivable


@dataclass(frozen=True)
class SlopeCost:
    """The search's cost of slope (module docstring): ``1 + weight * e**2`` times a cell's length, ``e`` its map
    slope's excess over ``from_deg``, as a share of the span up to ``to_deg`` (clipped to 0..1)."""

    weight: float
    from_deg: float = 15.0
    to_deg: float = 22.0

    def __post_init__(self) -> None:
        if not (self.weight >= 0 and 0 < self.from_deg < self.to_deg < 90):
            raise ValueError(
                "SlopeCost: expected weight >= 0 and 0 < from_deg < to_deg < 90, got "
                f"{self.weight}, {self.from_deg}, {self.to_deg}"
            )

    def factor(self, slope_deg: np.ndarray) -> np.ndarray:
        """The cost per metre of cells of ``slope_deg`` (NaN, unseen ground: 1)."""
        excess = np.clip((np.nan_to_num(slope_deg, nan=0.0) - self.from_deg) / (self.to_deg - self.from_deg), 0, 1)
        return 1.0 + self.weight * excess**2


def _cost_to_go() -> Any:
    """:func:`diana_lab.core.grid_search.cost_to_go`, imported when first needed (it needs numba)."""
    try:
        from diana_lab.core.grid_search import cost_to_go
    except ImportError as exc:  # the onboard runtime without numba
        raise ValueError(
            "the slope shield's detour (detour_after > 0) needs numba (pip install numba): " + str(exc)
        ) from exc
    return cost_to_go


class Detour:
    """Stall tracking and the search for one episode at a time (:meth:`reset` per episode).

    Args:
        after: decisions without progress before the detour drives (>= 1).
        progress: metres nearer the goal than ever that count as progress (> 0).
        margin: metres around the box spanning the rover and the goal that the search covers (> 0).
        limit_deg: the tilt check's limit (degrees).
        hazard_radius: metres around a hazard felt that the search does not cross (0: none).
        pool: a search cell is ``pool`` x ``pool`` map cells, drivable when all of them are (the shield passes the
            track width in cells: a gap in a wall narrower than the rover is no way through).
        relief: with the shield's relief check on, its limits: the map cells it calls hazards (on the map's mean
            layer, :mod:`diana_lab.shield.relief`) are not drivable either.
        slope_cost: the search's cost of slope (:class:`SlopeCost`); None: every drivable cell costs its length.
    """

    def __init__(
        self,
        after: int,
        progress: float,
        margin: float,
        limit_deg: float,
        hazard_radius: float,
        pool: int = 1,
        relief: ReliefLimits | None = None,
        slope_cost: SlopeCost | None = None,
    ) -> None:
        if not (after >= 1 and progress > 0 and margin > 0 and 0 < limit_deg < 90 and hazard_radius >= 0 and pool >= 1):
            raise ValueError(
                "Detour: expected after >= 1, progress > 0, margin > 0, 0 < limit_deg < 90, hazard_radius >= 0 and "
                f"pool >= 1, got {after}, {progress}, {margin}, {limit_deg}, {hazard_radius}, {pool}"
            )
        self.after, self.progress, self.margin = int(after), float(progress), float(margin)
        self.slope_limit = math.tan(math.radians(limit_deg))
        self.hazard_radius = float(hazard_radius)
        self.pool = int(pool)
        self.relief = relief
        self.slope_cost = slope_cost if slope_cost is not None and slope_cost.weight > 0 else None
        self.search = _cost_to_go()
        self.site_map: SiteMap | None = None  # what the search assumes of unseen ground (None: drivable, flat)
        self.reset()

    def reset(self) -> None:
        """A new episode (a new goal): no progress to compare with yet."""
        self.best = math.inf  # the nearest the rover has been to the goal (m)
        self.since = 0  # decisions since it last came `progress` nearer than that
        self._last: tuple[float, float] | None = None  # where the last decision was made

    def stalled(self, start: np.ndarray, goal: np.ndarray) -> bool:
        """Record a decision at ``start`` for ``goal`` (world xy) and say whether the detour should drive it."""
        here = (float(start[0]), float(start[1]))
        distance = math.hypot(goal[0] - here[0], goal[1] - here[1])
        if distance < self.best - self.progress:
            self.best, self.since = distance, 0
        elif here != self._last:
            self.since += 1
        self._last = here
        return self.since >= self.after

    def traversable(self, memory: HeightMemory, box: tuple[int, int, int, int]) -> np.ndarray:
        """Whether each cell of ``memory`` in ``box`` (``ix0, iy0, ix1, iy1``, end-exclusive) is drivable by the
        slope rule (module docstring), ``(iy1 - iy0, ix1 - ix0)`` bool; unseen cells are, unless the site map
        (:attr:`site_map`) puts them over the limit."""
        n = memory.n
        gx, gy = self._gradient(memory, memory.height, box)
        along_axes = np.maximum(np.abs(gx), np.abs(gy))  # headings 0 and 90 degrees: pitch and roll
        diagonal = np.maximum(np.abs(gx + gy), np.abs(gx - gy)) / math.sqrt(2.0)  # 45 and 135 degrees
        with np.errstate(invalid="ignore"):
            free = ~(np.minimum(along_axes, diagonal) > self.slope_limit)  # NaN (unseen): drivable
        if self.relief is not None and memory.mean_height is not None:
            free &= ~relief_hazards(memory.mean_height.reshape(n, n), box, memory.cell_size, self.relief)
        return free

    def _gradient(
        self, memory: HeightMemory, layer: np.ndarray, box: tuple[int, int, int, int]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The gradient of ``layer`` (a ``memory`` layer) in ``box``, and where the map cannot give one (a cell or
        a neighbour unseen), the site map's (:mod:`diana_lab.shield.site_map`), when there is one."""
        n = memory.n
        gx, gy = _gradient(layer.reshape(n, n), box, memory.cell_size)
        if self.site_map is not None:
            ix0, iy0, ix1, iy1 = box
            xs = memory.origin[0] + (np.arange(ix0, ix1) + 0.5) * memory.cell_size
            ys = memory.origin[1] + (np.arange(iy0, iy1) + 0.5) * memory.cell_size
            unseen = np.isnan(gx) | np.isnan(gy)
            iy, ix = np.nonzero(unseen)
            sx, sy = self.site_map.gradient_at(xs[ix], ys[iy])
            gx[unseen], gy[unseen] = sx, sy
        return gx, gy

    def costs_to_go(
        self,
        memory: HeightMemory,
        hazards: np.ndarray,
        start: np.ndarray,
        goal: np.ndarray,
        ends: np.ndarray,
    ) -> np.ndarray | None:
        """The least cost (m) from each of ``ends`` ``(K, 2)`` to ``goal`` over the map (module docstring), ``(K,)``,
        ``inf`` where there is no way; None when the map holds no ground yet or the goal lies off it."""
        if memory.origin is None:
            return None
        p, n = self.pool, memory.n
        c = memory.cell_size * p  # a search cell: p x p map cells, drivable when all of them are
        lo = np.minimum(start, goal) - self.margin
        hi = np.maximum(start, goal) + self.margin
        bx0, by0 = (max(0, int(math.floor((v - o) / c))) for v, o in zip(lo, memory.origin))
        bx1, by1 = (min(n // p, int(math.ceil((v - o) / c))) for v, o in zip(hi, memory.origin))
        if bx1 - bx0 < 2 or by1 - by0 < 2:
            return None
        box = (bx0 * p, by0 * p, bx1 * p, by1 * p)
        free = self.traversable(memory, box)
        ny, nx = by1 - by0, bx1 - bx0
        cost = np.where(free.reshape(ny, p, nx, p).all(axis=(1, 3)), 1.0, np.inf)
        if self.slope_cost is not None:  # a search cell costs as its steepest map cell
            layer = memory.mean_height if memory.mean_height is not None else memory.height
            gx, gy = self._gradient(memory, layer, box)
            with np.errstate(invalid="ignore"):
                slope = np.degrees(np.arctan(np.hypot(gx, gy)))
            cost = cost * self.slope_cost.factor(slope).reshape(ny, p, nx, p).max(axis=(1, 3))

        def cells(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            fx = np.floor((xy[:, 0] - memory.origin[0]) / c) - bx0
            fy = np.floor((xy[:, 1] - memory.origin[1]) / c) - by0
            inside = (fx >= 0) & (fx < nx) & (fy >= 0) & (fy < ny)
            return (np.where(inside, fy, 0) * nx + np.where(inside, fx, 0)).astype(np.int64), inside

        if len(hazards) and self.hazard_radius > 0:
            yy, xx = np.mgrid[0:ny, 0:nx]
            cx = memory.origin[0] + (bx0 + xx + 0.5) * c
            cy = memory.origin[1] + (by0 + yy + 0.5) * c
            for hx, hy in hazards:
                cost[(cx - hx) ** 2 + (cy - hy) ** 2 <= self.hazard_radius**2] = np.inf
        (goal_cell,), (goal_inside,) = cells(np.asarray(goal, dtype=np.float64).reshape(1, 2))
        if not goal_inside:
            return None
        gy, gx = divmod(int(goal_cell), nx)
        r = int(math.ceil(GOAL_CLEARANCE / c - 1e-9))
        cost[max(0, gy - r) : gy + r + 1, max(0, gx - r) : gx + r + 1] = 1.0
        points = np.concatenate([np.asarray(start, dtype=np.float64).reshape(1, 2), ends])
        targets, inside = cells(points)
        ctg = self.search(cost, c, int(goal_cell), targets)
        return np.where(inside, ctg, np.inf)[1:]

    def choose(
        self, shield: Any, offsets: np.ndarray, start: np.ndarray, goal: Sequence[float], fresh: np.ndarray
    ) -> int | None:
        """The index into ``offsets`` ``(K, 2)`` (world frame, the shield's ``top_k``) of the allowed drive with
        the least length plus cost to go from its end, one ending away from the places stood on (``fresh``)
        first; None when no allowed drive has a way (or there is no map to search)."""
        scored = self._scores(shield, offsets, start, goal)
        if scored is None:
            return None
        score, ok = scored
        for j in np.lexsort((score, ~fresh)):
            if ok[j] and not shield.obstructed(start, offsets[j]):
                return int(j)
        return None

    def route(
        self,
        shield: Any,
        offsets: np.ndarray,
        start: np.ndarray,
        goal: Sequence[float],
        fresh: np.ndarray,
        tolerance: float,
    ) -> int | None:
        """The route rule (module docstring): the index into ``offsets`` ``(K, 2)`` (world frame, the shield's
        ``top_k`` in the policy's order) of the first allowed drive whose length plus cost to go lies within
        ``tolerance`` (m) of the least among the drives the cheap checks allow, one ending away from the places
        stood on (``fresh``) first; None when none has a way (or there is no map to search)."""
        scored = self._scores(shield, offsets, start, goal)
        if scored is None:
            return None
        score, ok = scored
        best = float(np.min(np.where(ok, score, np.inf)))
        if not math.isfinite(best):
            return None
        first = None
        for j in np.flatnonzero(ok & (score <= best + tolerance)):
            if shield.obstructed(start, offsets[j]):
                continue
            if fresh[j]:
                return int(j)
            if first is None:
                first = int(j)
        return first

    def _scores(
        self, shield: Any, offsets: np.ndarray, start: np.ndarray, goal: Sequence[float]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Each drive's length plus cost to go from its end, ``(K,)`` (``inf``: no way), and whether the shield's
        cheap checks allow it (tilt, hazards felt, relief; :meth:`SlopeShield.allows` less the obstacle checks,
        which cost more and are left to the caller); None when there is no map to search or no drive has a way."""
        goal = np.asarray(goal, dtype=np.float64)[:2]
        ctg = self.costs_to_go(shield.memory, shield.hazards, start, goal, start + offsets)
        if ctg is None:
            return None
        score = np.hypot(offsets[:, 0], offsets[:, 1]) + ctg
        way = np.isfinite(score)
        if not way.any():
            return None
        ok = np.zeros(len(offsets), dtype=bool)
        ok[way] = (
            (shield.steepest_many(start, offsets[way]) <= shield.cfg.limit_deg)
            & ~shield.near_hazard(start, offsets[way])
            & ~shield.relief_crosses(start, offsets[way])
        )
        return score, ok


def _gradient(grid: np.ndarray, box: tuple[int, int, int, int], cell_size: float) -> tuple[np.ndarray, np.ndarray]:
    """The height's rise per metre along x and y of each cell of ``grid`` (``(N, M)``, NaN unknown, ``[iy, ix]``)
    in ``box`` (``ix0, iy0, ix1, iy1``, end-exclusive), by central differences over the 4 neighbours (NaN where
    one is unknown or off the grid), both ``(iy1 - iy0, ix1 - ix0)``."""
    ix0, iy0, ix1, iy1 = box
    rows, cols = grid.shape
    pad = np.full((iy1 - iy0 + 2, ix1 - ix0 + 2), np.nan)  # one cell of border for the differences
    sy0, sy1, sx0, sx1 = max(iy0 - 1, 0), min(iy1 + 1, rows), max(ix0 - 1, 0), min(ix1 + 1, cols)
    pad[sy0 - iy0 + 1 : sy1 - iy0 + 1, sx0 - ix0 + 1 : sx1 - ix0 + 1] = grid[sy0:sy1, sx0:sx1]
    two_cells = 2.0 * cell_size
    return (pad[1:-1, 2:] - pad[1:-1, :-2]) / two_cells, (pad[2:, 1:-1] - pad[:-2, 1:-1]) / two_cells
