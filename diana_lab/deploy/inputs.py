"""The runtime's inputs: the pose estimate, the goal and the raw cloud, checked, and the goal vector.

On a rover these come from other processes (localisation, a mission planner, a camera driver); a NaN or
a transposed array must fail loudly here, naming the argument, instead of turning into a plausible but
wrong waypoint further down.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Pose", "check_cloud", "check_goal", "goal_vector"]


@dataclass(frozen=True)
class Pose:
    """The rover's pose estimate in the world frame: position (m) and roll, pitch, yaw (rad, ZYX)."""

    x: float
    y: float
    z: float
    roll: float
    pitch: float
    yaw: float

    @classmethod
    def of(cls, pose: Pose | Sequence[float] | np.ndarray) -> Pose:
        """A :class:`Pose` from itself or ``(x, y, z, roll, pitch, yaw)``; ``ValueError`` naming ``pose``."""
        if isinstance(pose, Pose):
            fields = (pose.x, pose.y, pose.z, pose.roll, pose.pitch, pose.yaw)
            if all(type(v) is float and math.isfinite(v) for v in fields):
                return pose  # frozen, Python floats and finite: nothing to convert
            try:
                values = np.array([pose.x, pose.y, pose.z, pose.roll, pose.pitch, pose.yaw], dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"pose: expected 6 numbers (x, y, z, roll, pitch, yaw), got {pose!r}") from exc
        else:
            try:
                values = np.asarray(pose, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"pose: expected 6 numbers (x, y, z, roll, pitch, yaw), got {pose!r}") from exc
            if values.shape != (6,):
                raise ValueError(f"pose: expected shape (6,) = (x, y, z, roll, pitch, yaw), got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"pose: expected finite values, got {values.tolist()}")
        if np.any(np.abs(values[3:5]) > math.pi):  # a rover's roll and pitch: degrees given for radians
            raise ValueError(f"pose: roll and pitch are radians within [-pi, pi], got {values[3:5].tolist()}")
        return cls(*(float(v) for v in values))

    @property
    def xy(self) -> np.ndarray:
        return np.array([self.x, self.y])


def check_goal(goal: Any) -> np.ndarray:
    """The goal ``(x, y)`` in the world frame as float64; ``ValueError`` naming ``goal``."""
    try:
        g = np.asarray(goal, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"goal: expected (x, y) in the world frame, got {goal!r}") from exc
    if g.shape != (2,):
        raise ValueError(f"goal: expected shape (2,) = (x, y) in the world frame, got {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError(f"goal: expected finite values, got {g.tolist()}")
    return g


def check_cloud(cloud: Any, drop_invalid: bool = False) -> np.ndarray:
    """The cloud as a float64 ``(N, 3)`` array in the sensor frame; ``ValueError`` naming ``cloud``.

    Non-finite points are an error unless ``drop_invalid`` (organised clouds from depth drivers mark
    missing pixels with NaN; dropping them is then the intended behaviour, but it must be asked for).
    An empty cloud is always an error: it is far more often a broken driver than a clear view.
    """
    if not isinstance(drop_invalid, bool | np.bool_):
        raise ValueError(f"drop_invalid: expected True or False, got {drop_invalid!r}")
    try:
        pts = np.asarray(cloud, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"cloud: expected an (N, 3) array of numbers, got {type(cloud).__name__}") from exc
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"cloud: expected shape (N, 3) (x, y, z in the sensor frame), got {pts.shape}")
    # one reduction in the usual case: a NaN or inf anywhere makes the sum non-finite (so may an overflow of
    # huge finite values: the per-point test below then decides)
    finite = np.isfinite(pts).all(axis=1) if not np.isfinite(pts.sum()) else None
    if finite is not None and not finite.all():
        if not drop_invalid:
            raise ValueError(
                f"cloud: {int((~finite).sum())} of {len(pts)} points are NaN or infinite; pass "
                "drop_invalid=True to ignore them"
            )
        pts = pts[finite]
    if len(pts) == 0:
        raise ValueError("cloud: no points (an empty cloud is treated as a sensor failure, not as free space)")
    return pts


def goal_vector(pose: Pose, goal: np.ndarray, distance_scale: float, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The env's ``goal`` observation (:meth:`RoverNavEnv._goal_vector`): float64 maths, clipped, float32.

    ``[distance / distance_scale, sin(heading error), cos(heading error), roll / (pi/2), pitch / (pi/2),
    sin(yaw), cos(yaw)]`` with the heading error wrapped to [-pi, pi).
    """
    dx, dy = goal[0] - pose.x, goal[1] - pose.y
    distance = math.hypot(dx, dy)
    error = (math.atan2(dy, dx) - pose.yaw + math.pi) % (2.0 * math.pi) - math.pi
    g = np.array(
        [
            distance / distance_scale,
            math.sin(error),
            math.cos(error),
            pose.roll / (math.pi / 2),
            pose.pitch / (math.pi / 2),
            math.sin(pose.yaw),
            math.cos(pose.yaw),
        ]
    )
    return np.clip(g, low, high).astype(np.float32)
