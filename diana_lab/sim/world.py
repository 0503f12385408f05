"""World: a terrain plus static obstacle bodies, with the queries every other part needs.

A world is pure data (numpy arrays); simulators (PyBullet, open3d ray casting) build their own
views of it, so a world is cheap to pickle into ``SubprocVecEnv`` workers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from diana_lab.sim.terrain import Terrain

__all__ = ["Obstacle", "ObstacleMap", "World"]


@dataclass(eq=False)
class Obstacle:
    """A static rigid body in world coordinates (a rock, or a mesh the user supplies)."""

    vertices: np.ndarray  # (V, 3) float, world frame
    triangles: np.ndarray  # (T, 3) int
    name: str = "obstacle"
    convex: bool = True  # convex bodies get a convex-hull collision shape in PyBullet

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.asarray(self.triangles, dtype=np.int32).reshape(-1, 3)
        if len(self.vertices) < 4 or len(self.triangles) < 4:
            raise ValueError(f"obstacle '{self.name}': expected a closed mesh with at least 4 faces")
        if not np.all(np.isfinite(self.vertices)):
            raise ValueError(f"obstacle '{self.name}': vertices contain NaN or infinite values")

    @property
    def centre(self) -> np.ndarray:
        return self.vertices.mean(axis=0)


@dataclass(eq=False)
class ObstacleMap:
    """Obstacle tops rasterised on a regular grid (``height[iy, ix]`` above the terrain, 0 where free).

    The grid uses the terrain's convention (rows along +y, centred on the origin) at its own resolution.
    """

    height: np.ndarray
    resolution: float
    x_min: float
    y_min: float

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        ny, nx = self.height.shape
        ix = np.clip(np.rint((np.asarray(x) - self.x_min) / self.resolution).astype(np.int64), 0, nx - 1)
        iy = np.clip(np.rint((np.asarray(y) - self.y_min) / self.resolution).astype(np.int64), 0, ny - 1)
        return self.height[iy, ix]

    @cached_property
    def clearance(self) -> np.ndarray:
        """Distance (m) from every cell to the nearest obstacle cell taller than 1 cm (inf without any)."""
        from scipy.ndimage import distance_transform_edt

        occupied = self.height > 0.01
        if not occupied.any():
            return np.full(self.height.shape, np.inf)
        return distance_transform_edt(~occupied) * self.resolution

    def clearance_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        ny, nx = self.height.shape
        ix = np.clip(np.rint((np.asarray(x) - self.x_min) / self.resolution).astype(np.int64), 0, nx - 1)
        iy = np.clip(np.rint((np.asarray(y) - self.y_min) / self.resolution).astype(np.int64), 0, ny - 1)
        return self.clearance[iy, ix]


@dataclass(eq=False)
class World:
    """Terrain, obstacles and a name; built by :mod:`diana_lab.sim.worlds` from the ``world`` config."""

    name: str
    terrain: Terrain
    obstacles: list[Obstacle] = field(default_factory=list)
    seed: int = 0
    obstacle_resolution: float = 0.1

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self.terrain.bounds

    def height(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Terrain height (obstacles excluded) at world ``(x, y)``, vectorised."""
        return self.terrain.height(x, y)

    @cached_property
    def scene_mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """One triangle mesh of the whole static scene, ``(vertices float32, triangles int32)``."""
        vertices, triangles = self.terrain.mesh
        parts_v, parts_t, offset = [vertices], [triangles], len(vertices)
        for ob in self.obstacles:
            parts_v.append(ob.vertices.astype(np.float32))
            parts_t.append(ob.triangles + offset)
            offset += len(ob.vertices)
        return np.concatenate(parts_v), np.concatenate(parts_t).astype(np.int32)

    @cached_property
    def obstacle_map(self) -> ObstacleMap:
        """Obstacle tops above the terrain, found by casting rays straight down onto the obstacle meshes."""
        res = self.obstacle_resolution
        x0, x1, y0, y1 = self.bounds
        nx, ny = int(round((x1 - x0) / res)) + 1, int(round((y1 - y0) / res)) + 1
        height = np.zeros((ny, nx), dtype=np.float32)
        if self.obstacles:
            import open3d as o3d

            scene = o3d.t.geometry.RaycastingScene()
            for ob in self.obstacles:
                scene.add_triangles(ob.vertices.astype(np.float32), ob.triangles.astype(np.uint32))
            lo = np.min([ob.vertices.min(0) for ob in self.obstacles], axis=0)
            hi = np.max([ob.vertices.max(0) for ob in self.obstacles], axis=0)
            ix0, ix1 = (
                np.clip(np.floor((lo[0] - x0) / res), 0, nx - 1).astype(int),
                np.clip(np.ceil((hi[0] - x0) / res), 0, nx - 1).astype(int),
            )
            iy0, iy1 = (
                np.clip(np.floor((lo[1] - y0) / res), 0, ny - 1).astype(int),
                np.clip(np.ceil((hi[1] - y0) / res), 0, ny - 1).astype(int),
            )
            gx, gy = np.meshgrid(x0 + np.arange(ix0, ix1 + 1) * res, y0 + np.arange(iy0, iy1 + 1) * res)
            top = float(hi[2]) + 1.0
            rays = np.zeros((gx.size, 6), dtype=np.float32)
            rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 5] = gx.ravel(), gy.ravel(), top, -1.0
            t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            hit = np.isfinite(t_hit)
            z_top = np.where(hit, top - t_hit, -np.inf)
            above = np.maximum(z_top - self.terrain.height(gx.ravel(), gy.ravel()), 0.0)
            height[iy0 : iy1 + 1, ix0 : ix1 + 1] = np.where(hit, above, 0.0).reshape(gx.shape)
        return ObstacleMap(height=height, resolution=res, x_min=x0, y_min=y0)
