"""The same rays through PyBullet's ``rayTestBatch``: the reference the benchmark measures open3d against.

Not used by the env. The scene is ``world.scene_mesh`` as one static concave triangle mesh (terrain and
obstacles together, exactly what the open3d sensors cast against), in a private DIRECT client, so the two
casters answer the same question and can be timed side by side:

    ref = PyBulletRayCaster(world)
    origins, directions = sensor.rays_world(position, rpy)
    ranges = ref.cast(origins, directions, sensor.cfg.max_range)   # NaN where nothing was hit
    ref.close()
"""

from __future__ import annotations

import numpy as np

from diana_lab.sim.world import World

__all__ = ["PyBulletRayCaster", "cast_rays_pybullet"]

BATCH = 16384  # rays per rayTestBatch call (pybullet's MAX_RAY_INTERSECTION_BATCH_SIZE)


class PyBulletRayCaster:
    """A DIRECT PyBullet client holding ``world.scene_mesh`` as one static body."""

    def __init__(self, world: World, num_threads: int = 1) -> None:
        import pybullet as p

        self._p = p
        self.num_threads = int(num_threads)
        self.client = p.connect(p.DIRECT)
        vertices, triangles = world.scene_mesh
        shape = p.createCollisionShape(
            p.GEOM_MESH,
            vertices=np.asarray(vertices, dtype=np.float64).tolist(),
            indices=np.asarray(triangles, dtype=np.int64).reshape(-1).tolist(),
            flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
            physicsClientId=self.client,
        )
        if shape < 0:
            p.disconnect(self.client)
            raise RuntimeError(f"pybullet could not create the scene mesh of world '{world.name}'")
        p.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape, physicsClientId=self.client)

    def cast(self, origins: np.ndarray, directions: np.ndarray, max_range: float) -> np.ndarray:
        """Range along each unit ``direction`` from ``origins`` up to ``max_range``; NaN without a hit."""
        p = self._p
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        ends = origins + np.asarray(directions, dtype=np.float64).reshape(-1, 3) * max_range
        fractions = np.empty(len(origins))
        for start in range(0, len(origins), BATCH):
            stop = start + BATCH
            hits = p.rayTestBatch(origins[start:stop].tolist(), ends[start:stop].tolist(),
                                  numThreads=self.num_threads, physicsClientId=self.client)
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


def cast_rays_pybullet(world: World, origins: np.ndarray, directions: np.ndarray, max_range: float) -> np.ndarray:
    """One-off convenience: build the PyBullet scene, cast, close (time :class:`PyBulletRayCaster` instead)."""
    with PyBulletRayCaster(world) as ref:
        return ref.cast(origins, directions, max_range)
