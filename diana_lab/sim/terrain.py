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
        x0, x1, y0, y1 = self.bounds
        x, y = np.asarray(x), np.asarray(y)
        return (x >= x0 + margin) & (x <= x1 - margin) & (y >= y0 + margin) & (y <= y1 - margin)

    # ------------------------------------------------------------------ queries
    def _locate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        ny, nx = self.shape
        gx = np.clip((np.asarray(x, dtype=np.float64) - self.x_min) / self.dx, 0.0, nx - 1.0)
        gy = np.clip((np.asarray(y, dtype=np.float64) - self.y_min) / self.dy, 0.0, ny - 1.0)
        ix = np.minimum(gx.astype(np.int64), nx - 2)
        iy = np.minimum(gy.astype(np.int64), ny - 2)
        return ix, iy, gx - ix, gy - iy

    def height(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Height of the triangulated surface at world ``(x, y)`` (vectorised; clamped at the edges)."""
        ix, iy, u, v = self._locate(x, y)
        h = self.heights
        a = h[iy, ix]
        b = h[iy, ix + 1]
        c = h[iy + 1, ix]
        d = h[iy + 1, ix + 1]
        lower = u + v <= 1.0
        return np.where(lower, a + u * (b - a) + v * (c - a), d + (1.0 - u) * (c - d) + (1.0 - v) * (b - d))

    def normal(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Unit surface normal(s) of the triangle under ``(x, y)``, shape ``(..., 3)``."""
        ix, iy, u, v = self._locate(x, y)
        h = self.heights
        a, b, c, d = h[iy, ix], h[iy, ix + 1], h[iy + 1, ix], h[iy + 1, ix + 1]
        lower = u + v <= 1.0
        dzdx = np.where(lower, b - a, d - c) / self.dx
        dzdy = np.where(lower, c - a, d - b) / self.dy
        n = np.stack([-dzdx, -dzdy, np.ones_like(dzdx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

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
