"""The paper's position controller: turn in place towards the waypoint, then drive forward to it.

The same rules serve both dynamics: :class:`TurnThenDrive` gives closed-loop wheel commands for the physics
model, and :meth:`TurnThenDrive.nominal_time` / :attr:`heading_tolerance` let the kinematic model follow the
ideal path of the same controller analytically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from diana_lab.config.sim import ControllerConfig, RobotConfig


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angle(s) to [-pi, pi)."""
    return (
        (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
        if isinstance(a, np.ndarray)
        else ((a + math.pi) % (2.0 * math.pi) - math.pi)
    )


@dataclass
class Command:
    linear: float  # m/s forward
    angular: float  # rad/s, counter-clockwise
    phase: str  # "turn", "drive" or "done"


class TurnThenDrive:
    """Turn in place until the heading error is below the tolerance, then drive with a small steering term."""

    def __init__(self, cfg: ControllerConfig, robot: RobotConfig) -> None:
        self.cfg = cfg
        self.cruise_speed = float(robot.cruise_speed)
        self.turn_speed = float(robot.turn_speed)
        self.heading_tolerance = math.radians(cfg.heading_tolerance_deg)
        self.position_tolerance = float(cfg.position_tolerance)
        self._phase = "turn"

    def start(self) -> None:
        """Begin a new waypoint (always starts with the turn phase)."""
        self._phase = "turn"

    def nominal_time(self, distance: float, heading_error: float) -> float:
        """Time the ideal controller needs: the turn plus the straight drive."""
        return abs(heading_error) / self.turn_speed + max(distance - self.position_tolerance, 0.0) / self.cruise_speed

    def time_limit(self, distance: float, heading_error: float) -> float:
        """When the controller gives up on a waypoint."""
        return self.cfg.timeout_factor * self.nominal_time(distance, heading_error) + self.cfg.timeout_margin

    def command(self, xy: np.ndarray, yaw: float, waypoint: np.ndarray) -> Command:
        dx, dy = float(waypoint[0] - xy[0]), float(waypoint[1] - xy[1])
        distance = math.hypot(dx, dy)
        if distance <= self.position_tolerance:
            self._phase = "done"
            return Command(0.0, 0.0, "done")
        error = wrap_angle(math.atan2(dy, dx) - yaw)
        if self._phase == "turn" and abs(error) <= self.heading_tolerance:
            self._phase = "drive"
        elif self._phase == "drive" and abs(error) > max(4.0 * self.heading_tolerance, math.radians(30.0)):
            self._phase = "turn"  # knocked far off course (slip): turn in place again
        if self._phase == "turn":
            # slow down close to the target heading so that the turn does not overshoot
            w = math.copysign(min(self.turn_speed, max(2.0 * abs(error), 0.25 * self.turn_speed)), error)
            return Command(0.0, w, "turn")
        w = float(np.clip(self.cfg.steer_gain * error, -self.turn_speed, self.turn_speed))
        v = self.cruise_speed * min(1.0, distance / 0.5 + 0.3)
        return Command(v, w, "drive")
