"""Encoders: a :class:`SensorFrame` -> a fixed-shape float32 observation inside a gymnasium ``Box``.

Every value an encoder returns is finite and inside its ``space``: a ray without a return never leaks a
NaN or an ``inf`` into the policy, it gets a documented value instead (and, where the encoding has one, a
mask channel says so).

* ``depth_image`` ``(1, H, W)`` in [0, 1]: depth along the optical axis (cameras) or range (lidar) divided
  by ``max_range``; :data:`NO_RETURN` (1.0, "as far as the sensor sees") where there was no return.
  Channel-first, so SB3's ``CnnPolicy`` takes it (with ``normalize_images=False``).
* ``elevation_map`` ``(2, rows, cols)`` in [0, 1]: channel 0 the highest point per cell relative to the
  rover base, ``(clip(h, -c, c) / c + 1) / 2`` with ``c = height_clip`` (0.5 = level with the base) and
  :data:`UNKNOWN_HEIGHT` where the cell got no point; channel 1 is 1 for cells with points, 0 otherwise.
  The grid is rover-centred and heading-aligned but levelled (gravity up), so roll/pitch do not tilt it.
  With ``memory: true`` the cells come from a world-frame map fused over the episode
  (:class:`~diana_lab.core.height_memory.HeightMemory`), so what was seen stays known; :meth:`Encoder.reset`
  (called by the sensor's ``reset``) clears it.
* ``points`` ``(n_points, 4)``: the cloud in the rover frame down-sampled to at most ``n_points`` (voxel
  grid then an even subsample, or farthest-point sampling), xyz divided by ``max_range + |mount|`` into
  [-1, 1], column 3 the mask (1 real point, 0 padding; padded rows are all zero).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from gymnasium import spaces

from diana_lab.config.sensing import ElevationMapConfig, PointsConfig, SensorConfig
from diana_lab.core.hazard_memory import HazardMemory
from diana_lab.core.height_memory import HeightMemory
from diana_lab.core.rotations import level_points
from diana_lab.core.validation import ConfigError
from diana_lab.sensing.frame import SensorFrame

__all__ = [
    "NO_RETURN",
    "UNKNOWN_HEIGHT",
    "DepthImageEncoder",
    "ElevationMapEncoder",
    "Encoder",
    "PointsEncoder",
    "make_encoder",
]

NO_RETURN = 1.0  # depth_image value of a pixel without a return
UNKNOWN_HEIGHT = 0.0  # elevation_map height of a cell without points (its mask channel is 0)


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    # the legacy point cloud: its voxel grid and farthest-point sampling are 5x and 40x faster than the
    # tensor API's on clouds of a few thousand points (measured with open3d 0.20 on one core)
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def _positions(cloud: o3d.geometry.PointCloud) -> np.ndarray:
    return np.asarray(cloud.points, dtype=np.float32).reshape(-1, 3)


def voxel_down_sample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """Mean of the points in each ``voxel_size`` cube (open3d), or the points unchanged if 0 or empty."""
    if voxel_size <= 0 or len(points) == 0:
        return points
    return _positions(_cloud(points).voxel_down_sample(voxel_size))


class Encoder:
    """Base: ``space`` is the observation ``Box``; calling the encoder on a frame gives a value in it."""

    space: spaces.Box

    def reset(self) -> None:
        """Start an episode (only stateful encodings have anything to forget)."""

    def mark_hazard(self, xy: np.ndarray) -> None:
        """A drive was stopped at world ``xy`` (only an encoding with a stopped-drive channel keeps it)."""

    def __call__(self, frame: SensorFrame) -> np.ndarray:
        raise NotImplementedError


class DepthImageEncoder(Encoder):
    """Normalised depth (or range) image; needs only ``frame.ranges``, never the point cloud."""

    def __init__(self, image_shape: tuple[int, int], max_range: float, axis_cos: np.ndarray | None) -> None:
        h, w = image_shape
        factor = np.ones((h, w)) if axis_cos is None else np.asarray(axis_cos, dtype=np.float64)
        # depth / max_range in one multiply; valid ranges are in [min_range, max_range] so it stays in [0, 1]
        self._scale = (factor / max_range).astype(np.float32)
        self.space = spaces.Box(0.0, 1.0, (1, h, w), np.float32)

    def __call__(self, frame: SensorFrame) -> np.ndarray:
        out = np.multiply(frame.ranges, self._scale)
        np.fmin(out, NO_RETURN, out=out)  # fmin replaces NaN (no return) by NO_RETURN
        return out.reshape(self.space.shape)


class ElevationMapEncoder(Encoder):
    """Rover-centred 2.5-D grid of the highest return per cell, with a known/unknown mask channel (and, with
    ``hazard_radius``, the stopped-drive channel)."""

    def __init__(self, cfg: ElevationMapConfig) -> None:
        self.cfg = cfg
        self.rows, self.cols = cfg.shape
        self.space = spaces.Box(0.0, 1.0, (cfg.channels, self.rows, self.cols), np.float32)
        self.memory = (
            HeightMemory(cfg.cell_size, cfg.memory_radius, self.rows, self.cols, cfg.extent_forward, cfg.extent_side)
            if cfg.memory
            else None
        )
        self.hazards = (
            HazardMemory(cfg.hazard_radius, cfg.cell_size, self.rows, self.cols, cfg.extent_forward, cfg.extent_side)
            if cfg.hazard_radius > 0
            else None
        )

    def reset(self) -> None:
        if self.memory is not None:
            self.memory.reset()
        if self.hazards is not None:
            self.hazards.reset()

    def mark_hazard(self, xy: np.ndarray) -> None:
        if self.hazards is not None:
            self.hazards.mark(xy)

    def _filter(self, points: np.ndarray) -> np.ndarray:
        c = self.cfg
        if len(points) == 0 or (c.voxel_size <= 0 and not c.outlier_removal):
            return points
        cloud = _cloud(points)
        if c.voxel_size > 0:
            cloud = cloud.voxel_down_sample(c.voxel_size)
        if c.outlier_removal and len(cloud.points) > c.nb_neighbors:
            cloud, _ = cloud.remove_statistical_outlier(c.nb_neighbors, c.std_ratio)
        return _positions(cloud)

    def __call__(self, frame: SensorFrame) -> np.ndarray:
        c, rows, cols = self.cfg, self.rows, self.cols
        pts = frame.points
        if len(pts):
            pts = level_points(pts, float(frame.rpy[0]), float(frame.rpy[1]))
        pts = self._filter(pts)
        if self.memory is not None:
            top = self.memory.fuse(pts, frame.position, float(frame.rpy[2]))
        else:
            inv = 1.0 / c.cell_size
            row = np.floor((c.extent_forward - pts[:, 0]) * inv).astype(np.int64)
            col = np.floor((c.extent_side - pts[:, 1]) * inv).astype(np.int64)
            ok = np.flatnonzero((row >= 0) & (row < rows) & (col >= 0) & (col < cols))
            top = np.full(rows * cols, -np.inf, dtype=np.float32)
            np.maximum.at(top, row.take(ok) * cols + col.take(ok), pts[:, 2].take(ok))  # per-cell max, no loop
        known = top > -np.inf
        out = np.empty((c.channels, rows * cols), dtype=np.float32)
        height = np.clip(top, -c.height_clip, c.height_clip) * (0.5 / c.height_clip) + 0.5
        out[0] = np.where(known, height, UNKNOWN_HEIGHT)
        out[1] = known
        if self.hazards is not None:
            out[2] = self.hazards.window(float(frame.position[0]), float(frame.position[1]), float(frame.rpy[2]))
        return out.reshape(self.space.shape)


class PointsEncoder(Encoder):
    """A fixed-size, padded and masked point set (for PointNet-style policies)."""

    def __init__(self, cfg: PointsConfig, scale: float) -> None:
        self.cfg = cfg
        self.scale = float(scale)
        n = cfg.n_points
        low = np.tile(np.array([-1.0, -1.0, -1.0, 0.0], dtype=np.float32), (n, 1))
        self.space = spaces.Box(low, np.ones((n, 4), dtype=np.float32), dtype=np.float32)

    def select(self, points: np.ndarray) -> np.ndarray:
        """At most ``n_points`` points of the cloud (rover frame, metres), deterministic for a given cloud."""
        n = self.cfg.n_points
        pts = voxel_down_sample(points, self.cfg.voxel_size)
        if len(pts) <= n:
            return pts
        if self.cfg.method == "fps":
            return _positions(_cloud(pts).farthest_point_down_sample(n))
        return pts[(np.arange(n) * len(pts)) // n]  # an even, deterministic stride through the cloud

    def __call__(self, frame: SensorFrame) -> np.ndarray:
        pts = self.select(frame.points)
        out = np.zeros(self.space.shape, dtype=np.float32)
        m = len(pts)
        np.clip(pts * (1.0 / self.scale), -1.0, 1.0, out=out[:m, :3])
        out[:m, 3] = 1.0
        return out


def make_encoder(cfg: SensorConfig, image_shape: tuple[int, int], axis_cos: np.ndarray | None) -> Encoder:
    """The encoder named by ``cfg.encoding``."""
    if cfg.encoding == "depth_image":
        return DepthImageEncoder(image_shape, cfg.max_range, axis_cos)
    if cfg.encoding == "elevation_map":
        return ElevationMapEncoder(cfg.elevation_map)
    if cfg.encoding == "points":
        return PointsEncoder(cfg.points, cfg.max_range + float(np.linalg.norm(cfg.mount_xyz)))
    raise ConfigError(
        f"sensor.encoding: expected one of 'depth_image', 'elevation_map', 'points', got {cfg.encoding!r}"
    )
