"""Frames and ray patterns of the trained sensor, in numpy only (no open3d, no gymnasium, no torch).

Rotations come from :mod:`diana_lab.core.rotations` (numpy only, shared with the simulator). These mirror
:func:`diana_lab.sensing.camera.pinhole_pattern` and
:func:`diana_lab.sensing.lidar.lidar_pattern` (the tests hold them against each other): the runtime must
not import :mod:`diana_lab.sensing`, which pulls in open3d and gymnasium at import time.

Frames: rover x forward, y left, z up; the sensor frame is the sensor's BODY frame, also x forward (the
optical axis of a camera), y left, z up -- not the optical frame (z forward, x right, y down) that ROS
camera drivers publish; see :func:`optical_to_body`.
"""

from __future__ import annotations

import math

import numpy as np

from diana_lab.core.rotations import leveling_matrix, pitch_matrix, rpy_matrix
from diana_lab.deploy.spec import SensorSpec

__all__ = ["SensorModel", "leveling_matrix", "optical_to_body", "pitch_matrix", "rpy_matrix"]

RANGE_SLACK = 1e-6  # relative: a return at exactly max_range must survive a float round trip


def optical_to_body(points: np.ndarray) -> np.ndarray:
    """A camera-optical-frame cloud (z forward, x right, y down; ROS ``*_optical_frame``) in the body frame."""
    p = np.asarray(points)
    return np.stack([p[:, 2], -p[:, 0], -p[:, 1]], axis=1)


class SensorModel:
    """Where a sensor-frame point falls in the trained sensor's range image, and the sensor -> rover transform.

    ``locate`` keeps the points a simulated sensor could have returned (range in ``[min_range, max_range]``,
    inside the field of view) so that a real sensor with a wider view or longer range shows the policy
    what the trained one showed it.
    """

    def __init__(self, spec: SensorSpec) -> None:
        self.spec = spec
        self.rows, self.cols = spec.image_shape
        self.mount = np.asarray(spec.mount_xyz, dtype=np.float64)
        self.mount_rotation = pitch_matrix(spec.mount_pitch)
        self._mount_tiled = np.tile(self.mount, 4096)  # to_rover's flat add; grows with the clouds
        self._r2_min = spec.min_range**2 * (1.0 - RANGE_SLACK)
        self._r2_max = spec.max_range**2 * (1.0 + RANGE_SLACK)
        if spec.type == "depth_camera":
            self._inv_tan_h = 1.0 / math.tan(math.radians(spec.hfov_deg) / 2.0)  # type: ignore[arg-type]
            self._inv_tan_v = 1.0 / math.tan(math.radians(spec.vfov_deg) / 2.0)  # type: ignore[arg-type]
        else:
            top, bottom = math.radians(spec.vfov_max_deg), math.radians(spec.vfov_min_deg)  # type: ignore[arg-type]
            self._el_top = top if self.rows > 1 else (top + bottom) / 2.0
            # a beam covers half the spacing to its neighbours; a single beam +-half the configured span (min 1 deg)
            self._el_step = (top - bottom) / (self.rows - 1) if self.rows > 1 else 0.0
            self._el_half = self._el_step / 2.0 if self.rows > 1 else max((top - bottom) / 2.0, math.radians(1.0))
            self._az_step = 2.0 * math.pi / self.cols
            # the elevations the beams cover, as slopes z / hypot(x, y): the test of ``locate(pixels=False)``,
            # which needs no arctan (None: the bound lies at or past the vertical and excludes nothing)
            low, high = self._el_top - (self.rows - 1) * self._el_step - self._el_half, self._el_top + self._el_half
            self._slope_low = math.tan(low) if low > -math.pi / 2 else None
            self._slope_high = math.tan(high) if high < math.pi / 2 else None

    def to_rover(self, points: np.ndarray) -> np.ndarray:
        """Sensor-frame points ``(N, 3)`` in the rover frame (float64): ``R_mount @ p + mount``."""
        out = points @ self.mount_rotation.T
        # `+ mount` as one flat add of the mount repeated: the same sums, but numpy broadcasts a 3-wide row at
        # ~10x the cost (this runs on every onboard decision)
        n = 3 * len(out)
        if len(self._mount_tiled) < n:
            self._mount_tiled = np.tile(self.mount, max(len(out), 2 * len(self._mount_tiled) // 3))
        out.reshape(-1)[:] += self._mount_tiled[:n]
        return out

    def locate(self, points: np.ndarray, pixels: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """``(index, pixel)``: the indices of the points the trained sensor could see and their flat pixel
        index ``row * cols + col`` in its range image (``None`` with ``pixels=False``: a lidar then skips the
        azimuth, which never hides a point from a 360-degree sensor)."""
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        flat2 = x * x + y * y
        r2 = flat2 + z * z
        ok = (r2 >= self._r2_min) & (r2 <= self._r2_max)
        if self.spec.type != "depth_camera" and not pixels:
            # a spinning lidar sees every azimuth: only the beams' elevation span decides (the same points as
            # rounding the elevation to a beam below, but for exact ties, at a third of the cost)
            flat = np.sqrt(flat2)
            if self._slope_low is not None:
                ok &= z >= flat * self._slope_low
            if self._slope_high is not None:
                ok &= z <= flat * self._slope_high
            return np.flatnonzero(ok), None
        if self.spec.type == "depth_camera":
            ok &= x > 0
            idx = np.flatnonzero(ok)
            xs = x[idx]
            col = np.floor((-y[idx] / xs * self._inv_tan_h + 1.0) * (0.5 * self.cols))
            row = np.floor((-z[idx] / xs * self._inv_tan_v + 1.0) * (0.5 * self.rows))
        else:
            idx = np.flatnonzero(ok)
            xs, ys, zs = x[idx], y[idx], z[idx]
            drop = self._el_top - np.arctan2(zs, np.hypot(xs, ys))  # angle below the top beam
            row = np.round(drop / self._el_step) if self.rows > 1 else np.zeros_like(drop)
            off_beam = np.abs(drop - row * self._el_step) > self._el_half
            row = np.where(off_beam, -1.0, row)
            col = np.floor((math.pi - np.arctan2(ys, xs)) / self._az_step) % self.cols
        inside = (row >= 0) & (row < self.rows) & (col >= 0) & (col < self.cols)
        keep = np.flatnonzero(inside)
        if not pixels:
            return idx.take(keep), None
        pixel = row.take(keep).astype(np.int64) * self.cols + col.take(keep).astype(np.int64)
        return idx.take(keep), pixel

    def ranges(self, points: np.ndarray) -> np.ndarray:
        """Distance of each point from the sensor (what a lidar range image holds)."""
        return np.sqrt(np.einsum("ij,ij->i", points, points))
