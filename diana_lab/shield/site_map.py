"""A map of the site made before the drive: what the shield's search assumes of ground its own map has not seen.

Why it exists: without one the detour's search (and the route rule, :mod:`diana_lab.shield.detour`) takes unseen
ground as drivable, the free-space assumption. On the Mars yard that sends the rover into pockets closed by
walls it cannot see from outside (docs/reference_policy.md, "The speed target's slow successes"). Rovers rarely
go in blind: a Mars rover's drives are planned on an orbital elevation model, and a competition yard can be surveyed
beforehand (the ERC 2022 yard's DEM this project ships is a public model of it, from the Leo Rover simulator).
With the site's heights, the search judges unseen ground by the same slope rule and slope cost as the ground it
has seen, and plans round walls before the rover meets them. Wherever the shield's map gives a slope (a cell and its
4 neighbours seen) it wins over the site map: the map is what the rover measured today; the site map fills in
the cells it gives none for, unseen ones and those beside unseen ground.

The site map is heights on a regular grid (numpy only: the onboard runtime loads it too). Its gradient is
taken once, by central differences, and read at the shield's map cells by the nearest site cell. How fine it
must be: a wall the search must see is a slope over the tilt check's limit across a few of the site's cells,
so a trench a metre wide needs cells of about 0.2 m; at 0.5 m or 1 m (an orbital model's) the yard's trenches
blur below the limit (docs/reference_policy.md, "Site map").
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MAX_SQUARES", "SiteMap"]

# the most squares a simulated world's site map may have (16 M: 4,000 x 4,000, ~0.4 GB with its gradient): a cell
# mistyped a hundred times too fine would otherwise take tens of GB before anything said so
MAX_SQUARES = 16_000_000
_BLOCK_SAMPLES = 2_000_000  # terrain samples taken at a time while building one (bounds the memory it takes)


def _width(cell: Any, where: str) -> float:
    """``cell`` as a positive finite width in metres, or a ValueError naming ``where``."""
    if isinstance(cell, bool) or not isinstance(cell, (int, float, np.integer, np.floating)):
        raise ValueError(f"{where}: cell: expected a positive width in metres, got {cell!r}")
    size = float(cell)
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"{where}: cell: expected a positive width in metres, got {cell!r}")
    return size


class SiteMap:
    """Heights of the site on a regular grid, with the gradient the shield's search reads.

    Args:
        heights: ``(ny, nx)`` heights (m), row ``iy`` at ``y = origin[1] + (iy + 0.5) * cell``, column ``ix`` at
            ``x = origin[0] + (ix + 0.5) * cell``: each value is the ground of one ``cell`` x ``cell`` square, in
            the frame the rover's pose estimate uses. At least 2 x 2, all finite.
        origin: world ``(x, y)`` of the grid's corner (the lower-left corner of cell ``[0, 0]``).
        cell: the squares' width (m, > 0).
    """

    def __init__(self, heights: Any, origin: Any, cell: float) -> None:
        size = _width(cell, "SiteMap")
        if np.iscomplexobj(heights) or np.iscomplexobj(origin):
            raise ValueError("SiteMap: expected real heights and origin, got complex numbers")
        try:
            h = np.array(heights, dtype=np.float64)
            o = np.asarray(origin, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"SiteMap: expected numeric heights and origin: {exc}") from exc
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"SiteMap: heights: expected a 2-D grid of at least 2 x 2 cells, got shape {h.shape}")
        if not np.all(np.isfinite(h)):
            bad = int(np.count_nonzero(~np.isfinite(h)))
            raise ValueError(f"SiteMap: heights: {bad} cells are NaN or infinite; expected finite heights")
        if o.shape != (2,) or not np.all(np.isfinite(o)):
            raise ValueError(f"SiteMap: origin: expected a finite world (x, y), got {origin!r}")
        self.heights, self.origin, self.cell = h, o, size
        self.heights.setflags(write=False)
        gy, gx = np.gradient(h, size)  # rise per metre along y (rows) and x (columns)
        self._gx, self._gy = gx, gy

    @classmethod
    def from_terrain(cls, terrain: Any, cell: float, samples: int = 4) -> SiteMap:
        """The site map of a simulated world's ``terrain`` (:class:`~diana_lab.sim.terrain.Terrain`): its heights
        averaged over ``cell``-wide squares (``samples`` x ``samples`` points each), the squares covering its
        bounds from their lower-left corner (a part square at the far edges is left out). The terrain only: a
        world's obstacles (the craters' rocks) are not in it. At most :data:`MAX_SQUARES` squares."""
        cell = _width(cell, "SiteMap.from_terrain")
        if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
            raise ValueError(f"SiteMap.from_terrain: samples: expected an integer >= 1, got {samples!r}")
        x_min, x_max, y_min, y_max = terrain.bounds
        nx = int(math.floor((x_max - x_min) / cell + 1e-9))
        ny = int(math.floor((y_max - y_min) / cell + 1e-9))
        if nx < 2 or ny < 2:
            raise ValueError(
                f"SiteMap.from_terrain: cell {cell} m leaves fewer than 2 x 2 squares on a "
                f"{x_max - x_min:g} x {y_max - y_min:g} m terrain"
            )
        if nx * ny > MAX_SQUARES:
            raise ValueError(
                f"SiteMap.from_terrain: cell {cell} m makes {nx} x {ny} squares on a {x_max - x_min:g} x "
                f"{y_max - y_min:g} m terrain; expected at most {MAX_SQUARES:,} (a coarser cell)"
            )
        within = (np.arange(samples) + 0.5) / samples * cell
        xs = x_min + (np.arange(nx)[:, None] * cell + within).ravel()
        ys = y_min + (np.arange(ny)[:, None] * cell + within).ravel()
        h = np.empty((ny, nx))
        rows = max(1, _BLOCK_SAMPLES // (len(xs) * samples))  # rows of squares a block
        for r0 in range(0, ny, rows):
            r1 = min(ny, r0 + rows)
            grid_x, grid_y = np.meshgrid(xs, ys[r0 * samples : r1 * samples])
            block = np.asarray(terrain.height(grid_x, grid_y)).reshape(r1 - r0, samples, nx, samples)
            h[r0:r1] = block.mean(axis=(1, 3))
        return cls(h, (x_min, y_min), cell)

    def gradient_at(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The site's rise per metre along x and y at world ``x, y`` (the cell holding each point), NaN off the
        map; arrays of ``x``'s shape."""
        ix = np.floor((np.asarray(x, dtype=np.float64) - self.origin[0]) / self.cell)
        iy = np.floor((np.asarray(y, dtype=np.float64) - self.origin[1]) / self.cell)
        ny, nx = self.heights.shape
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        jx = np.where(inside, ix, 0).astype(np.int64)
        jy = np.where(inside, iy, 0).astype(np.int64)
        return np.where(inside, self._gx[jy, jx], np.nan), np.where(inside, self._gy[jy, jx], np.nan)
