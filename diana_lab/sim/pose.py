"""The pose service: the rover's estimate of its own pose, as the agent and the controller see it.

The paper assumes a reliable localisation service; ``dynamics.pose_noise`` makes it imperfect (zero-mean
Gaussian errors, drawn from the env's generator so that runs stay reproducible).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from diana_lab.config.sim import PoseNoiseConfig
from diana_lab.sim.state import RoverState


@dataclass(frozen=True)
class PoseEstimate:
    xy: np.ndarray
    yaw: float
    roll: float
    pitch: float


class PoseService:
    def __init__(self, cfg: PoseNoiseConfig) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(0)
        self._noisy = cfg.position_std > 0 or cfg.yaw_std_deg > 0 or cfg.tilt_std_deg > 0

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def estimate(self, state: RoverState) -> PoseEstimate:
        roll, pitch, yaw = state.rpy.tolist()
        xy = state.position[:2].copy()
        if self._noisy:
            c = self.cfg
            xy = xy + self.rng.normal(0.0, c.position_std, 2)
            yaw += self.rng.normal(0.0, math.radians(c.yaw_std_deg))
            roll += self.rng.normal(0.0, math.radians(c.tilt_std_deg))
            pitch += self.rng.normal(0.0, math.radians(c.tilt_std_deg))
        return PoseEstimate(xy, yaw, roll, pitch)

    def xy_yaw(self, state: RoverState) -> tuple[np.ndarray, float]:
        """The controller's view: estimated position and heading (for the dynamics' ``pose_estimate``)."""
        if not self._noisy:  # the estimate is the state itself: skip building a PoseEstimate
            return state.position[:2].copy(), float(state.rpy[2])
        est = self.estimate(state)
        return est.xy, est.yaw
