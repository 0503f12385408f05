"""A spinning multi-beam 3-D lidar: ``beams`` elevation channels x a full 360 deg of azimuth steps."""

from __future__ import annotations

import numpy as np

from diana_lab.config.sensing import Lidar3dConfig
from diana_lab.sensing.sensor import RaySensor

__all__ = ["Lidar3d", "lidar_pattern"]


def lidar_pattern(beams: int, vfov_min_deg: float, vfov_max_deg: float, columns: int) -> np.ndarray:
    """``(beams, columns, 3)`` unit directions in the sensor frame.

    Row 0 is the highest beam; elevations are evenly spaced from ``vfov_max_deg`` down to ``vfov_min_deg``
    (a single beam looks at their mean). Column ``j`` is at azimuth ``pi - (j + 0.5) * 2 pi / columns``:
    the range image starts behind the sensor and sweeps through left, forward (the middle columns) and
    right, so it reads like a panorama with the forward direction in the centre.
    """
    if beams == 1:
        elevation = np.radians([(vfov_min_deg + vfov_max_deg) / 2.0])
    else:
        elevation = np.radians(np.linspace(vfov_max_deg, vfov_min_deg, beams))
    azimuth = np.pi - (np.arange(columns) + 0.5) * (2.0 * np.pi / columns)
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


class Lidar3d(RaySensor):
    """A 3-D lidar; its range image is ``beams x columns`` and ``SensorFrame.depth`` is ``None``."""

    cfg: Lidar3dConfig

    def pattern(self) -> np.ndarray:
        c = self.cfg
        return lidar_pattern(c.beams, c.vfov_min_deg, c.vfov_max_deg, c.columns)
