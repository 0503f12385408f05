"""Traversability cost map of a world for one robot: what the sampler, SPL and the A* oracle plan on.

A cell is **untraversable** (cost ``inf``) when any hazard exceeds its limit -- footprint slope over
``robot.max_slope_deg`` less a safety margin, de-tilted step over ``robot.max_step_height``, roughness over
the roughness limit -- when an obstacle taller than the robot can pass lies within the inflation radius, or
when the cell lies in the border band. Otherwise ``cost = 1 + sum_i w_i * hazard_i / limit_i`` (each
normalised hazard is in ``[0, 1]``), so the planner prefers gentle ground without refusing anything the
robot can drive.

Grid: cell ``[iy, ix]`` is centred on ``x = x_min + ix * resolution``, ``y = y_min + iy * resolution``, the
terrain's convention; at the default resolution the cells coincide with the terrain samples.

Connectivity: components are labelled **4-connected**, and the planner's 8-connected graph allows a diagonal
move only when both cells it cuts past are traversable (no corner cutting). With that rule two cells are
joined by a path exactly when they share a 4-connected label, so "same component" is a guarantee that
:func:`diana_lab.planning.plan` finds a path (plain 8-connected labels would join cells that touch only at a
corner, which the robot cannot squeeze between).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import ndimage as ndi

from diana_lab.config.sim import RobotConfig
from diana_lab.core.validation import ConfigError, in_range, non_negative, positive
from diana_lab.planning.hazards import terrain_hazards
from diana_lab.sim.world import World

__all__ = ["CostMap", "CostMapConfig", "build_costmap"]


@dataclass
class CostMapConfig:
    """How hazards become costs. ``None`` limits fall back to the robot's own limits (see each key)."""

    resolution: float | None = None  # m per cell; None: terrain spacing, coarsened to <= max_cells per side
    max_cells: int = 300  # per side, only when resolution is None
    slope_weight: float = 1.0
    step_weight: float = 1.0
    roughness_weight: float = 1.0
    slope_limit_deg: float | None = None  # None: robot.max_slope_deg
    slope_margin_deg: float = 3.0  # lethal above (limit - margin): see build_costmap
    step_limit: float | None = None  # None: robot.max_step_height
    roughness_limit: float | None = None  # RMS residual (m); None: robot.ground_clearance
    obstacle_height: float | None = None  # taller is lethal; None: min(ground_clearance, max_step_height)
    inflation_margin: float = 0.0  # m of extra clearance around lethal obstacles (see build_costmap)
    border_margin: float | None = None  # m along the map edge that is untraversable; None: robot.radius

    def __post_init__(self) -> None:
        if self.resolution is not None:
            positive("planning.resolution", self.resolution)
        if not isinstance(self.max_cells, int) or self.max_cells < 8:
            raise ConfigError(f"planning.max_cells: expected an integer >= 8, got {self.max_cells!r}")
        for key in (
            "slope_weight",
            "step_weight",
            "roughness_weight",
            "slope_margin_deg",
            "inflation_margin",
        ):
            non_negative(f"planning.{key}", getattr(self, key))
        if self.slope_limit_deg is not None:
            in_range("planning.slope_limit_deg", self.slope_limit_deg, 0.0, 90.0, inclusive=False)
        for key in ("step_limit", "roughness_limit"):
            if getattr(self, key) is not None:
                positive(f"planning.{key}", getattr(self, key))
        for key in ("obstacle_height", "border_margin"):
            if getattr(self, key) is not None:
                non_negative(f"planning.{key}", getattr(self, key))


@dataclass(eq=False)
class CostMap:
    """Per-cell traversal cost (``inf`` = untraversable) on a square grid, plus the hazard layers behind it.

    ``layers`` holds same-shaped diagnostics: ``slope_deg``, ``step``, ``roughness`` (terrain hazards pooled
    to the cell), ``obstacle`` and ``border`` (bool masks of the lethal bands). Derived data (components,
    search graphs) is cached on the instance, so build one cost map per world and robot and reuse it.
    """

    cost: np.ndarray
    resolution: float
    x_min: float
    y_min: float
    layers: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    _cache: dict = field(default_factory=dict, repr=False)  # search graphs and recent searches (paths.py)

    def __post_init__(self) -> None:
        self.cost = np.ascontiguousarray(self.cost, dtype=np.float64)
        if self.cost.ndim != 2:
            raise ValueError(f"cost map: expected a 2-D cost grid, got shape {self.cost.shape}")
        if np.any(np.isnan(self.cost)) or np.any(self.cost < 1.0):
            raise ValueError("cost map: costs must be >= 1 (inf for untraversable), without NaN")
        self.cost.setflags(write=False)

    @property
    def shape(self) -> tuple[int, int]:
        return self.cost.shape  # (ny, nx)

    @cached_property
    def free(self) -> np.ndarray:
        """Boolean grid of traversable cells."""
        return np.isfinite(self.cost)

    # ------------------------------------------------------------------ coordinates
    def world_to_cell(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Nearest cell ``(ix, iy)`` of world points (not clipped: may fall outside the grid)."""
        ix = np.rint((np.asarray(x, dtype=np.float64) - self.x_min) / self.resolution).astype(np.int64)
        iy = np.rint((np.asarray(y, dtype=np.float64) - self.y_min) / self.resolution).astype(np.int64)
        return ix, iy

    def cell_to_world(self, ix: np.ndarray | int, iy: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates of cell centres."""
        return self.x_min + np.asarray(ix) * self.resolution, self.y_min + np.asarray(iy) * self.resolution

    def inside(self, ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
        ny, nx = self.shape
        return (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)

    def cost_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Cost of the cell under world points; ``inf`` outside the map."""
        ix, iy = self.world_to_cell(x, y)
        ok = self.inside(ix, iy)
        ny, nx = self.shape
        return np.where(ok, self.cost[np.clip(iy, 0, ny - 1), np.clip(ix, 0, nx - 1)], np.inf)

    def traversable(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Whether the robot may stand at world ``(x, y)`` (False outside the map)."""
        return np.isfinite(self.cost_at(x, y))

    # ------------------------------------------------------------------ connectivity
    @cached_property
    def _labels(self) -> tuple[np.ndarray, int]:
        cross = ndi.generate_binary_structure(2, 1)  # 4-connected: see the module docstring
        labels, n = ndi.label(self.free, structure=cross)
        return labels, int(n)

    @property
    def components(self) -> np.ndarray:
        """Component label of every cell (0 = untraversable); cells sharing a label are mutually reachable."""
        return self._labels[0]

    @property
    def n_components(self) -> int:
        return self._labels[1]

    def component_at(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Component label under world points (0 when untraversable or outside)."""
        ix, iy = self.world_to_cell(x, y)
        ok = self.inside(ix, iy)
        ny, nx = self.shape
        return np.where(ok, self.components[np.clip(iy, 0, ny - 1), np.clip(ix, 0, nx - 1)], 0)

    @cached_property
    def largest_component_mask(self) -> np.ndarray:
        """Boolean grid of the largest connected traversable region (all False if nothing is traversable)."""
        labels, n = self._labels
        if n == 0:
            return np.zeros(self.shape, dtype=bool)
        sizes = np.bincount(labels.ravel(), minlength=n + 1)
        sizes[0] = 0
        return labels == int(np.argmax(sizes))

    @cached_property
    def nearest_free(self) -> tuple[np.ndarray, np.ndarray]:
        """For every cell, ``(distance m, flat index)`` of the nearest traversable cell (to snap starts)."""
        if not self.free.any():
            return np.full(self.shape, np.inf), np.full(self.shape, -1, dtype=np.int64)
        dist, (iy, ix) = ndi.distance_transform_edt(~self.free, return_indices=True)
        return dist * self.resolution, np.ravel_multi_index((iy, ix), self.shape)


# ---------------------------------------------------------------------------------------------- building


def _grid_resolution(world: World, cfg: CostMapConfig) -> float:
    terrain = world.terrain
    if cfg.resolution is not None:
        return float(cfg.resolution)
    spacing = max(terrain.dx, terrain.dy)
    coarsest = max(terrain.size_x, terrain.size_y) / (cfg.max_cells - 1)
    return max(spacing, coarsest)


def _pool_to_cells(
    layer: np.ndarray, world: World, cell_x: np.ndarray, cell_y: np.ndarray, resolution: float
) -> np.ndarray:
    """Worst terrain-sample value within each cell (the samples themselves when cells coincide with them).

    A cell of side ``resolution`` around ``c`` holds samples up to ``resolution / 2`` from ``c``, i.e. up to
    ``k = floor(resolution / (2 d) + 1/2)`` samples either side of the sample nearest to ``c``.
    """
    t = world.terrain
    k = [0 if abs(resolution - d) < 1e-9 else int(np.floor(resolution / (2.0 * d) + 0.5 + 1e-9)) for d in (t.dy, t.dx)]
    if any(k):
        layer = ndi.maximum_filter(layer, size=(2 * k[0] + 1, 2 * k[1] + 1), mode="nearest")
    ny, nx = t.shape
    ix = np.clip(np.rint((cell_x - t.x_min) / t.dx).astype(np.int64), 0, nx - 1)
    iy = np.clip(np.rint((cell_y - t.y_min) / t.dy).astype(np.int64), 0, ny - 1)
    return layer[np.ix_(iy, ix)]


def _obstacle_band(world: World, cell_x: np.ndarray, cell_y: np.ndarray, height: float, radius: float) -> np.ndarray:
    """Cells whose centre lies within ``radius`` of an obstacle taller than ``height``.

    The obstacle raster comes from :attr:`World.obstacle_map`; each raster sample stands for a square of side
    ``obstacle_resolution``, so half of that is added to the radius. The distance is measured to the exact
    position of the nearest lethal sample (``distance_transform_edt`` with indices), so the band is a true
    disc around obstacles even when the cost map is coarser than the raster.
    """
    shape = (len(cell_y), len(cell_x))
    if not world.obstacles:
        return np.zeros(shape, dtype=bool)
    om = world.obstacle_map
    lethal = om.height > height
    if not lethal.any():
        return np.zeros(shape, dtype=bool)
    _, (oy, ox) = ndi.distance_transform_edt(~lethal, return_indices=True)
    gx, gy = np.meshgrid(cell_x, cell_y)
    rny, rnx = om.height.shape
    rix = np.clip(np.rint((gx - om.x_min) / om.resolution).astype(np.int64), 0, rnx - 1)
    riy = np.clip(np.rint((gy - om.y_min) / om.resolution).astype(np.int64), 0, rny - 1)
    nearest_x = om.x_min + ox[riy, rix] * om.resolution
    nearest_y = om.y_min + oy[riy, rix] * om.resolution
    return np.hypot(gx - nearest_x, gy - nearest_y) <= radius + 0.5 * om.resolution


def build_costmap(world: World, robot: RobotConfig, cfg: CostMapConfig | None = None) -> CostMap:
    """The cost map of ``world`` for ``robot``.

    Slope margin: the hazard slope is the tilt of a plane fitted over the whole footprint, while the wheels
    meet shorter bumps, so planned paths would pitch nose-up past ``max_slope_deg`` without a margin; the default
    3 degrees keeps them under it at the price of a little of the map.

    Obstacle inflation uses ``robot.radius`` (the circle enclosing the footprint), not the half-width: the
    turn-then-drive controller turns in place at every waypoint, sweeping that whole circle, and the planner
    does not know the heading the robot will arrive with. Half a cell is added because smoothed paths run
    anywhere inside free cells, not only through their centres (without it planned paths grazed rocks in the
    kinematic model's collision check), and ``inflation_margin`` on top for whatever tracking error a controller
    has.
    """
    cfg = cfg or CostMapConfig()
    terrain = world.terrain
    res = _grid_resolution(world, cfg)
    x0, x1, y0, y1 = terrain.bounds
    nx = int(np.floor((x1 - x0) / res + 1e-9)) + 1
    ny = int(np.floor((y1 - y0) / res + 1e-9)) + 1
    cell_x, cell_y = x0 + np.arange(nx) * res, y0 + np.arange(ny) * res

    hz = terrain_hazards(terrain, robot.radius)
    slope_limit = cfg.slope_limit_deg if cfg.slope_limit_deg is not None else robot.max_slope_deg
    if slope_limit - cfg.slope_margin_deg <= 0.0:
        raise ConfigError(
            f"planning.slope_margin_deg: expected less than the slope limit ({slope_limit} deg), "
            f"got {cfg.slope_margin_deg}"
        )
    limits = {
        "slope_deg": slope_limit - cfg.slope_margin_deg,
        "step": cfg.step_limit if cfg.step_limit is not None else robot.max_step_height,
        "roughness": cfg.roughness_limit if cfg.roughness_limit is not None else robot.ground_clearance,
    }
    weights = {"slope_deg": cfg.slope_weight, "step": cfg.step_weight, "roughness": cfg.roughness_weight}
    layers: dict[str, np.ndarray] = {}
    cost = np.ones((ny, nx))
    lethal = np.zeros((ny, nx), dtype=bool)
    for key in ("slope_deg", "step", "roughness"):
        layer = _pool_to_cells(getattr(hz, key), world, cell_x, cell_y, res)
        layers[key] = layer
        limit = float(limits[key])
        if limit <= 0.0:  # a zero limit (e.g. max_step_height 0) only forbids, it cannot normalise
            lethal |= layer > 1e-9
            continue
        norm = layer / limit
        lethal |= norm > 1.0
        cost += weights[key] * np.minimum(norm, 1.0)

    obstacle_height = cfg.obstacle_height
    if obstacle_height is None:
        obstacle_height = min(robot.ground_clearance, robot.max_step_height)
    layers["obstacle"] = _obstacle_band(
        world, cell_x, cell_y, obstacle_height, robot.radius + 0.5 * res + cfg.inflation_margin
    )
    margin = robot.radius if cfg.border_margin is None else cfg.border_margin
    gx, gy = np.meshgrid(cell_x, cell_y)
    layers["border"] = ~terrain.contains(gx, gy, margin=margin)
    lethal |= layers["obstacle"] | layers["border"]
    cost[lethal] = np.inf
    return CostMap(cost=cost, resolution=res, x_min=x0, y_min=y0, layers=layers)


_SHARED: weakref.WeakKeyDictionary[World, dict[str, CostMap]] = weakref.WeakKeyDictionary()


def shared_costmap(world: World, robot: RobotConfig, cfg: CostMapConfig | None = None) -> CostMap:
    """:func:`build_costmap`, cached per world object and robot/config within the process.

    Every env of a vectorised set (and every evaluation env) in one process shares its world; without this
    each of them would rebuild the same cost map and its connected components (~0.3 s and ~4 MB each).
    The cost map is never modified after it is built, so sharing it is safe.
    """
    key = repr((robot, cfg))
    per_world = _SHARED.setdefault(world, {})
    if key not in per_world:
        per_world[key] = build_costmap(world, robot, cfg)
    return per_world[key]
