"""Raw sensor-frame point cloud -> the policy's sensor tensor, exactly as the training encoders build it.

The training encoders (:mod:`diana_lab.sensing.encoders`) start from the simulated sensor's range image;
a real sensor hands over a point cloud. Each encoder here turns the cloud back into what the training
encoder saw:

* ``depth_image``: the points are projected into the trained sensor's pixel grid (pinhole camera) or
  beam x azimuth grid (lidar); each cell keeps its nearest return (depth along the optical axis for a
  camera, range for a lidar) divided by ``max_range``, and cells without a return get ``no_return``.
  Pure numpy, no open3d.
* ``elevation_map`` and ``points``: the points go to the rover frame through the mount and then through the
  same steps as in training (levelling by the pose's roll and pitch, open3d voxel down-sampling, binning or
  subsampling). open3d is imported only here, and only when a voxel size (or outlier removal) asks for it.

Every encoder first drops the points the trained sensor could not have returned (outside its range or
field of view). An ``elevation_map`` trained with ``memory: true`` keeps the episode's map
(:class:`~diana_lab.core.height_memory.HeightMemory`, the class the training encoder uses): call
:meth:`CloudEncoder.reset` (``Navigator.reset``) whenever a new goal starts a new traverse.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from diana_lab.core.hazard_memory import HazardMemory
from diana_lab.core.height_memory import HeightMemory
from diana_lab.core.rotations import level_points
from diana_lab.deploy.geometry import SensorModel
from diana_lab.deploy.inputs import Pose
from diana_lab.deploy.spec import EncodingSpec, SensorSpec

__all__ = ["CloudEncoder", "DepthImage", "ElevationMap", "Points", "make_cloud_encoder"]


def _o3d_cloud(points: np.ndarray) -> Any:
    import open3d as o3d  # only the voxel-based encodings pay for it

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def _positions(cloud: Any) -> np.ndarray:
    return np.asarray(cloud.points, dtype=np.float32).reshape(-1, 3)


class CloudEncoder:
    """Base: ``encoder(points_sensor, pose)`` -> float32 array of ``shape`` (no batch axis)."""

    shape: tuple[int, ...]

    def __init__(self, sensor: SensorSpec, encoding: EncodingSpec) -> None:
        self.sensor = SensorModel(sensor)
        self.encoding = encoding
        self.shape = tuple(encoding.shape)
        self._last_visible: tuple[np.ndarray, np.ndarray] | None = None  # (cloud, its visible rover points)

    def visible_rover_points(self, points: np.ndarray) -> np.ndarray:
        """The points the trained sensor could see, in the rover frame, float32 and in their given order
        (the simulated frame lists its returns row-major, and the ``points`` subsample depends on order).

        The result for the latest cloud is kept: the slope shield asks again for the cloud the encoding
        just used (the same array object, unchanged in between: a caller that edits a cloud in place must
        pass a copy)."""
        last = self._last_visible
        if last is not None and last[0] is points:
            return last[1]
        idx, _ = self.sensor.locate(points, pixels=False)
        seen = points if len(idx) == len(points) else points.take(idx, axis=0)  # usually every point
        visible = self.sensor.to_rover(seen).astype(np.float32)
        self._last_visible = (points, visible)
        return visible

    def reset(self) -> None:
        """A new traverse: stateful encodings forget their map."""

    def mark_hazard(self, xy: np.ndarray) -> None:
        """A drive was stopped at world ``xy``: kept only by an ``elevation_map`` with the stopped-drive channel."""

    def __call__(self, points: np.ndarray, pose: Pose) -> np.ndarray:
        raise NotImplementedError


class DepthImage(CloudEncoder):
    """``(1, H, W)`` in [0, 1]: nearest return per pixel / ``max_range``; ``no_return`` where there is none."""

    def __init__(self, sensor: SensorSpec, encoding: EncodingSpec) -> None:
        super().__init__(sensor, encoding)
        self.no_return = np.float32(encoding.param("no_return"))
        self._inv_max = 1.0 / sensor.max_range
        self._camera = sensor.type == "depth_camera"
        rows, cols = self.sensor.rows, self.sensor.cols
        if self.shape != (1, rows, cols):
            raise ValueError(f"encoding.shape: expected (1, {rows}, {cols}) for this sensor, got {self.shape}")

    def __call__(self, points: np.ndarray, pose: Pose) -> np.ndarray:
        idx, pixel = self.sensor.locate(points)
        seen = points.take(idx, axis=0)
        # a camera reports depth along its optical axis (x), a lidar the range along the ray
        value = seen[:, 0] if self._camera else self.sensor.ranges(seen)
        out = np.full(self.sensor.rows * self.sensor.cols, self.no_return, dtype=np.float32)
        np.minimum.at(out, pixel, (value * self._inv_max).astype(np.float32))  # nearest return per pixel
        return out.reshape(self.shape)


class ElevationMap(CloudEncoder):
    """``(2, rows, cols)``: highest levelled point per cell and a known mask (see the training encoder); a third
    channel, the stopped-drive channel, where the sidecar's ``hazard_radius`` is set (:meth:`mark_hazard`, fed by
    ``Navigator.report_hazard``)."""

    def __init__(self, sensor: SensorSpec, encoding: EncodingSpec) -> None:
        super().__init__(sensor, encoding)
        p = encoding.param
        self.cell_size, self.height_clip = float(p("cell_size")), float(p("height_clip"))
        self.extent_forward, self.extent_side = float(p("extent_forward")), float(p("extent_side"))
        self.voxel_size, self.outlier_removal = float(p("voxel_size")), bool(p("outlier_removal"))
        self.nb_neighbors, self.std_ratio = int(p("nb_neighbors")), float(p("std_ratio"))
        self.unknown_height = np.float32(p("unknown_height"))
        hazard_radius = float(encoding.params.get("hazard_radius", 0.0))  # absent from older sidecars: none
        channels = 3 if hazard_radius > 0 else 2
        if len(self.shape) != 3 or self.shape[0] != channels:
            raise ValueError(
                f"encoding.shape: expected ({channels}, rows, cols) for elevation_map with hazard_radius "
                f"{hazard_radius:g}, got {self.shape}"
            )
        self.rows, self.cols = self.shape[1], self.shape[2]
        self.hazards = (
            HazardMemory(hazard_radius, self.cell_size, self.rows, self.cols, self.extent_forward, self.extent_side)
            if hazard_radius > 0
            else None
        )
        # the world points of the latest frame the memory fused, when they are every visible return of that frame
        # (no voxel or outlier filter): the slope shield then maps them without levelling them again
        self.fused_points: np.ndarray | None = None
        self.memory = (
            HeightMemory(
                self.cell_size, float(p("memory_radius")), self.rows, self.cols, self.extent_forward, self.extent_side
            )
            if bool(encoding.params.get("memory", False))
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

    def _filter(self, pts: np.ndarray) -> np.ndarray:
        if len(pts) == 0 or (self.voxel_size <= 0 and not self.outlier_removal):
            return pts
        cloud = _o3d_cloud(pts)
        if self.voxel_size > 0:
            cloud = cloud.voxel_down_sample(self.voxel_size)
        if self.outlier_removal and len(cloud.points) > self.nb_neighbors:
            cloud, _ = cloud.remove_statistical_outlier(self.nb_neighbors, self.std_ratio)
        return _positions(cloud)

    def __call__(self, points: np.ndarray, pose: Pose) -> np.ndarray:
        rows, cols, clip = self.rows, self.cols, self.height_clip
        pts = self.visible_rover_points(points)
        if len(pts):
            pts = level_points(pts, pose.roll, pose.pitch)
        pts = self._filter(pts)
        self.fused_points = None
        if self.memory is not None:
            top = self.memory.fuse(pts, (pose.x, pose.y, pose.z), pose.yaw)
            if self.voxel_size <= 0 and not self.outlier_removal:  # unfiltered: what the slope shield maps too
                self.fused_points = self.memory.last_world
        else:
            inv = 1.0 / self.cell_size
            row = np.floor((self.extent_forward - pts[:, 0]) * inv).astype(np.int64)
            col = np.floor((self.extent_side - pts[:, 1]) * inv).astype(np.int64)
            ok = np.flatnonzero((row >= 0) & (row < rows) & (col >= 0) & (col < cols))
            top = np.full(rows * cols, -np.inf, dtype=np.float32)
            np.maximum.at(top, row.take(ok) * cols + col.take(ok), pts[:, 2].take(ok))
        known = top > -np.inf
        out = np.empty((self.shape[0], rows * cols), dtype=np.float32)
        height = np.clip(top, -clip, clip) * (0.5 / clip) + 0.5
        out[0] = np.where(known, height, self.unknown_height)
        out[1] = known
        if self.hazards is not None:
            out[2] = self.hazards.window(pose.x, pose.y, pose.yaw)
        return out.reshape(self.shape)


class Points(CloudEncoder):
    """``(n_points, 4)``: voxel-down-sampled rover-frame points / ``scale`` plus a mask column."""

    def __init__(self, sensor: SensorSpec, encoding: EncodingSpec) -> None:
        super().__init__(sensor, encoding)
        p = encoding.param
        self.n_points, self.method = int(p("n_points")), str(p("method"))
        self.voxel_size, self.scale = float(p("voxel_size")), float(p("scale"))
        if self.shape != (self.n_points, 4):
            raise ValueError(f"encoding.shape: expected ({self.n_points}, 4) for points, got {self.shape}")

    def select(self, pts: np.ndarray) -> np.ndarray:
        n = self.n_points
        if self.voxel_size > 0 and len(pts):
            pts = _positions(_o3d_cloud(pts).voxel_down_sample(self.voxel_size))
        if len(pts) <= n:
            return pts
        if self.method == "fps":
            return _positions(_o3d_cloud(pts).farthest_point_down_sample(n))
        return pts[(np.arange(n) * len(pts)) // n]

    def __call__(self, points: np.ndarray, pose: Pose) -> np.ndarray:
        pts = self.select(self.visible_rover_points(points))
        out = np.zeros(self.shape, dtype=np.float32)
        m = len(pts)
        np.clip(pts * (1.0 / self.scale), -1.0, 1.0, out=out[:m, :3])
        out[:m, 3] = 1.0
        return out


ENCODERS: dict[str, type[CloudEncoder]] = {"depth_image": DepthImage, "elevation_map": ElevationMap, "points": Points}


def make_cloud_encoder(sensor: SensorSpec, encoding: EncodingSpec) -> CloudEncoder:
    """The runtime encoder named by ``encoding.name``."""
    return ENCODERS[encoding.name](sensor, encoding)
