"""Exact ray casting against a heightfield terrain plus obstacle meshes, compiled with numba (one thread).

Why it exists: the sensor targets (a 64 x 48 depth frame to ``depth_image`` in 0.3 ms, 112 x 112 in 2 ms,
one core) cannot be met with open3d's ``RaycastingScene``: ``cast_rays`` takes 0.54-0.69 ms for the 3,072
rays against the 131k-triangle Mars yard and ~0.15 ms even against a 2-triangle plane (per-call floor). The
terrain is a regular grid, so a walk through its cells finds the few triangles a ray can hit without any
acceleration structure: it casts a 64 x 48 frame on the yard in about half open3d's time (the timings, and what
did not help: docs/implementation_notes.md). A depth camera's frame goes faster still: the terrain near the
sensor, where most of its rays end, is rasterised into the image with this walk's own tests
(:mod:`diana_lab.sensing.pinhole_raster`, the same ranges bit for bit), and only the rays that hit nothing there
are walked, from where they leave it.

Exact: it intersects the very triangles of ``World.scene_mesh`` (the two per cell of :attr:`Terrain.mesh`,
split from ``(ix + 1, iy)`` to ``(ix, iy + 1)``, at the mesh's float32 vertex coordinates; the obstacles'
own triangles) in float64 and returns the nearest hit, so distances agree with open3d (float32 Embree) to
its rounding. Obstacle triangles use Moller-Trumbore. A terrain triangle is hit where the ray crosses its
plane inside the ray's interval over the cell and on the triangle's side of the diagonal: the same
intersection, and watertight, since neighbouring cells share the interval ends and the diagonal test.
Only the *order* of the tests is clever:

* a ray is clipped to the map's box, the terrain's height range and the maximum range;
* cells are walked in ray order (Amanatides-Woo) and the walk stops at the first cell whose triangles are
  hit. Cell edges are the mesh's own vertex coordinates, so a cell's ray interval is exactly the part of
  the ray over its two triangles;
* a cell the ray passes above (its highest corner lower than the ray at both ends of the interval) costs
  one comparison, and so does a block of ``2**shift x 2**shift`` cells (a 2-level max mipmap): rays above
  the terrain cross a block per step (blocks are walked by their own DDA; a ray entering a block through an
  x edge knows its column there, and only its row is looked up, and vice versa);
* obstacles are cast first, in their own pass (only worlds that have any pay for it): those whose bounding
  sphere is out of range of the sensor are dropped once per sensor position, the others are tested with
  their bounding sphere and box and then triangle by triangle; the terrain walk then stops at that hit.

Rays come either as an ``(N, 6)`` array (:meth:`HeightfieldScene.cast`) or as a pose
(:meth:`HeightfieldScene.cast_pose`): the sensor's fixed body-frame directions, a rotation and an origin, the
kernels rotating each direction as they go, so a frame builds no ray array (and, given ``min_range``, they also
write the sensor's NaN for no return, so the frame needs no masking pass, and :meth:`HeightfieldScene.cast_frame`
has them write the frame's point cloud too). :func:`pose_rays` writes those very
rays (bit for bit) for the casters that need an array (open3d, PyBullet). The two forms are compiled apart
(``None`` arguments), so neither pays for the other.

What measurement taught (numba specifics): a call passing arrays costs ~70 ns a ray in reference counting
(so the kernels are single functions with scalar-only helpers); the tests' divisions and early exits sat on
the walk's critical path, so the terrain test decides with products only (branch-free, divides once for a
hit) and Moller-Trumbore combines its tests with ``&``; numba wraps negative indices on every access with a
signed index (two or three instructions each), so the terrain kernel indexes with :func:`_u` (unsigned),
which alone made it ~9% faster.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from diana_lab.sensing.heightfield_kernels import cast_obstacles, cast_terrain, pose_rays
from diana_lab.sim.world import World

if TYPE_CHECKING:
    from diana_lab.sensing.pinhole import Pinhole

__all__ = [
    "BLOCK_SHIFT",
    "HeightfieldScene",
    "cast_obstacles",
    "cast_terrain",
    "heightfield_for",
    "pose_rays",
]


BLOCK_SHIFT = 3  # blocks of 8 x 8 cells (1.56 m on the Mars yard)


@dataclass(eq=False)
class HeightfieldScene:
    """The arrays the kernels read: plain numpy, so picklable; built once per world by :func:`heightfield_for`.

    Terrain: ``xs (nx,)`` and ``ys (ny,)`` the vertex coordinates and ``heights`` the ``(ny * nx,)`` vertex
    heights (row-major, ``iy * nx + ix``) of :attr:`Terrain.mesh` (float32 values, as float64);
    ``cell_max (ny-1) * (nx-1)`` and ``block_max`` the highest corner of every cell and block (row-major),
    and ``z_range`` the lowest and highest vertex, all widened by a rounding margin.
    Obstacles: all their vertices and triangles (indices into ``ob_vertices``), ``ob_start (n+1,)`` the
    first triangle of each, ``ob_box (n, 6)`` their bounding boxes (lo xyz, hi xyz) and ``ob_sphere
    (n, 4)`` bounding spheres (centre xyz, radius).
    """

    xs: np.ndarray
    ys: np.ndarray
    heights: np.ndarray
    cell_max: np.ndarray
    block_max: np.ndarray
    block_cols: int
    shift: int
    z_range: np.ndarray  # (2,) lowest and highest terrain vertex (widened by the margin)
    ob_vertices: np.ndarray
    ob_triangles: np.ndarray
    ob_start: np.ndarray
    ob_box: np.ndarray
    ob_sphere: np.ndarray
    min_cell: float  # the narrowest cell's width or depth (m)

    @classmethod
    def from_world(cls, world: World, shift: int = BLOCK_SHIFT) -> HeightfieldScene:
        ny, nx = world.terrain.shape
        vertices, _ = world.terrain.mesh  # float32: exactly the coordinates open3d casts against
        grid = vertices.reshape(ny, nx, 3).astype(np.float64)
        xs, ys, heights = grid[0, :, 0].copy(), grid[:, 0, 1].copy(), np.ascontiguousarray(grid[:, :, 2])
        if not (np.all(np.diff(xs) > 0) and np.all(np.diff(ys) > 0)):
            raise ValueError("heightfield cast: terrain vertex coordinates are not strictly increasing")
        # the skip tests compare the ray's height at the ends of an interval, computed in float64, with these
        # maxima: a margin far above that rounding (and far below any distance that matters) keeps a ray
        # that touches a cell's highest corner exactly (a flat plane's every hit) from skipping it
        eps = 1e-9 * (1.0 + float(np.abs(heights).max()))
        cell_max = np.maximum.reduce([heights[:-1, :-1], heights[:-1, 1:], heights[1:, :-1], heights[1:, 1:]]) + eps
        b = 1 << shift
        ncy, ncx = cell_max.shape
        nby, nbx = -(-ncy // b), -(-ncx // b)
        padded = np.full((nby * b, nbx * b), -np.inf)
        padded[:ncy, :ncx] = cell_max
        block_max = padded.reshape(nby, b, nbx, b).max(axis=(1, 3))

        obs = world.obstacles
        parts_v, parts_t, start, boxes, spheres, offset = [], [], [0], [], [], 0
        for ob in obs:
            v = ob.vertices.astype(np.float32).astype(np.float64)  # as in World.scene_mesh
            parts_v.append(v)
            parts_t.append(ob.triangles.astype(np.int64) + offset)
            offset += len(v)
            start.append(start[-1] + len(ob.triangles))
            lo, hi = v.min(axis=0), v.max(axis=0)
            centre = (lo + hi) / 2.0
            radius = float(np.sqrt(((v - centre) ** 2).sum(axis=1)).max())
            boxes.append(np.concatenate([lo, hi]))
            spheres.append([*centre, radius * (1.0 + 1e-9) + 1e-9])  # a hair larger: rounding never culls a hit
        return cls(
            xs=xs,
            ys=ys,
            heights=heights.ravel(),
            cell_max=np.ascontiguousarray(cell_max).ravel(),
            block_max=np.ascontiguousarray(block_max).ravel(),
            block_cols=int(nbx),
            shift=int(shift),
            z_range=np.array([heights.min() - eps, heights.max() + eps]),
            ob_vertices=np.ascontiguousarray(np.concatenate(parts_v)) if obs else np.zeros((0, 3)),
            ob_triangles=np.ascontiguousarray(np.concatenate(parts_t)) if obs else np.zeros((0, 3), np.int64),
            ob_start=np.array(start, dtype=np.int64),
            ob_box=np.array(boxes, dtype=np.float64).reshape(-1, 6),
            ob_sphere=np.array(spheres, dtype=np.float64).reshape(-1, 4),
            min_cell=float(min(np.diff(xs).min(), np.diff(ys).min())),
        )

    @property
    def n_obstacles(self) -> int:
        return len(self.ob_start) - 1

    def cast(self, rays: np.ndarray, max_range: float = math.inf) -> np.ndarray:
        """Hit distance of every ray of ``rays (N, 6)`` float32 (origin xyz, unit direction xyz): ``(N,)``
        float32, ``inf`` where nothing is hit within ``max_range`` (a fresh array)."""
        return self._cast(rays, None, None, float(max_range), None)[0]

    def cast_pose(
        self,
        directions: np.ndarray,
        origin: np.ndarray,
        rotation: np.ndarray,
        max_range: float = math.inf,
        min_range: float | None = None,
        pinhole: Pinhole | None = None,
    ) -> np.ndarray:
        """:meth:`cast` of the rays ``directions (N, 3)`` (float32, C-contiguous, unit, body frame) rotated by
        ``rotation (3, 3)`` and starting at ``origin (3,)`` (world frame, float64): the pose transform is done
        in the kernel, ray by ray, so a frame builds no ``(N, 6)`` ray array. The rays cast are
        :func:`pose_rays`'s, bit for bit (float32 origin and rotation, the product in float64 rounded once to
        float32: within half a float32 ulp of a numpy float32 matmul's, not always equal to it).

        With ``min_range`` the result is a sensor's: NaN for no hit and for a (float32) range outside
        ``[min_range, max_range]`` (compared in float32, as numpy compares a float32 array with Python
        floats), so the caller needs no masking pass.

        With ``pinhole`` (the camera the directions are the pixel rays of) the terrain near the sensor is
        rasterised (:mod:`diana_lab.sensing.pinhole_raster`): the same ranges, bit for bit, in less time."""
        lo = None if min_range is None else float(min_range)
        return self._cast(directions, origin, rotation, float(max_range), lo, pinhole=pinhole)[0]

    def cast_frame(
        self,
        directions: np.ndarray,
        origin: np.ndarray,
        rotation: np.ndarray,
        mount: np.ndarray,
        max_range: float,
        min_range: float,
        pinhole: Pinhole | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`cast_pose` with ``min_range`` (a sensor's ranges, NaN for no return), and the returns as the
        sensor's point cloud in the body frame: ``(M, 3)`` float32 ``directions * range + mount`` (``mount
        (3,)`` float32, the sensor's position on the body) of the rays with a return, in ray order, exactly
        as numpy computes it in float32 (:attr:`SensorFrame.points`), written by the cast itself.
        The cloud is a view of the first ``M`` rows of an ``(N, 3)`` buffer. ``pinhole``: as in :meth:`cast_pose`."""
        cloud = np.empty((directions.shape[0], 3), dtype=np.float32)
        ranges, m = self._cast(
            directions, origin, rotation, float(max_range), float(min_range), cloud, mount, pinhole=pinhole
        )
        return ranges, cloud[:m]

    def _cast(
        self,
        rays: np.ndarray,
        origin: np.ndarray | None,
        rotation: np.ndarray | None,
        max_range: float,
        min_range: float | None,
        points: np.ndarray | None = None,
        mount: np.ndarray | None = None,
        pinhole: Pinhole | None = None,
    ) -> tuple[np.ndarray, int]:
        if self.n_obstacles:
            first = cast_obstacles(
                rays,
                origin,
                rotation,
                max_range,
                self.ob_vertices,
                self.ob_triangles,
                self.ob_start,
                self.ob_box,
                self.ob_sphere,
            )
        else:
            first = _NONE
        near_best, near_box = None, _NO_BOX
        if pinhole is not None and origin is not None:
            near_best, near_box = self._raster(rays, origin, rotation, pinhole)
        return cast_terrain(
            rays,
            origin,
            rotation,
            max_range,
            first,
            self.xs,
            self.ys,
            self.heights,
            self.cell_max,
            self.block_max,
            self.block_cols,
            self.shift,
            self.z_range,
            min_range,
            points,
            mount,
            near_best,
            near_box,
        )

    def _raster(
        self, directions: np.ndarray, origin: np.ndarray, rotation: np.ndarray, pinhole: Pinhole
    ) -> tuple[np.ndarray | None, np.ndarray]:
        """The near field's hits (:func:`~diana_lab.sensing.pinhole_raster.raster_near`) and its box; ``None``
        and an empty box where the raster does not apply (cells narrower than its ``DELTA``, the sensor off
        the map or down at the terrain)."""
        from diana_lab.sensing.pinhole_raster import (  # (it imports this module)
            DELTA,
            REACH_CELLS,
            REACH_M,
            raster_near,
        )

        if self.min_cell <= DELTA:
            return None, _NO_BOX
        best, box = raster_near(
            directions,
            origin,
            rotation,
            pinhole.mount_rotation,
            pinhole.params,
            min(REACH_M, REACH_CELLS * self.min_cell),
            self.xs,
            self.ys,
            self.heights,
            self.cell_max,
        )
        return (None, _NO_BOX) if box[0] > box[1] else (best, box)


_NONE = np.zeros(0)  # cast_terrain's "no obstacle hits"
_NO_BOX = np.array([0, -1, 0, -1], dtype=np.int64)  # cast_terrain's "nothing rasterised"
_SCENES: weakref.WeakKeyDictionary[World, HeightfieldScene] = weakref.WeakKeyDictionary()


def heightfield_for(world: World) -> HeightfieldScene:
    """The (cached, per world object and process) :class:`HeightfieldScene` of ``world``."""
    scene = _SCENES.get(world)
    if scene is None:
        scene = _SCENES[world] = HeightfieldScene.from_world(world)
    return scene
