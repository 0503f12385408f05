"""The same rays through PyBullet's ``rayTestBatch``: the reference the benchmark measures open3d against.

Not used by the env. By default the scene is ``world.scene_mesh`` as one static concave triangle mesh
(terrain and obstacles together, exactly what the open3d sensors cast against; the two agree to ~1e-5 m).
``terrain="heightfield"`` loads the terrain as a Bullet heightfield instead (what a PyBullet simulation
uses; obstacles stay meshes): same triangles, but Bullet's heightfield ray test is slower and misses a few
grazing rays, so use it for timing, not as ground truth. A private DIRECT client keeps it apart from any
simulation in the process:

    ref = PyBulletRayCaster(world)
    origins, directions = sensor.rays_world(position, rpy)
    ranges = ref.cast(origins, directions, sensor.cfg.max_range)   # NaN where nothing was hit
    ref.close()
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from diana_lab.sim.world import World

__all__ = ["PyBulletRayCaster", "cast_rays_pybullet"]

BATCH = 16384  # rays per rayTestBatch call (pybullet's MAX_RAY_INTERSECTION_BATCH_SIZE)


class PyBulletRayCaster:
    """A DIRECT PyBullet client holding ``world.scene_mesh`` as one static body."""

    def __init__(self, world: World, terrain: Literal["mesh", "heightfield"] = "mesh", num_threads: int = 1) -> None:
        import pybullet as p

        if terrain not in ("mesh", "heightfield"):
            raise ValueError(f"terrain: expected 'mesh' or 'heightfield', got {terrain!r}")
        self._p = p
        self.num_threads = int(num_threads)
        self.client: int | None = p.connect(p.DIRECT)
        if terrain == "mesh":
            self._add_mesh(*world.scene_mesh)
        else:
            t = world.terrain
            ny, nx = t.shape
            shape = p.createCollisionShape(
                p.GEOM_HEIGHTFIELD,
                meshScale=[t.dx, t.dy, 1.0],
                heightfieldData=t.heights.ravel().tolist(),
                numHeightfieldRows=nx,
                numHeightfieldColumns=ny,
                physicsClientId=self.client,
            )
            # Bullet centres a heightfield between its lowest and highest sample
            p.createMultiBody(
                0.0,
                shape,
                basePosition=[0.0, 0.0, (t.min_height + t.max_height) / 2.0],
                physicsClientId=self.client,
            )
            for ob in world.obstacles:
                self._add_mesh(ob.vertices, ob.triangles)

    def _add_mesh(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        p = self._p
        shape = p.createCollisionShape(
            p.GEOM_MESH,
            vertices=np.asarray(vertices, dtype=np.float64).tolist(),
            indices=np.asarray(triangles, dtype=np.int64).reshape(-1).tolist(),
            flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
            physicsClientId=self.client,
        )
        if shape < 0:
            self.close()
            raise RuntimeError("pybullet could not create a collision mesh of the scene")
        p.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape, physicsClientId=self.client)

    def cast(self, origins: np.ndarray, directions: np.ndarray, max_range: float) -> np.ndarray:
        """Range along each unit ``direction`` from ``origins`` up to ``max_range``; NaN without a hit."""
        p = self._p
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        ends = origins + np.asarray(directions, dtype=np.float64).reshape(-1, 3) * max_range
        fractions = np.empty(len(origins))
        for start in range(0, len(origins), BATCH):
            stop = start + BATCH
            hits = p.rayTestBatch(
                origins[start:stop].tolist(),
                ends[start:stop].tolist(),
                numThreads=self.num_threads,
                physicsClientId=self.client,
            )
            fractions[start:stop] = [h[2] if h[0] >= 0 else np.nan for h in hits]
        return fractions * max_range

    def close(self) -> None:
        if self.client is not None and self._p.isConnected(self.client):
            self._p.disconnect(self.client)
        self.client = None

    def __enter__(self) -> PyBulletRayCaster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def cast_rays_pybullet(
    world: World,
    origins: np.ndarray,
    directions: np.ndarray,
    max_range: float,
    terrain: Literal["mesh", "heightfield"] = "mesh",
) -> np.ndarray:
    """One-off: build the PyBullet scene, cast, close (to time, use :class:`PyBulletRayCaster`)."""
    with PyBulletRayCaster(world, terrain) as ref:
        return ref.cast(origins, directions, max_range)
