"""The env's sensor for many rovers: one compiled call casts every rover's frame, another encodes them.

The rays are the scalar sensor's (:class:`~diana_lab.sensing.sensor.RaySensor`: its pattern, mount and range
window), cast by the same heightfield kernels (:mod:`diana_lab.sensing.heightfield_kernels`, the depth camera's
near field rasterised by :mod:`diana_lab.sensing.pinhole_raster`), one rover per thread (numba ``prange``). The
``depth_image`` and ``elevation_map`` encodings (with and without memory, with the voxel filter) are compiled
here too, to the scalar encoders' arithmetic (:mod:`diana_lab.sensing.encoders`,
:class:`~diana_lab.core.height_memory.HeightMemory`), float32 where they are float32, and so is the map's
stopped-drive channel (:class:`~diana_lab.core.hazard_memory.HazardMemory`).

Three things stay per rover, in Python, through the scalar code itself (exact, and slow): sensor noise (each
rover's :class:`~diana_lab.sensing.noise.NoiseModel`, drawing from that rover's generator), the ``points``
encoding and the elevation map's outlier removal (open3d). :attr:`BatchedSensor.slow_paths` names those in use.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from diana_lab.core.height_memory import window_offsets
from diana_lab.sensing.frame import SensorFrame
from diana_lab.sensing.heightfield_cast import heightfield_for
from diana_lab.sensing.heightfield_kernels import _jit, cast_obstacles, cast_terrain
from diana_lab.sensing.noise import NoiseModel
from diana_lab.sensing.pinhole_raster import DELTA, REACH_CELLS, REACH_M, raster_near
from diana_lab.sensing.returns import valid_points
from diana_lab.sensing.sensor import RaySensor

__all__ = ["BatchedSensor", "cast_batch", "elevation_batch", "hazard_batch"]

_NO_BOX = np.array([0, -1, 0, -1], dtype=np.int64)


@_jit(inline="always")
def _rpy(roll, pitch, yaw):  # pragma: no cover (numba)
    """:func:`diana_lab.core.rotations.rpy_matrix`, term for term."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    r[1, 0], r[1, 1], r[1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    r[2, 0], r[2, 1], r[2, 2] = -sp, cp * sr, cp * cr
    return r


@_jit(parallel=True)
def cast_batch(
    rows,
    state,
    directions,
    mount,
    mount32,
    max_range,
    min_range,
    xs,
    ys,
    hs,
    cell_max,
    block_max,
    block_cols,
    shift,
    z_range,
    ob_vertices,
    ob_triangles,
    ob_start,
    ob_box,
    ob_sphere,
    cam,
    proj,
    reach,
    ranges,
    cloud,
    counts,
):  # pragma: no cover (numba)
    """Every rover ``i`` in ``rows`` casts the sensor's rays from ``state[i]`` (x, y, z, roll, pitch, yaw): into
    ``ranges[i]`` (float32) and, with ``min_range`` (not None), its returns into ``cloud[i, :counts[i]]`` (the
    rover-frame cloud, as :meth:`HeightfieldScene.cast_frame`); with ``min_range`` None the raw hit distances
    (``inf``: none), as :meth:`HeightfieldScene.cast_pose` gives a noisy sensor. ``cam`` (None: not a camera) and
    ``proj`` the pinhole whose near field is rasterised, to ``reach`` metres."""
    n_ob = ob_start.shape[0] - 1
    min_cell = min(np.diff(xs).min(), np.diff(ys).min())
    for r in prange(rows.shape[0]):
        i = rows[r]
        rot = _rpy(state[i, 3], state[i, 4], state[i, 5])
        origin = np.empty(3)
        for k in range(3):
            origin[k] = state[i, k] + (rot[k, 0] * mount[0] + rot[k, 1] * mount[1] + rot[k, 2] * mount[2])
        if n_ob > 0:
            first = cast_obstacles(
                directions, origin, rot, max_range, ob_vertices, ob_triangles, ob_start, ob_box, ob_sphere
            )
        else:
            first = np.zeros(0)
        use_raster = False
        best = np.zeros(0)
        box = np.array([0, -1, 0, -1], dtype=np.int64)
        # nested: numba prunes the branch on ``cam is None`` only when that test stands alone
        if cam is not None:  # noqa: SIM102
            if min_cell > DELTA:
                best, box = raster_near(directions, origin, rot, cam, proj, reach, xs, ys, hs, cell_max)
                use_raster = box[0] <= box[1]
        if min_range is None:
            if use_raster:
                out, m = cast_terrain(
                    directions, origin, rot, max_range, first, xs, ys, hs, cell_max, block_max, block_cols, shift,
                    z_range, None, None, None, best, box,
                )  # fmt: skip
            else:
                out, m = cast_terrain(
                    directions, origin, rot, max_range, first, xs, ys, hs, cell_max, block_max, block_cols, shift,
                    z_range, None, None, None, None, box,
                )  # fmt: skip
        elif use_raster:
            out, m = cast_terrain(
                directions, origin, rot, max_range, first, xs, ys, hs, cell_max, block_max, block_cols, shift,
                z_range, min_range, cloud[i], mount32, best, box,
            )  # fmt: skip
        else:
            out, m = cast_terrain(
                directions, origin, rot, max_range, first, xs, ys, hs, cell_max, block_max, block_cols, shift,
                z_range, min_range, cloud[i], mount32, None, box,
            )  # fmt: skip
        ranges[i, :] = out
        counts[i] = m


@_jit(parallel=True)
def clouds_batch(rows, ranges, directions, mount32, cloud, counts):  # pragma: no cover (numba)
    """The rover-frame clouds of frames whose ranges were edited after the cast (noise): ``valid_points``."""
    for r in prange(rows.shape[0]):
        i = rows[r]
        pts = valid_points(ranges[i], directions, mount32)
        m = pts.shape[0]
        cloud[i, :m] = pts
        counts[i] = m


@_jit(parallel=True)
def depth_batch(rows, ranges, scale, out):  # pragma: no cover (numba)
    """``depth_image``: ``fmin(range * scale, 1)`` (NaN, no return, becomes 1), float32."""
    one = np.float32(1.0)
    for r in prange(rows.shape[0]):
        i = rows[r]
        o = out[i]
        for k in range(ranges.shape[1]):
            v = ranges[i, k] * scale[k]
            o[k] = one if not v < one else v  # fmin: NaN -> 1


@_jit(inline="always")
def _level(cloud, m, roll, pitch, out):  # pragma: no cover (numba)
    """:func:`diana_lab.core.rotations.level_points` of ``cloud[:m]`` into ``out[:m]``: float64 products, one
    rounding to float32."""
    lv = _rpy(roll, pitch, 0.0)
    for j in range(m):
        p0, p1, p2 = np.float64(cloud[j, 0]), np.float64(cloud[j, 1]), np.float64(cloud[j, 2])
        for k in range(3):
            out[j, k] = np.float32(lv[k, 0] * p0 + lv[k, 1] * p1 + lv[k, 2] * p2)


@_jit(inline="always")
def _voxel(pts, m, size):  # pragma: no cover (numba)
    """open3d's ``voxel_down_sample`` of ``pts[:m]``: the mean (float64, points summed in their order, then
    float32) of the points in each ``size`` cube of a grid whose origin is the cloud's lowest corner less half a
    voxel. In voxel order, not open3d's (a hash map's): the elevation map keeps each cell's highest point, so the
    order of the points does not change it."""
    lo = np.empty(3)
    for k in range(3):
        lo[k] = np.float64(pts[0, k])
        for j in range(1, m):
            lo[k] = min(lo[k], np.float64(pts[j, k]))
        lo[k] = lo[k] - size * 0.5
    idx = np.empty((m, 3), dtype=np.int64)
    for j in range(m):
        for k in range(3):
            idx[j, k] = np.int64(math.floor((np.float64(pts[j, k]) - lo[k]) / size))
    span1 = idx[:, 1].max() + 1
    span2 = idx[:, 2].max() + 1
    key = (idx[:, 0] * span1 + idx[:, 1]) * span2 + idx[:, 2]
    order = np.argsort(key, kind="mergesort")  # stable: each voxel's points in their order
    out = np.empty((m, 3), dtype=np.float32)
    n = 0
    j = 0
    while j < m:
        k0 = key[order[j]]
        s0 = s1 = s2 = 0.0
        c = 0
        while j < m and key[order[j]] == k0:
            q = order[j]
            s0 += np.float64(pts[q, 0])
            s1 += np.float64(pts[q, 1])
            s2 += np.float64(pts[q, 2])
            c += 1
            j += 1
        out[n, 0], out[n, 1], out[n, 2] = np.float32(s0 / c), np.float32(s1 / c), np.float32(s2 / c)
        n += 1
    return out, n


@_jit(parallel=True)
def elevation_batch(
    rows, state, cloud, counts, params, voxel, memory, mem_origin, mem_set, mem_radius, offsets, out
):  # pragma: no cover (numba)
    """``elevation_map`` of each rover's cloud: levelled, voxel-filtered (``voxel`` > 0), binned into the
    heading-aligned grid (``params`` = cell_size, extent_forward, extent_side, height_clip, rows, cols) or, with
    ``memory`` (``(N, n * n)`` float32, NaN unknown; None: no memory), fused into the rover's world-frame map and
    read back round it (``offsets (rows * cols, 2)``: the window's cell centres, heading frame)."""
    cell, ef, es, clip = params[0], params[1], params[2], params[3]
    n_rows, n_cols = int(params[4]), int(params[5])
    f32 = np.float32
    inv = 1.0 / cell
    for r in prange(rows.shape[0]):
        i = rows[r]
        m = counts[i]
        pts = np.empty((max(m, 1), 3), dtype=np.float32)
        _level(cloud[i], m, state[i, 3], state[i, 4], pts)
        if voxel > 0.0 and m > 0:
            pts, m = _voxel(pts, m, voxel)
        top = np.full(n_rows * n_cols, -np.inf, dtype=np.float32)
        if memory is None:
            ef32, es32, inv32 = f32(ef), f32(es), f32(inv)
            for j in range(m):
                row = np.int64(math.floor((ef32 - pts[j, 0]) * inv32))
                col = np.int64(math.floor((es32 - pts[j, 1]) * inv32))
                if 0 <= row < n_rows and 0 <= col < n_cols:
                    k = row * n_cols + col
                    top[k] = max(top[k], pts[j, 2])
        else:
            mem = memory[i]
            nn = int(round(math.sqrt(mem.shape[0])))
            px, py, pz, yaw = state[i, 0], state[i, 1], state[i, 2], state[i, 5]
            if not mem_set[i]:
                mem_origin[i, 0], mem_origin[i, 1] = px - mem_radius, py - mem_radius
                mem_set[i] = True
            c, s = math.cos(yaw), math.sin(yaw)
            c32, s32 = f32(c), f32(s)
            ox, oy = mem_origin[i, 0], mem_origin[i, 1]
            world = np.empty((max(m, 1), 3), dtype=np.float32)
            cells = np.empty(max(m, 1), dtype=np.int64)
            for j in range(m):  # HeightMemory.to_world: float32 turn, float64 shift, one rounding
                world[j, 0] = f32(np.float64(c32 * pts[j, 0] - s32 * pts[j, 1]) + px)
                world[j, 1] = f32(np.float64(s32 * pts[j, 0] + c32 * pts[j, 1]) + py)
                world[j, 2] = f32(np.float64(pts[j, 2]) + pz)
                fx = math.floor((np.float64(world[j, 0]) - ox) * inv)
                fy = math.floor((np.float64(world[j, 1]) - oy) * inv)
                cells[j] = np.int64(fy * nn + fx) if (0 <= fx < nn and 0 <= fy < nn) else -1
            for j in range(m):  # the frame's highest point per cell replaces what the map held there
                if cells[j] >= 0:
                    mem[cells[j]] = -np.inf
            for j in range(m):
                if cells[j] >= 0:
                    mem[cells[j]] = max(mem[cells[j]], world[j, 2])
            base = f32(pz)
            for k in range(n_rows * n_cols):  # HeightMemory.window
                dx, dy = offsets[k, 0], offsets[k, 1]
                fx = math.floor((px + c * dx - s * dy - ox) * inv)
                fy = math.floor((py + s * dx + c * dy - oy) * inv)
                if 0 <= fx < nn and 0 <= fy < nn:
                    h = mem[np.int64(fy * nn + fx)]
                    if not math.isnan(h):
                        top[k] = h - base
        o = out[i]
        lo, hi, scale, half = f32(-clip), f32(clip), f32(0.5 / clip), f32(0.5)
        for k in range(n_rows * n_cols):
            t = top[k]
            if t > -np.inf:
                o[k] = min(max(t, lo), hi) * scale + half
                o[n_rows * n_cols + k] = f32(1.0)
            else:
                o[k] = f32(0.0)
                o[n_rows * n_cols + k] = f32(0.0)


@_jit(parallel=True)
def hazard_batch(rows, state, spots, n_spots, offsets, r2, channel, out):  # pragma: no cover (numba)
    """The stopped-drive channel of each rover's map (``HazardMemory.window``, the same float64 arithmetic): cell
    ``k`` of ``out[i, channel * cells:]`` is 1 where its centre (``offsets``, heading frame) round the rover's pose
    lies within ``sqrt(r2)`` of one of the rover's ``n_spots[i]`` spots, else 0."""
    cells = offsets.shape[0]
    base = channel * cells
    for r in prange(rows.shape[0]):
        i = rows[r]
        o = out[i]
        px, py, yaw = state[i, 0], state[i, 1], state[i, 5]
        c, s = math.cos(yaw), math.sin(yaw)
        for k in range(cells):
            dx, dy = offsets[k, 0], offsets[k, 1]
            wx = px + c * dx - s * dy
            wy = py + s * dx + c * dy
            near = False
            for j in range(n_spots[i]):
                ex, ey = wx - spots[i, j, 0], wy - spots[i, j, 1]
                if ex * ex + ey * ey <= r2:
                    near = True
                    break
            o[base + k] = np.float32(1.0) if near else np.float32(0.0)


class BatchedSensor:
    """``n`` copies of one scalar sensor: :meth:`observe` fills :attr:`obs` for the rovers named.

    Args:
        sensor: the scalar sensor of the env (its rays, mount, noise preset, encoder and world).
        n: the number of rovers.
    """

    def __init__(self, sensor: RaySensor, n: int) -> None:
        cfg = sensor.cfg
        if cfg.backend != "heightfield":
            from diana_lab.core.validation import ConfigError

            raise ConfigError(
                f"sensor.backend={cfg.backend}: the batched env (train.vec_env=batched) casts with the compiled "
                "heightfield marcher; use sensor.backend=heightfield (the same ranges) or another train.vec_env"
            )
        self.sensor, self.n, self.cfg = sensor, n, cfg
        self.encoding = cfg.encoding
        self.scene = heightfield_for(sensor.world)
        self.directions = sensor.caster.directions
        self.mount = np.asarray(sensor.mount, dtype=np.float64)
        self.mount32 = self.mount.astype(np.float32)
        n_rays = len(self.directions)
        self.noisy = sensor.noise.active
        self.noise = [NoiseModel(cfg.noise, cfg.noise_level, sensor.image_shape, cfg.min_range) for _ in range(n)]
        self.max_range = math.inf if self.noisy else float(cfg.max_range)
        pinhole = sensor.caster.pinhole
        self.cam = None if pinhole is None else pinhole.mount_rotation
        self.proj = np.zeros(4) if pinhole is None else pinhole.params
        self.reach = min(REACH_M, REACH_CELLS * self.scene.min_cell)
        self.ranges = np.zeros((n, n_rays), dtype=np.float32)
        self.cloud = np.zeros((n, n_rays, 3), dtype=np.float32)
        self.counts = np.zeros(n, dtype=np.int64)
        self.space = sensor.observation_space
        self.obs = np.zeros((n, *self.space.shape), dtype=np.float32)
        self._flat = self.obs.reshape(n, -1)
        enc = sensor.encoder
        self.slow_paths: list[str] = []
        if self.noisy:
            self.slow_paths.append(f"sensor.noise={cfg.noise}")
        self.encoders: list | None = None  # the scalar encoders, one per rover, for the slow encodings
        self.memory = None
        if self.encoding == "depth_image":
            self.scale = np.ascontiguousarray(enc._scale.reshape(-1), dtype=np.float32)
        elif self.encoding == "elevation_map" and not cfg.elevation_map.outlier_removal:
            m = cfg.elevation_map
            self.map_params = np.array([m.cell_size, m.extent_forward, m.extent_side, m.height_clip, *m.shape])
            if m.memory:
                mem = enc.memory
                self.memory = np.full((n, mem.n * mem.n), np.nan, dtype=np.float32)
                self.offsets = np.ascontiguousarray(mem._offsets)
            else:
                self.offsets = np.zeros((1, 2))
            self.mem_origin = np.zeros((n, 2))
            self.mem_set = np.zeros(n, dtype=np.bool_)
            self.mem_radius = float(m.memory_radius)
        else:
            reason = "sensor.encoding=points" if self.encoding == "points" else "sensor.elevation_map.outlier_removal"
            self.slow_paths.append(reason)
            from diana_lab.sensing.encoders import make_encoder

            self.encoders = [make_encoder(cfg, sensor.image_shape, sensor.axis_cos) for _ in range(n)]
        # the stopped-drive channel (elevation_map.hazard_radius): each rover's spots this episode
        m = cfg.elevation_map
        self.hazard_r2 = float(m.hazard_radius) ** 2 if self.encoding == "elevation_map" else 0.0
        self.spots = np.zeros((n, 8 if self.hazard_r2 > 0 else 0, 2))
        self.n_spots = np.zeros(n, dtype=np.int64)
        self.hazard_offsets = window_offsets(m.cell_size, *m.shape, m.extent_forward, m.extent_side)

    def reset(self, i: int, rng: np.random.Generator) -> None:
        """Rover ``i`` starts an episode (``RaySensor.reset``): its noise draws from ``rng``, its map is empty."""
        if self.noisy:
            self.noise[i].reset(rng)
        if self.memory is not None:
            self.memory[i].fill(np.nan)
            self.mem_set[i] = False
        if self.encoders is not None:
            self.encoders[i].reset()
        self.n_spots[i] = 0

    def mark_hazards(self, rows: np.ndarray, xy: np.ndarray) -> None:
        """The rovers ``rows`` had a drive stopped at world ``xy`` (``(len(rows), 2)``): their maps' stopped-drive
        channel shows it from the next observation on (``RaySensor.mark_hazard``); nothing without the channel."""
        if self.hazard_r2 <= 0:
            return
        for i, point in zip(rows, xy):
            if self.encoders is not None:
                self.encoders[i].mark_hazard(point)
            if self.n_spots[i] == self.spots.shape[1]:
                self.spots = np.concatenate([self.spots, np.zeros_like(self.spots)], axis=1)
            self.spots[i, self.n_spots[i]] = point[:2]
            self.n_spots[i] += 1

    def observe(self, rows: np.ndarray, state: np.ndarray) -> None:
        """Cast and encode the frames of the rovers ``rows`` at ``state`` (x, y, z, roll, pitch, yaw) into
        :attr:`obs`."""
        s = self.scene
        lo = None if self.noisy else float(self.cfg.min_range)
        cast_batch(
            rows, state, self.directions, self.mount, self.mount32, self.max_range, lo, s.xs, s.ys, s.heights,
            s.cell_max, s.block_max, s.block_cols, s.shift, s.z_range, s.ob_vertices, s.ob_triangles, s.ob_start,
            s.ob_box, s.ob_sphere, self.cam, self.proj, self.reach, self.ranges, self.cloud, self.counts,
        )  # fmt: skip
        if self.noisy:
            lo32, hi32 = np.float32(self.cfg.min_range), np.float32(self.cfg.max_range)
            for i in rows:
                t = self.noise[i].apply(self.ranges[i])
                np.putmask(t, (t < lo32) | (t > hi32), np.float32(np.nan))
                self.ranges[i] = t
            if self.encoding != "depth_image":
                clouds_batch(rows, self.ranges, self.directions, self.mount32, self.cloud, self.counts)
        if self.encoding == "depth_image":
            depth_batch(rows, self.ranges, self.scale, self._flat)
        elif self.encoders is None:
            voxel = float(self.cfg.elevation_map.voxel_size)
            elevation_batch(
                rows, state, self.cloud, self.counts, self.map_params, voxel, self.memory, self.mem_origin,
                self.mem_set, self.mem_radius, self.offsets, self._flat,
            )  # fmt: skip
            if self.hazard_r2 > 0:
                hazard_batch(rows, state, self.spots, self.n_spots, self.hazard_offsets, self.hazard_r2, 2, self._flat)
        else:
            self._encode_slow(rows, state)

    def _encode_slow(self, rows: np.ndarray, state: np.ndarray) -> None:
        """The scalar encoders, rover by rover, on the frames cast above."""
        sensor = self.sensor
        for i in rows:
            frame = SensorFrame(
                self.ranges[i].reshape(sensor.image_shape).copy(),
                state[i, :3].copy(),
                state[i, 3:6].copy(),
                sensor.caster.directions,
                sensor._mount32,
                sensor.axis_cos,
                self.cloud[i, : self.counts[i]].copy(),
            )
            self.obs[i] = self.encoders[i](frame)
