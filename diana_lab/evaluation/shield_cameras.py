"""The slope shield's hazard cameras in the simulator: depth cameras whose returns feed only the shield's map.

Why they exist: in physics the rover tips over on relief a cell or two wide that its lidar does not resolve (a
32-beam lidar's rings lie 0.3 m and more apart beyond 2.5 m, and it leaves the ground near the rover unseen).
Depth cameras round a mast fill that ground in (docs/reference_policy.md, "Hazard cameras", has the figures).
The network still sees only its own sensor: the cameras change
what the shield lets through, not what the policy chooses.

Each camera is the platform's :class:`~diana_lab.sensing.camera.DepthCamera` with the env sensor's noise. A
camera turned ``yaw_deg`` from the heading is the same camera on a rover turned by ``yaw_deg``: it is cast from
that turned pose, and its returns, in that turned frame, are mapped with it (so no sensor needs a yaw mount).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["ShieldCameras", "turned_attitude"]


def turned_attitude(rpy: np.ndarray, yaw_deg: float) -> np.ndarray:
    """The roll, pitch, yaw (ZYX) of a body with attitude ``rpy`` turned by ``yaw_deg`` about its own z axis."""
    from diana_lab.core.rotations import rpy_matrix

    if yaw_deg == 0.0:
        return np.asarray(rpy, dtype=np.float64).copy()
    a = math.radians(yaw_deg)
    turn = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    m = rpy_matrix(np.asarray(rpy, dtype=np.float64)) @ turn
    pitch = -math.asin(max(-1.0, min(1.0, m[2, 0])))
    return np.array([math.atan2(m[2, 1], m[2, 2]), pitch, math.atan2(m[1, 0], m[0, 0])])


class ShieldCameras:
    """The cameras of ``eval.shield.cameras`` on one world; :meth:`reset` per episode, :meth:`feed` per decision.

    Args:
        cameras: the ``ShieldCameraConfig`` entries.
        sensor: the env sensor's config (its noise preset and level are the cameras' too).
        world: the world they cast against.
    """

    def __init__(self, cameras: Sequence[Any], sensor: Any, world: Any) -> None:
        from diana_lab.config import build
        from diana_lab.config.sensing import DepthCameraConfig

        self.world = world
        self.yaws = [float(c.yaw_deg) for c in cameras]
        self.cameras = [
            build(
                DepthCameraConfig(
                    mount_xyz=[float(v) for v in c.mount_xyz],
                    mount_pitch_deg=float(c.pitch_deg),
                    width=int(c.width),
                    height=int(c.height),
                    hfov_deg=float(c.hfov_deg),
                    vfov_deg=float(c.vfov_deg),
                    max_range=float(c.max_range),
                    noise=sensor.noise,
                    noise_level=float(sensor.noise_level),
                ),
                world,
            )
            for c in cameras
        ]

    def __len__(self) -> int:
        return len(self.cameras)

    def reset(self, rng: np.random.Generator) -> None:
        """A new episode: the cameras' noise draws from ``rng`` (one generator, the cameras in turn)."""
        for camera in self.cameras:
            camera.reset(rng)

    def body_frames(self, position: np.ndarray, rpy: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """Every camera's returns from the rover pose in the rover's body frame, with the camera's position in it:
        ``[(points (N, 3) float64, sensor_xyz (3,))]``, what a rover hands :meth:`Navigator.map_for_shield`."""
        frames = []
        for camera, yaw in zip(self.cameras, self.yaws, strict=True):
            a = math.radians(yaw)
            turn = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
            points = camera.capture(position, turned_attitude(rpy, yaw)).points.astype(np.float64)
            frames.append((points @ turn.T, turn @ camera.mount))
        return frames

    def feed(self, shield: Any, position: np.ndarray, rpy: np.ndarray) -> None:
        """Cast every camera from the rover pose ``position``, ``rpy`` and map its returns into ``shield``."""
        for camera, yaw in zip(self.cameras, self.yaws, strict=True):
            pose = turned_attitude(rpy, yaw)
            frame = camera.capture(position, pose)
            shield.observe_rover(frame.points, frame.position, pose, camera.mount)
