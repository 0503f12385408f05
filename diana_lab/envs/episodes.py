"""Episode sampling: a start and a goal in the same connected traversable region, so a path exists.

Traversability comes from the planner's cost map (slope, step and roughness limits of the robot, obstacles
inflated by its footprint), which the ``astar`` baseline and SPL use too: every sampled episode is solvable by
construction. An optional curriculum widens the goal distance from ``curriculum.start_max_distance`` to
``max_distance`` over the first ``curriculum.episodes`` episodes of each env.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from diana_lab.config.env import EpisodeConfig
from diana_lab.config.sim import RobotConfig
from diana_lab.core.validation import ConfigError
from diana_lab.planning import CostMap, shared_costmap
from diana_lab.sim.world import World

MAX_TRIES = 64
SQUARED_MARGIN = 1e-9  # relative: squared distances this close to a limit are settled by hypot


@dataclass(frozen=True)
class Episode:
    start: np.ndarray  # (x, y)
    yaw: float
    goal: np.ndarray  # (x, y)


class EpisodeSampler:
    def __init__(self, cfg: EpisodeConfig, world: World, robot: RobotConfig, costmap: CostMap | None = None) -> None:
        self.cfg, self.world = cfg, world
        self.costmap = costmap if costmap is not None else shared_costmap(world, robot)
        labels = self.costmap.components
        if not np.any(labels > 0):
            raise ConfigError(
                f"world '{world.name}': no traversable cell for robot '{robot.name}' "
                "(slopes, steps or obstacles exceed its limits everywhere)"
            )
        iy, ix = np.nonzero(labels > 0)
        x, y = self.costmap.cell_to_world(ix, iy)
        # the env clamps waypoints this far inside the map: a goal beyond it could never be reached
        inside = world.terrain.contains(x, y, margin=robot.radius + cfg.map_margin)
        self._xy = np.column_stack([x, y])[inside]
        self._x, self._y = self._xy[:, 0].copy(), self._xy[:, 1].copy()
        self._label = labels[iy, ix][inside]
        self._scratch: tuple[np.ndarray, ...] | None = None  # per-cell work buffers of sample(), made on first use
        self._in_region: dict[int, np.ndarray] = {}  # label -> bool mask of its cells, for the regions drawn from
        if self._label.size == 0:
            raise ConfigError(
                f"episode.map_margin: no traversable cell of world '{world.name}' lies "
                f"{robot.radius + cfg.map_margin:.2f} m inside the map edge"
            )
        ids, counts = np.unique(self._label, return_counts=True)
        # draw starts from regions that are large enough to hold an episode, in proportion to their size
        big = ids[counts * self.costmap.resolution**2 >= math.pi * cfg.min_distance**2 / 4]
        self._start_pool = np.flatnonzero(np.isin(self._label, big if big.size else ids[[np.argmax(counts)]]))
        self.episodes_drawn = 0

    def max_distance(self) -> float:
        c = self.cfg.curriculum
        if not c.enabled:
            return self.cfg.max_distance
        frac = min(1.0, self.episodes_drawn / c.episodes)
        return c.start_max_distance + frac * (self.cfg.max_distance - c.start_max_distance)

    def sample(
        self,
        rng: np.random.Generator,
        min_distance: float | None = None,
        max_distance: float | None = None,
        keys: str = "episode",
    ) -> Episode:
        """A start and goal ``min_distance..max_distance`` apart (default: the ``episode`` config's); ``keys``:
        the config group the distances came from, named when no such pair exists."""
        lo = self.cfg.min_distance if min_distance is None else min_distance
        hi = self.max_distance() if max_distance is None else max_distance
        for _ in range(MAX_TRIES):
            i = int(self._start_pool[rng.integers(len(self._start_pool))])
            start = self._xy[i]
            candidates = np.flatnonzero(self._reachable(i, lo, hi))
            if candidates.size:
                goal = self._xy[candidates[rng.integers(candidates.size)]]
                self.episodes_drawn += 1
                return Episode(start.copy(), float(rng.uniform(-math.pi, math.pi)), goal.copy())
        raise ConfigError(
            f"{keys}.min_distance/max_distance: no start/goal pair {lo}..{hi} m apart in one "
            f"traversable region of world '{self.world.name}' after {MAX_TRIES} tries; "
            "lower the distances or use a larger world"
        )

    def _reachable(self, i: int, lo: float, hi: float) -> np.ndarray:
        """Cells in the region of cell ``i`` whose distance ``hypot(dx, dy)`` from it is in ``[lo, hi]``: a bool
        mask, which the next call overwrites.

        Squared distances settle every cell but those within a relative :data:`SQUARED_MARGIN` of a limit,
        where ``hypot`` settles it: a multiply-add costs a fraction of a ``hypot``, and rounding errors (~1e-16)
        come nowhere near the margin, so the cells are the same as testing ``hypot`` everywhere. Everything is
        written into buffers kept between calls: fresh temporaries of this size (tens of thousands of cells)
        cost more to page in than the arithmetic does.
        """
        if self._scratch is None:
            n = len(self._xy)
            self._scratch = (np.empty(n), np.empty(n), *(np.empty(n, dtype=bool) for _ in range(3)))
        r2, dy2, ok, maybe, test = self._scratch
        x, y = self._x[i], self._y[i]
        np.subtract(self._x, x, out=r2)
        np.subtract(self._y, y, out=dy2)
        r2 *= r2
        r2 += np.multiply(dy2, dy2, out=dy2)
        lo2 = max(lo, 0.0) ** 2  # a negative minimum is no limit; NaN stays NaN (and admits nothing)
        hi2 = hi * hi if hi >= 0.0 else -1.0  # a negative maximum (or NaN) admits nothing
        np.greater_equal(r2, lo2 * (1.0 + SQUARED_MARGIN), out=ok)  # surely inside
        ok &= np.less_equal(r2, hi2 * (1.0 - SQUARED_MARGIN), out=test)
        np.greater_equal(r2, lo2 * (1.0 - SQUARED_MARGIN), out=maybe)  # possibly inside
        maybe &= np.less_equal(r2, hi2 * (1.0 + SQUARED_MARGIN), out=test)
        near_limit = np.flatnonzero(np.logical_xor(maybe, ok, out=maybe))
        if near_limit.size:
            d = np.hypot(self._x[near_limit] - x, self._y[near_limit] - y)
            ok[near_limit] = (d >= lo) & (d <= hi)
        label = int(self._label[i])
        if label not in self._in_region:
            self._in_region[label] = self._label == label
        ok &= self._in_region[label]
        return ok

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_scratch"], state["_in_region"] = None, {}  # rebuilt on use: no need to pickle megabytes
        return state

    def check_point(self, xy: np.ndarray, what: str) -> None:
        """Fixed episodes (``reset(options=...)``) must lie on the map."""
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"reset options '{what}': expected a finite (x, y) pair, got {xy.tolist()}")
        if not bool(self.world.terrain.contains(xy[0], xy[1])):
            raise ValueError(f"reset options '{what}': {xy.tolist()} lies outside the map {self.world.bounds}")
