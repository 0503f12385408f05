"""A pinhole depth camera (an Intel RealSense D435 by default), ray-cast at ``width x height`` pixels."""

from __future__ import annotations

import math

import numpy as np

from diana_lab.config.sensing import DepthCameraConfig
from diana_lab.sensing.pinhole import Pinhole
from diana_lab.sensing.sensor import RaySensor

__all__ = ["DepthCamera", "pinhole_pattern"]


def pinhole_pattern(width: int, height: int, hfov_deg: float, vfov_deg: float) -> np.ndarray:
    """``(height, width, 3)`` unit directions through the pixel centres, in the sensor frame.

    The optical axis is +x; pixel column ``j`` grows to the right (-y) and row ``i`` downwards (-z), as in
    the picture the camera takes. Pixels sample the image plane uniformly (a pinhole, not equal angles).
    """
    u = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * math.tan(math.radians(hfov_deg) / 2.0)
    v = ((np.arange(height) + 0.5) / height * 2.0 - 1.0) * math.tan(math.radians(vfov_deg) / 2.0)
    uu, vv = np.meshgrid(u, v)
    d = np.stack([np.ones_like(uu), -uu, -vv], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


class DepthCamera(RaySensor):
    """A depth camera; ``SensorFrame.depth`` is the z-buffer depth (along the optical axis)."""

    cfg: DepthCameraConfig

    def pattern(self) -> np.ndarray:
        c = self.cfg
        return pinhole_pattern(c.width, c.height, c.hfov_deg, c.vfov_deg)

    def pinhole(self, mount_rotation: np.ndarray) -> Pinhole:
        c = self.cfg
        tan_h, tan_v = math.tan(math.radians(c.hfov_deg) / 2.0), math.tan(math.radians(c.vfov_deg) / 2.0)
        return Pinhole(c.width, c.height, tan_h, tan_v, mount_rotation)

    def optical_axis_cos(self, pattern: np.ndarray) -> np.ndarray:
        return pattern[..., 0].astype(np.float32)  # x component of a unit vector = cos to the +x axis
