"""Ray-cast range sensors (depth camera, 3-D lidar), their noise models and observation encoders.

Build one from the ``sensor`` config with ``diana_lab.config.build(cfg, world)``; see
:mod:`diana_lab.sensing.sensor` for the calls the env makes.
"""

from diana_lab.sensing.camera import DepthCamera
from diana_lab.sensing.frame import SensorFrame
from diana_lab.sensing.lidar import Lidar3d
from diana_lab.sensing.sensor import RaySensor

__all__ = ["DepthCamera", "Lidar3d", "RaySensor", "SensorFrame"]
