"""Terrain: a regular elevation grid with one triangulated surface.

Grid convention (stated here, once, and pinned by ``tests/sim/test_terrain.py``):

* ``heights[iy, ix]`` is the height of the sample at world ``x = x_min + ix * dx``, ``y = y_min + iy * dy``;
  rows run along +y, columns along +x, and the grid is centred on the world origin.
* Image files (DEM tif/png) store their first row at the *top* of the picture, i.e. the +y (north) edge, as a
  Gazebo heightmap does; :func:`grid_from_image` flips them once so that the rule above holds.

Every height query uses the same two triangles per cell as :meth:`Terrain.mesh` (split along the diagonal
from ``(ix + 1, iy)`` to ``(ix, iy + 1)``, as Bullet's heightfield does), so what the sensors ray-cast, what
the kinematic model stands on and what PyBullet collides with is one surface.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

__all__ = ["Terrain", "grid_from_image"]


def grid_from_image(image: np.ndarray) -> np.ndarray:
    """Turn an image-ordered elevation array (row 0 = north edge) into the grid order used here."""
    return np.ascontiguousarray(np.asarray(image, dtype=np.float64)[::-1, :])


@dataclass(eq=False)
class Terrain:
    """A height grid of ``ny x nx`` samples spanning ``size_x x size_y`` metres, centred on the origin."""

    heights: np.ndarray
    size_x: float
    size_y: float
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        h = np.asarray(self.heights, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError(f"terrain heights: expected a 2-D grid of at least 2 x 2 samples, got {h.shape}")
        if not np.all(np.isfinite(h)):
            bad = int(np.count_nonzero(~np.isfinite(h)))
            raise ValueError(f"terrain heights: {bad} cells are NaN or infinite; expected finite heights")
        if not (self.size_x > 0 and self.size_y > 0):
            raise ValueError(f"terrain size: expected positive sizes, got {self.size_x} x {self.size_y}")
        self.heights = np.ascontiguousarray(h)
        self.heights.setflags(write=False)

    # ------------------------------------------------------------------ geometry of the grid
    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape  # (ny, nx)

    @property
    def dx(self) -> float:
        return self.size_x / (self.shape[1] - 1)

    @property
    def dy(self) -> float:
        return self.size_y / (self.shape[0] - 1)

    @property
    def x_min(self) -> float:
        return -self.size_x / 2.0

    @property
    def y_min(self) -> float:
        return -self.size_y / 2.0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` in metres."""
        return (-self.size_x / 2.0, self.size_x / 2.0, -self.size_y / 2.0, self.size_y / 2.0)

    @property
    def min_height(self) -> float:
        return float(self.heights.min())

    @property
    def max_height(self) -> float:
        return float(self.heights.max())

    def cell_xy(self, ix: np.ndarray | int, iy: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates of grid samples."""
        return self.x_min + np.asarray(ix) * self.dx, self.y_min + np.asarray(iy) * self.dy

    def contains(self, x: np.ndarray | float, y: np.ndarray | float, margin: float = 0.0) -> np.ndarray:
        # the grid is centred on the origin, so x_min + margin <= x <= x_max - margin is |x| <= x_max - margin
        # (exactly: rounding is symmetric); written so that NaN is outside
        inside_x = np.abs(x) <= self.size_x / 2.0 - margin
        return np.logical_and(inside_x, np.abs(y) <= self.size_y / 2.0 - margin)

    # ------------------------------------------------------------------ queries
    # The queries work on points stacked as one (2, N) array (x, then y): both axes take one numpy call per
    # step instead of two. On the few hundred points of a kinematic waypoint the calls cost more than the
    # arithmetic, and env steps make ~1,000 such queries a second.
    @staticmethod
    def _stack(x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, tuple[int, ...]]:
        """``(x, y)`` broadcast together as one ``(2, N)`` array, and the shape they broadcast to."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if x.shape != y.shape:
            x, y = np.broadcast_arrays(x, y)
        return np.array([x, y]).reshape(2, -1), x.shape

    @cached_property
    def _grid_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(2, 1)`` columns (x, then y) of the first sample's coordinate, the spacing, the last sample index
        and the last cell index."""
        ny, nx = self.shape
        return (
            np.array([[self.x_min], [self.y_min]]),
            np.array([[self.dx], [self.dy]]),
            np.array([[nx - 1.0], [ny - 1.0]]),
            np.array([[nx - 2], [ny - 2]]),
        )

    def _locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cell ``(ix, iy)`` and offsets ``(u, v)`` in it, ``(2, N)`` each, of points ``xy (2, N)``; points off
        the grid are clamped onto its edge."""
        origin, step, last, last_cell = self._grid_axes
        g = (xy - origin) / step
        np.minimum(np.maximum(g, 0.0, out=g), last, out=g)  # np.clip without its Python wrapper
        cell = np.minimum(g.astype(np.int64), last_cell)
        return cell, np.subtract(g, cell, out=g)

    @cached_property
    def _triangle_corners(self) -> tuple[np.ndarray, np.ndarray]:
        """Flat-index offsets ``(3, 1)`` from a cell's first sample ``a`` at ``(ix, iy)`` to the corners of its
        lower triangle (``u + v <= 1``: ``a, b, c``) and of its upper one (``d, c, b``), where ``b`` is at
        ``(ix + 1, iy)``, ``c`` at ``(ix, iy + 1)`` and ``d`` at ``(ix + 1, iy + 1)``."""
        nx = self.shape[1]
        return np.array([[0], [1], [nx]]), np.array([[nx + 1], [nx], [1]])

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """:meth:`height` of points ``xy (2, N)`` (x, then y), ``(N,)``.

        The lower triangle interpolates ``a + u (b - a) + v (c - a)``, the upper ``d + (1 - u)(c - d) +
        (1 - v)(b - d)``: the same formula from the opposite corner. So each point gathers its own triangle's
        three corners (one ``take``) and weights, and evaluates the formula once instead of both.
        """
        (ix, iy), uv = self._locate(np.asarray(xy, dtype=np.float64))
        lower = uv[0] + uv[1] <= 1.0
        lower_corners, upper_corners = self._triangle_corners
        corners = iy * self.shape[1] + ix + np.where(lower, lower_corners, upper_corners)
        h = self.heights.ravel().take(corners)  # (3, N): the base corner, then the two others
        rise = h[1:] - h[0]
        rise *= np.where(lower, uv, 1.0 - uv)
        return h[0] + rise[0] + rise[1]

    def height(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Height of the triangulated surface at world ``(x, y)`` (vectorised; clamped at the edges)."""
        xy, shape = self._stack(x, y)
        return self.height_at(xy).reshape(shape)

    def normal(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Unit surface normal(s) of the triangle under ``(x, y)``, shape ``(..., 3)``."""
        xy, shape = self._stack(x, y)
        (ix, iy), (u, v) = self._locate(xy)
        h = self.heights
        a, b, c, d = h[iy, ix], h[iy, ix + 1], h[iy + 1, ix], h[iy + 1, ix + 1]
        lower = u + v <= 1.0
        dzdx = np.where(lower, b - a, d - c) / self.dx
        dzdy = np.where(lower, c - a, d - b) / self.dy
        n = np.stack([-dzdx, -dzdy, np.ones_like(dzdx)], axis=-1)
        return (n / np.linalg.norm(n, axis=-1, keepdims=True)).reshape((*shape, 3))

    @cached_property
    def slope_deg(self) -> np.ndarray:
        """Per-sample slope in degrees (central differences), the grid planners and samplers use."""
        gy, gx = np.gradient(self.heights, self.dy, self.dx)
        return np.degrees(np.arctan(np.hypot(gx, gy)))

    # ------------------------------------------------------------------ mesh
    @cached_property
    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """``(vertices (ny*nx, 3) float32, triangles (2*(ny-1)*(nx-1), 3) int32)`` of the surface."""
        ny, nx = self.shape
        xs = self.x_min + np.arange(nx) * self.dx
        ys = self.y_min + np.arange(ny) * self.dy
        gx, gy = np.meshgrid(xs, ys)
        vertices = np.stack([gx, gy, self.heights], axis=-1).reshape(-1, 3).astype(np.float32)
        idx = np.arange(ny * nx, dtype=np.int32).reshape(ny, nx)
        a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        # counter-clockwise seen from above, so normals point up
        triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]).astype(np.int32)
        return vertices, triangles
