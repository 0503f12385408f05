"""Casting one fixed bundle of rays against a world's static scene, with one of two backends.

``backend="heightfield"`` (the default) is the exact numba ray marcher of
:mod:`diana_lab.sensing.heightfield_cast`: it walks the terrain grid and tests the obstacle meshes, on one
thread, and stops rays at ``max_range``. ``backend="open3d"`` casts against ``World.scene_mesh`` with
open3d's ``RaycastingScene`` (Embree), the reference it is tested against. Both return the same ranges.

Why it looks the way it does:

* Neither scene travels with the caster: ``SubprocVecEnv`` pickles the env (and so its sensor) into each
  worker, and the Embree scene behind ``RaycastingScene`` cannot be pickled. The scene is therefore built
  lazily on first use, dropped by ``__getstate__``, and shared by every caster of the same :class:`World`
  object in one process (a weak-key cache, so it goes away with the world).
* The ray directions are fixed in the rover frame; a frame only rotates them and sets the origin. The
  heightfield kernel does that itself, ray by ray (``HeightfieldScene.cast_pose``: no ``(N, 6)`` array is
  built per frame); for open3d (and :meth:`RayCaster.rays`) ``heightfield_cast.pose_rays`` writes the very
  same float32 rays, bit for bit, into one ``(N, 6)`` buffer that an open3d tensor views without copying
  (``Tensor.from_numpy``), so both backends cast the same rays.
* ``nthreads=1`` by default for open3d: vectorised envs already run one env per core, and more threads per
  cast only contend with them. The heightfield kernel is always single-threaded.
"""

from __future__ import annotations

import math
import weakref
from typing import TYPE_CHECKING, Any

import numpy as np
import open3d as o3d

from diana_lab.config.sensing import BACKENDS
from diana_lab.core.validation import one_of
from diana_lab.sim.world import World

if TYPE_CHECKING:  # imported on first use: numba takes ~0.3 s to import, and encoders-only users never cast
    from diana_lab.sensing.heightfield_cast import HeightfieldScene
    from diana_lab.sensing.pinhole import Pinhole

__all__ = ["RayCaster", "scene_for"]

_SCENES: weakref.WeakKeyDictionary[World, o3d.t.geometry.RaycastingScene] = weakref.WeakKeyDictionary()


def scene_for(world: World, nthreads: int = 1) -> o3d.t.geometry.RaycastingScene:
    """The (cached) ray-casting scene of ``world.scene_mesh``: terrain and obstacles as one mesh."""
    scene = _SCENES.get(world)
    if scene is None:
        vertices, triangles = world.scene_mesh
        scene = o3d.t.geometry.RaycastingScene(nthreads=nthreads)
        scene.add_triangles(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(vertices, dtype=np.float32)),
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(triangles, dtype=np.uint32)),
        )
        _SCENES[world] = scene
    return scene


class RayCaster:
    """Casts ``directions`` (unit vectors in the rover frame, ``(N, 3)``) from a moving sensor.

    :meth:`cast` returns the hit distance along every ray (``inf`` where nothing was hit); with unit
    directions that is the range. ``backend`` is ``"heightfield"`` or ``"open3d"`` (see the module);
    ``max_range`` lets the heightfield backend stop rays early (hits beyond it come back as ``inf``; open3d
    casts to infinity either way, and the sensor discards returns beyond its range itself). ``pinhole``: the
    camera whose pixel rays ``directions`` are (checked here), which lets the heightfield backend rasterise the
    terrain near the sensor (the same ranges, faster); open3d has no use for it.
    """

    def __init__(
        self,
        world: World,
        directions: np.ndarray,
        nthreads: int = 1,
        backend: str = "heightfield",
        max_range: float = math.inf,
        pinhole: Pinhole | None = None,
    ) -> None:
        one_of("sensor.backend", backend, BACKENDS)
        self.world = world
        self.nthreads = int(nthreads)
        self.backend = backend
        self.max_range = float(max_range)
        self.directions = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        self.directions.setflags(write=False)
        if pinhole is not None:
            pinhole.check(self.directions)
        self.pinhole = pinhole
        self._rays = np.zeros((len(self.directions), 6), dtype=np.float32)
        self._scene: o3d.t.geometry.RaycastingScene | HeightfieldScene | None = None
        self._rays_t: o3d.core.Tensor | None = None

    def __len__(self) -> int:
        return len(self.directions)

    # ------------------------------------------------------------------ pickling (SubprocVecEnv)
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_scene"] = None
        state["_rays_t"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    # ------------------------------------------------------------------ casting
    def rays(self, origin: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Fill the ray buffer for a sensor at world ``origin`` whose rover frame has world ``rotation``.

        Returns the buffer itself, ``(N, 6)`` = origin xyz, direction xyz (overwritten by the next call).
        """
        from diana_lab.sensing.heightfield_cast import pose_rays

        return pose_rays(self.directions, _f64(origin), _f64(rotation), self._rays)

    def cast(self, origin: np.ndarray, rotation: np.ndarray, min_range: float | None = None) -> np.ndarray:
        """Hit distance of every ray, ``(N,)`` float32, ``inf`` for no hit (a fresh array). With ``min_range``:
        a sensor's ranges, NaN for no hit and outside ``[min_range, max_range]`` (compared in float32)."""
        if self.backend == "heightfield":
            return self._heightfield().cast_pose(
                self.directions, _f64(origin), _f64(rotation), self.max_range, min_range, self.pinhole
            )
        self.rays(origin, rotation)
        if self._scene is None:
            self._scene = scene_for(self.world, self.nthreads)
        if self._rays_t is None:
            self._rays_t = o3d.core.Tensor.from_numpy(self._rays)
        t = self._scene.cast_rays(self._rays_t, nthreads=self.nthreads)["t_hit"].numpy()
        if min_range is not None:
            np.putmask(t, (t < min_range) | (t > self.max_range), np.float32(np.nan))
        return t

    def cast_frame(
        self, origin: np.ndarray, rotation: np.ndarray, min_range: float, mount: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`cast` with ``min_range``, and the returns as a point cloud in the rover frame, ``(M, 3)``
        float32 ``directions * range + mount`` (``mount (3,)`` float32: the sensor's position on the rover),
        when the backend writes it during the cast (heightfield); ``None`` otherwise (open3d: the frame
        computes it from the ranges on demand, to the same bits)."""
        if self.backend == "heightfield":
            scene = self._heightfield()
            return scene.cast_frame(
                self.directions, _f64(origin), _f64(rotation), mount, self.max_range, min_range, self.pinhole
            )
        return self.cast(origin, rotation, min_range), None

    def _heightfield(self) -> HeightfieldScene:
        if self._scene is None:
            from diana_lab.sensing.heightfield_cast import heightfield_for

            self._scene = heightfield_for(self.world)
        return self._scene  # type: ignore[return-value]


def _f64(a: np.ndarray) -> np.ndarray:
    return a if type(a) is np.ndarray and a.dtype == np.float64 else np.asarray(a, dtype=np.float64)
