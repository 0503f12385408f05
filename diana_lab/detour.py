"""The slope shield's detour: a rover that has stopped gaining on its goal drives round what blocks it.

Why it exists: the slowest of the reference policy's successes on the Mars yard, and many of its timeouts, were
goals behind a wall: a trench or a crater rim between the rover and the goal. The policy keeps choosing drives
at the wall, the shield vetoes them, the place rule sends the rover to new places beside it, and it wanders
along the wall for dozens of decisions before it comes round an end (v0.12's slowest: 88 m driven for a goal
11 m away across a trench whose end lay 7 m to the side). The shield's own map already shows the wall: ground
its tilt check would not let the rover drive. A least-cost search over that map, rooted at the goal, with
ground the map has not seen taken as drivable (the free-space assumption of D* Lite-style navigation), tells
which of the allowed candidates leads round it.

The rule (:class:`Detour`): once ``after`` decisions, each from a place the rover had moved to, have passed
without the rover coming ``progress`` metres nearer the goal than it has ever been, the shield drives, among
the candidates it allows, the one with the least drive length plus cost to go from its end (those ending away
from the places stood on first); when none has a way, the shield chooses as without the rule. Once the rover
gains again, the policy drives again. Decisions from the place of the last one do not count: a rover that has
not moved has not tried anything new (and the latency benchmark's replay on one spot does not plan).

The search (:meth:`Detour.costs_to_go`) covers the shield map within ``margin`` of the box spanning the rover and
the goal. A map cell is untraversable where, for each of the headings 0, 45, 90 and 135 degrees, the pitch along
it or the roll across it that the map's slope there gives (central differences over the 4 neighbouring cells) is
over the tilt check's limit: no way of crossing it passes the check. The search's cells are as wide as the
rover's track (2 x 2 map cells for the Jackal on 0.2 m cells) and drivable only when every map cell in them is,
so a gap in a wall narrower than the rover is no way through (single map cells: the yard's validation suites
0.94 / 0.89 / 0.89 against 0.97 / 0.95 / 0.95); those within ``hazard_radius`` of a hazard felt are not drivable
either. Every other search cell costs its length, seen or not, and those within :data:`GOAL_CLEARANCE` of the
goal's (per axis) are drivable: the goal is where the rover has to go, even on a steep spot. With the shield's
relief check on (``relief``), the cells it calls relief hazards are walls too.
:func:`diana_lab.grid_search.cost_to_go` searches it (numba; onboard too).

Validation suites (100 episodes each), v0.12 -> ``after`` 4, ``progress`` 0.5 m, ``margin`` 10 m: see
docs/reference_policy.md, "Detour".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from diana_lab.height_memory import HeightMemory
from diana_lab.relief import ReliefLimits, relief_hazards

__all__ = ["GOAL_CLEARANCE", "Detour"]

GOAL_CLEARANCE = 0.6  # m (per axis, in whole cells) around the goal's cell that the search takes as drivable


def _cost_to_go() -> Any:
    """:func:`diana_lab.grid_search.cost_to_go`, imported when first needed (it needs numba)."""
    try:
        from diana_lab.grid_search import cost_to_go
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
            layer, :mod:`diana_lab.relief`) are not drivable either.
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
        self.search = _cost_to_go()
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
        slope rule (module docstring), ``(iy1 - iy0, ix1 - ix0)`` bool; unseen cells are."""
        ix0, iy0, ix1, iy1 = box
        n = memory.n
        h = memory.height.reshape(n, n)
        # one cell of border for the differences (NaN beyond the map)
        pad = np.full((iy1 - iy0 + 2, ix1 - ix0 + 2), np.nan)
        sy0, sy1, sx0, sx1 = max(iy0 - 1, 0), min(iy1 + 1, n), max(ix0 - 1, 0), min(ix1 + 1, n)
        pad[sy0 - iy0 + 1 : sy1 - iy0 + 1, sx0 - ix0 + 1 : sx1 - ix0 + 1] = h[sy0:sy1, sx0:sx1]
        two_cells = 2.0 * memory.cell_size
        gx = (pad[1:-1, 2:] - pad[1:-1, :-2]) / two_cells
        gy = (pad[2:, 1:-1] - pad[:-2, 1:-1]) / two_cells
        along_axes = np.maximum(np.abs(gx), np.abs(gy))  # headings 0 and 90 degrees: pitch and roll
        diagonal = np.maximum(np.abs(gx + gy), np.abs(gx - gy)) / math.sqrt(2.0)  # 45 and 135 degrees
        with np.errstate(invalid="ignore"):
            free = ~(np.minimum(along_axes, diagonal) > self.slope_limit)  # NaN (unseen): drivable
        if self.relief is not None and memory.mean_height is not None:
            free &= ~relief_hazards(memory.mean_height.reshape(n, n), box, memory.cell_size, self.relief)
        return free

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
        free = self.traversable(memory, (bx0 * p, by0 * p, bx1 * p, by1 * p))
        ny, nx = by1 - by0, bx1 - bx0
        cost = np.where(free.reshape(ny, p, nx, p).all(axis=(1, 3)), 1.0, np.inf)

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
        goal = np.asarray(goal, dtype=np.float64)[:2]
        ctg = self.costs_to_go(shield.memory, shield.hazards, start, goal, start + offsets)
        if ctg is None:
            return None
        score = np.hypot(offsets[:, 0], offsets[:, 1]) + ctg
        way = np.isfinite(score)
        if not way.any():
            return None
        # the shield's checks (SlopeShield.allows), the cheap ones for every drive with a way at once
        ok = np.zeros(len(offsets), dtype=bool)
        ok[way] = (
            (shield.steepest_many(start, offsets[way]) <= shield.cfg.limit_deg)
            & ~shield.near_hazard(start, offsets[way])
            & ~shield.relief_crosses(start, offsets[way])
        )
        for j in np.lexsort((score, ~fresh)):
            if ok[j] and not shield.obstructed(start, offsets[j]):
                return int(j)
        return None
