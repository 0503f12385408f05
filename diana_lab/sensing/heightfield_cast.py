"""Exact ray casting against a heightfield terrain plus obstacle meshes, compiled with numba (one thread).

Why it exists: the sensor targets (a 64 x 48 depth frame to ``depth_image`` in 0.3 ms, 112 x 112 in 2 ms,
one core) cannot be met with open3d's ``RaycastingScene``: ``cast_rays`` takes 0.54-0.69 ms for the 3,072
rays against the 131k-triangle Mars yard and ~0.15 ms even against a 2-triangle plane (per-call floor). The
terrain is a regular grid, so a walk through its cells finds the few triangles a ray can hit without any
acceleration structure: it casts a 64 x 48 frame on the yard in about half open3d's time (numbers, and what
did not help: :data:`SPEED`). A depth camera's frame goes faster still: the terrain near the sensor, where most
of its rays end, is rasterised into the image with this walk's own tests (:mod:`diana_lab.sensing.pinhole_raster`,
the same ranges bit for bit), and only the rays that hit nothing there are walked, from where they leave it.

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
from numba import njit

from diana_lab.sim.world import World

if TYPE_CHECKING:
    from diana_lab.sensing.pinhole import Pinhole

__all__ = [
    "BLOCK_SHIFT",
    "SPEED",
    "HeightfieldScene",
    "cast_obstacles",
    "cast_terrain",
    "heightfield_for",
    "pose_rays",
]

SPEED = """\
Measured 2026-11-22, 2 cores (Xeon, load 3.6-4.5 from another job), one thread, mars_yard, the benchmark's rover
poses (python -m diana_lab.bench 'only=[sensor_ms,elevation_map_ms,sensor_ms_112]' sensor.backend=...), before the
unsigned indices and the block DDA:
  64 x 48 (3,072 rays): cast 0.35 ms (open3d 0.65 ms); frame -> depth_image (sensor_ms) 0.354 ms (open3d 0.667)
  112 x 112 (12,544 rays): cast 1.16 ms (open3d 2.36 ms); frame -> depth_image 1.18 ms (open3d 2.43)
  elevation_map of a 64 x 48 frame: 0.69 ms (open3d 1.01 ms)
A 64 x 48 ray cost ~100 ns: ~3 block steps, ~7 cell steps and ~1.4 cell tests (the clipping and first cell ~11 ns).
Starting every ray 0.3 m before its hit (an oracle) would still take 0.20 ms a frame. Tried, no faster: one level
or 4 / 16-cell blocks, a branch-free DDA step, float32 maxima, walking column by column, always testing.
Then (A/B against that kernel in one process, the benchmark's 256 frames interleaved, medians of 40 rounds): unsigned
indices 0.91x the time, the block DDA and cheaper block entry a further ~0.97x: 0.88x in all (cast ~0.29 ms a frame
unloaded; sensor_ms ~0.32 ms by estimate). Tried, no faster: skipping the start of each ray that is provably above
the terrain (per frame, the highest point in square rings of cells and blocks around the sensor, per quadrant):
30% fewer steps, yet 15-25% slower (the per-ray level test and locating the start cell cost more than the steps);
the same for upward rays only: no change; fastmath {nsz, contract}: no change.
Then (whole frame: sensor.observe of the bench's depth_image sensor over its 256 poses, variants interleaved with
the order rotated, per-round ratio to the previous kernel, medians of 50-60 rounds; load 2-4.6 from another job,
where two copies of one kernel differ by 0.2-0.3%): the pose form with the sensor's window (RayCaster and
RaySensor.capture calling cast_pose(..., min_range=...)) 0.973x the frame (~9 us of ~325: the numpy ray transform
~7 us and the NaN mask ~6 us a frame, less ~3 us of rotating in the kernel); the pose form without the window
0.99x; the (N, 6) form unchanged (kernel A/B 1.001x). Tried, slower, taken out: a per-frame horizon (the steepest
slope to the terrain in 64 azimuth sectors, from cells near the sensor and blocks out to max_range, conservative by
a sector either side; exact): it marks 280-320 of the ~536 rays a frame that hit nothing, but those are the cheap
ones (upward rays leave the height range at once: ~17 us a frame for all of them), while the costly misses (~215
near the horizon, ~175 ns each) pass below it; building it takes 6-16 us a frame and testing every ray more, so the
cast took 1.035-1.06x the time (blocks only / 8 cells near). Clipping rays to the highest block in range instead of
the map's highest point: 1.01x (no gain).
Then (session 5, the same A/B method, frames on the bench's poses; a busy machine, two copies of one kernel within
0.1-0.5%): where a ray's time goes: clipping alone ~12 ns, clipping and the first block and cell ~22 ns, the whole
frame ~100 ns a ray, yet one ray repeated 3,072 times costs 40-70 ns (hits at 0.4-1.7 m): about a third of a
frame is the cost of rays that differ (mispredicted branches; shuffling the rays makes the frame 1.30x slower).
Tried, too little to keep: per-cell plane coefficients precomputed (the test then needs 6 loads and 2 FMAs a plane)
0.983x; no z division for downward rays 0.996x; t to the next edge accumulated instead of recomputed from the
vertex coordinates (not exact on a non-uniform grid) 0.984x; rays in column-major order 0.986x; 4 x 4 / 16 x 16
blocks 1.053x / 1.006x. The frame's point cloud, written by the kernel as it goes (``points``), costs ~1 ns a ray
(the numpy form, from the ranges afterwards, ~60 us a frame).
Then (session 13, another machine: AMD EPYC, where the frame above took 0.32 ms cast alone and sensor_ms was
0.338 ms, open3d's bare cast_rays 0.53 ms against the 0.4 ms the issue quotes): the near field rasterised for
pinhole cameras (diana_lab.sensing.pinhole_raster): cast 0.315 -> 0.19 ms a frame, sensor_ms 0.338 -> 0.23 ms,
sensor_ms_112 1.14 -> 0.78 ms; the rays it leaves (about a fifth: hits beyond its box, misses) are walked from
the box's edge.
Compile: ~4 s the first time (2.9 s terrain + 1.1 s obstacle kernel), then cached; 0.4 s on first use per process.
Each form compiles apart, on first use (under load: the (N, 6) form 4.0 s, the pose form 3.7 s, with the window
2.7 s, pose_rays 1.6 s), then cached.
"""

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


# ----------------------------------------------------------------------------------------------- kernels
# Helpers take scalars only: numba does not inline across @njit functions by itself, and passing arrays to
# even an inlined helper costs reference counting on every call. No parallel=True: one thread, always.


def _jit(**options):
    """``numba.njit`` with the compiled code cached on disk: next to this file (``__pycache__``), or in the
    user's cache directory when the package is read-only (numba's own fallback). Where nothing is writable
    numba refuses ``cache=True`` at decoration time; the kernels are then compiled in every process."""

    def wrap(fn):
        try:
            return njit(cache=True, nogil=True, error_model="numpy", **options)(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return njit(cache=False, nogil=True, error_model="numpy", **options)(fn)

    return wrap


@_jit(inline="always")
def _triangle_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, cx, cy, cz):  # pragma: no cover (numba)
    """Distance along the ray to triangle ``abc`` (either side), ``inf`` if missed (Moller-Trumbore,
    branch-free: the tests are combined with ``&`` so that they compile to selects)."""
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    sx, sy, sz = ox - ax, oy - ay, oz - az
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    sign = -1.0 if det < 0.0 else 1.0
    u = (sx * px + sy * py + sz * pz) * sign
    v = (dx * qx + dy * qy + dz * qz) * sign
    w = (e2x * qx + e2y * qy + e2z * qz) * sign  # t * |det|
    adet = det * sign
    hit = (adet != 0.0) & (u >= 0.0) & (v >= 0.0) & (u + v <= adet) & (w > 0.0)
    return w / adet if hit else np.inf


@_jit(inline="always")
def _crossing(a, b, t_in, t_out, g0, g1, side):  # pragma: no cover (numba)
    """Whether a ray ``a + t b`` above a triangle's plane (times the cell's area) crosses it at a ``t`` in
    ``[t_in, t_out]`` on the triangle's ``side`` of the cell's diagonal (-1: ``g0 + t g1 <= 0``, +1: ``>= 0``);
    and that ``t > 0`` as ``n / d``, ``d > 0``. No division: every test is multiplied through by ``|b|``."""
    sign = -1.0 if b < 0.0 else 1.0
    n, d = -a * sign, b * sign
    hit = (d > 0.0) & (n > 0.0) & (n >= t_in * d) & (n <= t_out * d) & ((g0 * d + n * g1) * side >= 0.0)
    return hit, n, d


@_jit(inline="always")
def _slab(o, d, lo, hi, t0, t1):  # pragma: no cover (numba)
    """``[t0, t1]`` narrowed to where ``o + t d`` lies in ``[lo, hi]`` on one axis (empty: ``t0 > t1``)."""
    if d == 0.0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return t0, t1
    ta, tb = (lo - o) / d, (hi - o) / d
    if ta > tb:
        ta, tb = tb, ta
    return max(t0, ta), min(t1, tb)


@_jit(inline="always")
def _guess(p, e_lo, cells_per_m, lo, hi):  # pragma: no cover (numba)
    """First guess of the cell in ``[lo, hi]`` holding coordinate ``p`` on an axis whose edges are (up to
    float32 rounding) ``e_lo + i / cells_per_m``; the caller corrects it against the real edges."""
    g = (p - e_lo) * cells_per_m
    if not g > lo:  # also NaN
        return lo
    return min(int(g), hi)


@_jit(inline="always")
def _u(i):  # pragma: no cover (numba)
    """``i`` as an unsigned index: numba then leaves out the wrap-around of negative indices on every access
    (two or three instructions each, on the walk's every step)."""
    return np.uint64(i)


@_jit(inline="always")
def _pose32(origin, rotation):  # pragma: no cover (numba)
    """A pose's rotation and origin as float32 values (in float64 variables): what the rays carry."""
    f = np.float32
    return (
        np.float64(f(rotation[0, 0])),
        np.float64(f(rotation[0, 1])),
        np.float64(f(rotation[0, 2])),
        np.float64(f(rotation[1, 0])),
        np.float64(f(rotation[1, 1])),
        np.float64(f(rotation[1, 2])),
        np.float64(f(rotation[2, 0])),
        np.float64(f(rotation[2, 1])),
        np.float64(f(rotation[2, 2])),
        np.float64(f(origin[0])),
        np.float64(f(origin[1])),
        np.float64(f(origin[2])),
    )


@_jit(inline="always")
def _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22):  # pragma: no cover (numba)
    """``R e`` in float64, rounded to float32 (one rounding: within half an ulp of the exact product)."""
    f = np.float32
    dx = np.float64(f(r00 * ex + r01 * ey + r02 * ez))
    dy = np.float64(f(r10 * ex + r11 * ey + r12 * ez))
    dz = np.float64(f(r20 * ex + r21 * ey + r22 * ez))
    return dx, dy, dz


@_jit()
def pose_rays(directions, origin, rotation, out):  # pragma: no cover (numba)
    """Write the rays of a pose into ``out (N, 6)`` float32 (origin xyz, direction xyz) and return it:
    bit for bit the rays :func:`cast_terrain` and :func:`cast_obstacles` cast for ``(directions, origin,
    rotation)``, for casting the same rays elsewhere (open3d, PyBullet)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    for i in range(directions.shape[0]):
        ex, ey, ez = np.float64(directions[i, 0]), np.float64(directions[i, 1]), np.float64(directions[i, 2])
        dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        out[i, 0], out[i, 1], out[i, 2] = pose_x, pose_y, pose_z
        out[i, 3], out[i, 4], out[i, 5] = dx, dy, dz
    return out


@_jit()
def cast_obstacles(
    rays, origin, rotation, max_range, ob_vertices, ob_triangles, ob_start, ob_box, ob_sphere
):  # pragma: no cover (numba)
    """Nearest obstacle hit of every ray (float64, ``inf`` for none within ``max_range``); the rays as in
    :func:`cast_terrain`."""
    n, n_ob = rays.shape[0], ob_start.shape[0] - 1
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = pose_x = pose_y = pose_z = 0.0
    if rotation is not None:  # a pose (None: the rays carry origins and directions); compiled apart
        r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    out = np.full(n, np.inf)
    t_lim = max_range * (1.0 + 1e-6) + 1e-6
    near = np.empty(n_ob, dtype=np.int64)  # the obstacles in range of the current ray origin
    n_near, home_x, home_y, home_z = 0, np.nan, np.nan, np.nan
    v = ob_vertices
    for i in range(n):
        if rotation is not None:
            ex, ey, ez = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            ox, oy, oz = pose_x, pose_y, pose_z
            dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        else:
            ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        if not (ox == home_x and oy == home_y and oz == home_z):  # a new sensor position: cull once
            home_x, home_y, home_z, n_near = ox, oy, oz, 0
            for k in range(n_ob):
                cx, cy, cz, r = ob_sphere[k, 0] - ox, ob_sphere[k, 1] - oy, ob_sphere[k, 2] - oz, ob_sphere[k, 3]
                if math.sqrt(cx * cx + cy * cy + cz * cz) - r <= t_lim:
                    near[n_near] = k
                    n_near += 1
        best = np.inf
        for m in range(n_near):
            k = near[m]
            cx, cy, cz, r = ob_sphere[k, 0] - ox, ob_sphere[k, 1] - oy, ob_sphere[k, 2] - oz, ob_sphere[k, 3]
            along = cx * dx + cy * dy + cz * dz
            if along + r < 0.0 or cx * cx + cy * cy + cz * cz - along * along > r * r:
                continue  # the ray's line misses the sphere, or the sphere is behind the origin
            t0, t1 = _slab(ox, dx, ob_box[k, 0], ob_box[k, 3], 0.0, min(t_lim, best))
            t0, t1 = _slab(oy, dy, ob_box[k, 1], ob_box[k, 4], t0, t1)
            t0, t1 = _slab(oz, dz, ob_box[k, 2], ob_box[k, 5], t0, t1)
            if t0 > t1:
                continue
            for j in range(ob_start[k], ob_start[k + 1]):
                a, b, c = ob_triangles[j, 0], ob_triangles[j, 1], ob_triangles[j, 2]
                ax, ay, az, bx, by, bz = v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2]
                t = _triangle_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, v[c, 0], v[c, 1], v[c, 2])
                best = min(best, t)
        out[i] = best
    return out


@_jit()
def cast_terrain(
    rays,
    origin,
    rotation,
    max_range,
    first,
    xs,
    ys,
    hs,
    cell_max,
    block_max,
    block_cols,
    shift,
    z_range,
    lo,
    points,
    mount,
    near_best,
    near_box,
):  # pragma: no cover (numba)
    """Nearest hit of every ray on the terrain, or on an obstacle if ``first[i]`` (obstacle hit distances;
    empty: none) is nearer: ``(N,)`` float32, ``inf`` for no hit within ``max_range``; and how many rows of
    ``points`` were written (0 without it). The rays: ``rays (N,
    6)`` float32 (origin xyz, unit direction xyz), ``origin`` and ``rotation`` None; or a pose, ``rays (N,
    3)`` float32 directions in the body frame rotated by ``rotation (3, 3)`` from ``origin (3,)`` (both
    float64), exactly as :func:`pose_rays` writes them. With ``lo`` (not None), a range (float32) outside
    ``[lo, max_range]`` (compared as float32 values) or no hit comes back as NaN (the sensor's "no return").
    With ``points (N, 3)`` float32 as well (a pose and ``lo`` only) the returns are also written there as the
    sensor's point cloud in the body frame, ``directions[i] * range + mount`` (``mount (3,)`` float32) in
    float32 as numpy computes it, in ray order, each ray to the next free row (a return advances it): the
    frame's cloud without a second pass over the rays. With ``near_best`` (a pose only; None: compiled apart), the
    rays' nearest terrain hits within the cell box ``near_box`` (``ix_lo, ix_hi, iy_lo, iy_hi``) that
    :func:`~diana_lab.sensing.pinhole_raster.raster_near` found (``inf``: none there): a ray with one is done,
    the others are walked from where they leave the box."""
    n = rays.shape[0]
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = pose_x = pose_y = pose_z = 0.0
    if rotation is not None:  # a pose (None: the rays carry origins and directions); compiled apart
        r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    lo32, hi32 = np.float32(-np.inf), np.float32(max_range)
    if lo is not None:  # None: no window; compiled apart
        lo32 = np.float32(lo)
    out = np.empty(n, dtype=np.float32)
    n_points = 0
    m_x = m_y = m_z = 0.0
    if points is not None:  # None: no cloud; compiled apart
        m_x, m_y, m_z = np.float64(mount[0]), np.float64(mount[1]), np.float64(mount[2])
    has_first = first.shape[0] == n
    t_lim = max_range * (1.0 + 1e-6) + 1e-6  # a hit the caller may keep after rounding to float32 stays
    z_lo, z_hi = z_range[0], z_range[1]
    nx, ny = xs.shape[0], ys.shape[0]
    ncx, ncy = nx - 1, ny - 1
    nbx, nby = block_cols, block_max.shape[0] // block_cols
    x_lo, x_hi, y_lo, y_hi = xs[0], xs[_u(ncx)], ys[0], ys[_u(ncy)]
    per_mx, per_my = ncx / (x_hi - x_lo), ncy / (y_hi - y_lo)  # cells per metre
    # every ray of a frame starts at the sensor: its cell is located once
    home_x, home_y, home_ix, home_iy = np.nan, np.nan, 0, 0
    for i in range(n):
        if rotation is not None:
            ex, ey, ez = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            ox, oy, oz = pose_x, pose_y, pose_z
        else:
            ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        best = first[i] if has_first else np.inf
        near = np.inf
        if near_best is not None:
            near = near_best[i]
        if near < np.inf:  # the raster found its nearest terrain hit (pinhole_raster): no walk, no world ray
            best = min(best, near)
        else:
            if rotation is not None:
                dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
            # clip to the map's box, the terrain's height range, the range limit and the obstacle hit
            step_x = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
            step_y = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
            inv_dx = 1.0 / dx if dx != 0.0 else 0.0
            inv_dy = 1.0 / dy if dy != 0.0 else 0.0
            t0, t1 = 0.0, min(t_lim, best)
            if step_x != 0:
                ta, tb = (x_lo - ox) * inv_dx, (x_hi - ox) * inv_dx
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif ox < x_lo or ox > x_hi:
                t1 = -1.0
            if step_y != 0:
                ta, tb = (y_lo - oy) * inv_dy, (y_hi - oy) * inv_dy
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif oy < y_lo or oy > y_hi:
                t1 = -1.0
            if dz != 0.0:
                inv_dz = 1.0 / dz
                ta, tb = (z_lo - oz) * inv_dz, (z_hi - oz) * inv_dz
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif oz < z_lo or oz > z_hi:
                t1 = -1.0
            if near_best is not None:  # no hit in the rasterised box: the walk starts where the ray leaves it
                t_box = np.inf
                if step_x != 0:
                    t_box = (xs[_u(near_box[1] + 1 if step_x > 0 else near_box[0])] - ox) * inv_dx
                if step_y != 0:
                    t_box = min(t_box, (ys[_u(near_box[3] + 1 if step_y > 0 else near_box[2])] - oy) * inv_dy)
                t0 = max(t0, t_box)
            if t0 <= t1:
                off_x = 1 if step_x > 0 else 0
                off_y = 1 if step_y > 0 else 0
                # the first cell (t0 may sit on the map's edge: clamped into it)
                if t0 == 0.0 and ox == home_x and oy == home_y:
                    ix, iy = home_ix, home_iy
                else:
                    px, py = ox + t0 * dx, oy + t0 * dy
                    ix = _guess(px, x_lo, per_mx, 0, ncx - 1)
                    while ix > 0 and xs[_u(ix)] > px:
                        ix -= 1
                    while ix < ncx - 1 and xs[_u(ix + 1)] < px:
                        ix += 1
                    iy = _guess(py, y_lo, per_my, 0, ncy - 1)
                    while iy > 0 and ys[_u(iy)] > py:
                        iy -= 1
                    while iy < ncy - 1 and ys[_u(iy + 1)] < py:
                        iy += 1
                    if t0 == 0.0:
                        home_x, home_y, home_ix, home_iy = ox, oy, ix, iy
                bx, by = ix >> shift, iy >> shift
                t_enter, z_enter = t0, oz + dz * t0
                # the block DDA: the ray's exits from the current block (its far edges) on either axis
                offb_x = 1 if step_x > 0 else 0
                offb_y = 1 if step_y > 0 else 0
                tbx = (xs[_u(min((bx + offb_x) << shift, ncx))] - ox) * inv_dx if step_x != 0 else np.inf
                tby = (ys[_u(min((by + offb_y) << shift, ncy))] - oy) * inv_dy if step_y != 0 else np.inf
                entered = 0  # how the ray entered the block: 0 first block (ix, iy known), 1 x edge, 2 y edge
                while True:
                    t_exit = min(tbx, tby, t1)
                    z_exit = oz + dz * t_exit
                    if min(z_enter, z_exit) <= block_max[_u(by * nbx + bx)]:
                        # walk this block's cells; test those the ray does not pass above
                        cx0, cy0 = bx << shift, by << shift
                        cx1, cy1 = min(cx0 + (1 << shift), ncx) - 1, min(cy0 + (1 << shift), ncy) - 1
                        if entered == 1:  # through its near x edge: locate the row there (in the block)
                            ix = cx0 if step_x > 0 else cx1
                            py = oy + t_enter * dy
                            iy = _guess(py, y_lo, per_my, cy0, cy1)
                            while iy > cy0 and ys[_u(iy)] > py:
                                iy -= 1
                            while iy < cy1 and ys[_u(iy + 1)] < py:
                                iy += 1
                        elif entered == 2:
                            iy = cy0 if step_y > 0 else cy1
                            px = ox + t_enter * dx
                            ix = _guess(px, x_lo, per_mx, cx0, cx1)
                            while ix > cx0 and xs[_u(ix)] > px:
                                ix -= 1
                            while ix < cx1 and xs[_u(ix + 1)] < px:
                                ix += 1
                        tmax_x = (xs[_u(ix + off_x)] - ox) * inv_dx if step_x != 0 else np.inf
                        tmax_y = (ys[_u(iy + off_y)] - oy) * inv_dy if step_y != 0 else np.inf
                        k = iy * ncx + ix
                        z_prev, t_in = z_enter, t_enter  # the ray's height and t entering the cell
                        hit = False
                        while True:
                            tc = min(tmax_x, tmax_y, t_exit)
                            z_c = oz + dz * tc
                            if min(z_prev, z_c) <= cell_max[_u(k)]:
                                # the cell's triangles (a, b, c) and (d, c, b) of Terrain.mesh, a = (x0, y0),
                                # d = (x1, y1). In [t_in, tc] the ray is over the cell, so it hits a triangle where
                                # it crosses its plane at a t in that interval on the triangle's side of the
                                # diagonal. Heights above the planes times w h are A + t B; the tests multiply
                                # through by |B|, so the branch waits on no division (the division only gives the
                                # distance of a hit).
                                kv = iy * nx + ix
                                x0, x1, y0, y1 = xs[_u(ix)], xs[_u(ix + 1)], ys[_u(iy)], ys[_u(iy + 1)]
                                ha, hb = hs[_u(kv)], hs[_u(kv + 1)]
                                hc, hd = hs[_u(kv + nx)], hs[_u(kv + nx + 1)]
                                w, h = x1 - x0, y1 - y0
                                wh = w * h
                                sx, sy = ox - x0, oy - y0
                                p, q = (hb - ha) * h, (hc - ha) * w
                                a_low, b_low = (oz - ha) * wh - sx * p - sy * q, dz * wh - dx * p - dy * q
                                p, q = (hc - hd) * h, (hb - hd) * w
                                a_up, b_up = (oz - hd) * wh + (sx - w) * p + (sy - h) * q, dz * wh + dx * p + dy * q
                                g0, g1 = sx * h + sy * w - wh, dx * h + dy * w  # diagonal side at t, times w h
                                hit_low, n_low, d_low = _crossing(a_low, b_low, t_in, tc, g0, g1, -1.0)
                                hit_up, n_up, d_up = _crossing(a_up, b_up, t_in, tc, g0, g1, 1.0)
                                if hit_low | hit_up:  # the first cell with a hit holds the nearest one
                                    t_low = n_low / d_low if hit_low else np.inf
                                    best = min(best, t_low, n_up / d_up if hit_up else np.inf)
                                    hit = True
                                    break
                            if tc >= t_exit:
                                break
                            z_prev, t_in = z_c, tc
                            if tmax_x < tmax_y:
                                ix += step_x
                                if ix < cx0 or ix > cx1:
                                    break
                                k += step_x
                                tmax_x = (xs[_u(ix + off_x)] - ox) * inv_dx
                            else:
                                iy += step_y
                                if iy < cy0 or iy > cy1:
                                    break
                                k += step_y * ncx
                                tmax_y = (ys[_u(iy + off_y)] - oy) * inv_dy
                        if hit:
                            break
                    if t_exit >= t1:
                        break
                    # the next block
                    t_enter, z_enter = t_exit, z_exit  # t_exit < t1 here: the nearer of tbx and tby
                    if tbx < tby:
                        bx += step_x
                        if bx < 0 or bx >= nbx:
                            break
                        tbx = (xs[_u(min((bx + offb_x) << shift, ncx))] - ox) * inv_dx
                        entered = 1
                    else:
                        by += step_y
                        if by < 0 or by >= nby:
                            break
                        tby = (ys[_u(min((by + offb_y) << shift, ncy))] - oy) * inv_dy
                        entered = 2
        if lo is None:
            out[i] = best if best <= t_lim else np.inf
        else:
            r = np.float32(best) if best <= t_lim else np.float32(np.inf)
            r = r if r >= lo32 and r <= hi32 else np.float32(np.nan)
            out[i] = r
            if points is not None:
                # float32 product, then float32 sum (each exact in float64 before its one rounding)
                f, rr, j = np.float32, np.float64(r), _u(n_points)
                points[j, 0] = f(np.float64(f(ex * rr)) + m_x)
                points[j, 1] = f(np.float64(f(ey * rr)) + m_y)
                points[j, 2] = f(np.float64(f(ez * rr)) + m_z)
                n_points += not np.isnan(r)
    return out, n_points
