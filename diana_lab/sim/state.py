"""What both dynamics models report: the rover state and the outcome of executing one waypoint."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

Outcome = Literal["reached", "gave_up", "collision", "tipover", "stuck", "out_of_bounds", "sim_error", "halted"]
FAILURES: tuple[str, ...] = ("collision", "tipover", "stuck", "out_of_bounds", "sim_error")


@dataclass
class RoverState:
    """Ground-truth rover state. Angles in radians; ``rpy`` is (roll, pitch, yaw), ZYX convention."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))
    linear_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    time: float = 0.0  # simulated seconds since reset

    @property
    def xy(self) -> np.ndarray:
        return self.position[:2]

    @property
    def yaw(self) -> float:
        return float(self.rpy[2])

    @property
    def tilt_deg(self) -> float:
        """Angle between the body's up axis and the world vertical."""
        return tilt_deg(self.rpy[0], self.rpy[1])

    def copy(self) -> RoverState:
        return RoverState(
            self.position.copy(),
            self.rpy.copy(),
            self.linear_velocity.copy(),
            self.angular_velocity.copy(),
            self.time,
        )


def tilt_deg(roll: np.ndarray | float, pitch: np.ndarray | float) -> np.ndarray | float:
    """Tilt of the body z axis from vertical for ZYX roll/pitch: ``acos(cos(roll) cos(pitch))``.

    Scalars go through ``math`` (a tenth of numpy's per-call cost; the env asks for one every step).
    """
    if isinstance(roll, float) and isinstance(pitch, float):  # numpy's float64 scalars included
        return math.degrees(math.acos(min(max(math.cos(roll) * math.cos(pitch), -1.0), 1.0)))
    c = np.cos(roll) * np.cos(pitch)
    return np.degrees(np.arccos(np.minimum(np.maximum(c, -1.0), 1.0)))


@dataclass
class WaypointResult:
    """The outcome of handing one waypoint to the position controller.

    ``trace_xy``/``trace_tilt_deg``/``trace_rp`` sample the driven path (including the final pose) so that
    evaluation and rendering never have to re-simulate it.
    """

    outcome: Outcome
    duration: float  # simulated seconds spent on this waypoint
    path_length: float  # metres driven (xy)
    trace_xy: np.ndarray  # (K, 2)
    trace_tilt_deg: np.ndarray  # (K,)
    trace_rp: np.ndarray  # (K, 2) roll, pitch in radians
    detail: str = ""  # human-readable reason, e.g. which body was hit
    trace_t: np.ndarray | None = None  # (K,) seconds since the waypoint started; None: evenly spaced
    # where the wheels met ground they could not drive (xy): the tilt guard's halt (``halted``) or a slope too
    # steep to climb (``stuck``); None otherwise. Proprioception: what a rover's IMU and odometry report
    hazard_xy: np.ndarray | None = None

    @property
    def reached(self) -> bool:
        return self.outcome == "reached"

    @property
    def failed(self) -> bool:
        return self.outcome in FAILURES

    def sample_durations(self) -> np.ndarray:
        """Seconds each trace sample stands for (for time-weighted statistics such as time over 15 degrees)."""
        k = len(self.trace_tilt_deg)
        if k == 0:
            return np.zeros(0)
        if self.trace_t is None or len(self.trace_t) != k:
            return np.full(k, self.duration / k)
        t = np.asarray(self.trace_t, dtype=np.float64)
        durations = np.empty(k)  # np.diff(t, prepend=0.0), without its concatenate
        durations[0] = t[0]
        np.subtract(t[1:], t[:-1], out=durations[1:])
        return np.maximum(durations, 0.0, out=durations)

    @property
    def max_tilt_deg(self) -> float:
        return float(self.trace_tilt_deg.max()) if len(self.trace_tilt_deg) else 0.0


def hazard_ahead(length: float, heading: float) -> np.ndarray:
    """Where ground the rover could not drive is reported, relative to the rover, when it met it without
    reaching it (a tilt-guard halt or a slope while turning in place, a slope holding it while driving): half
    its ``length`` towards ``heading`` (rad). The spot may not be steep itself; reporting it keeps the slope
    shield from sending the rover that way again from here, which is what the wheels learnt."""
    return 0.5 * length * np.array([math.cos(heading), math.sin(heading)])
