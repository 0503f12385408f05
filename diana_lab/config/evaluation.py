"""Config schema of the ``eval`` node: the fixed evaluation suite, its conditions and its outputs.

The suite is drawn from its own generator (``eval.seed``), never from training's, so every policy and every
periodic evaluation of one run meets exactly the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diana_lab.config.sensing import MAX_RAYS
from diana_lab.config.store import register
from diana_lab.core.shield_rules import ShieldRules
from diana_lab.core.validation import (
    ConfigError,
    boolean,
    check_seed,
    in_range,
    length,
    non_negative,
    non_negative_int,
    one_of,
    ordered,
    positive,
    positive_int,
)

DYNAMICS_OPTIONS = ("kinematic", "physics")


@dataclass
class ShieldCameraConfig:
    """A depth camera that feeds only the slope shield's map (a hazard camera; the policy never sees it). It
    takes the env sensor's noise (``sensor.noise``, ``sensor.noise_level``). ``yaw_deg`` turns it from the
    rover's heading (left positive); ``mount_xyz`` is its position in the rover frame turned by ``yaw_deg`` (x
    along where it looks), so four cameras at 0, 90, 180 and -90 deg with the same ``mount_xyz`` stand round
    the mast."""

    yaw_deg: float = 0.0
    mount_xyz: list[float] = field(default_factory=lambda: [0.2, 0.0, 1.0])
    pitch_deg: float = 40.0  # down
    width: int = 256
    height: int = 192
    hfov_deg: float = 87.0
    vfov_deg: float = 58.0
    max_range: float = 6.0  # m

    def check(self, key: str) -> None:
        """Raise a :class:`ConfigError` naming ``key`` (``eval.shield.cameras[i]``) for a bad value."""
        in_range(f"{key}.yaw_deg", self.yaw_deg, -180.0, 180.0)
        length(f"{key}.mount_xyz", self.mount_xyz, 3)
        for i, v in enumerate(self.mount_xyz):
            in_range(f"{key}.mount_xyz[{i}]", v, -5.0, 5.0)
        in_range(f"{key}.pitch_deg", self.pitch_deg, -90.0, 90.0)
        positive_int(f"{key}.width", self.width)
        positive_int(f"{key}.height", self.height)
        if self.width * self.height > MAX_RAYS:
            raise ConfigError(f"{key}: expected at most {MAX_RAYS} pixels, got {self.width} x {self.height}")
        in_range(f"{key}.hfov_deg", self.hfov_deg, 0.0, 180.0, inclusive=False)
        in_range(f"{key}.vfov_deg", self.vfov_deg, 0.0, 180.0, inclusive=False)
        positive(f"{key}.max_range", self.max_range)


@dataclass
class ShieldConfig(ShieldRules):
    """``eval.shield``: the slope shield (:mod:`diana_lab.shield.slope_shield`) round a learnt discrete policy,
    choose one with ``shield=<option>`` (``conf/shield/``). Its rules and their keys: :class:`ShieldRules`."""

    enabled: bool = False
    # depth cameras that feed only the shield's map (ShieldCameraConfig); []: the env sensor's returns alone
    cameras: list[ShieldCameraConfig] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.enabled = boolean("eval.shield.enabled", self.enabled)
        self.check_rules("eval.shield")
        for i, camera in enumerate(self.cameras):
            if not isinstance(camera, ShieldCameraConfig):
                raise ConfigError(
                    f"eval.shield.cameras[{i}]: expected a camera (yaw_deg, mount_xyz, pitch_deg, width, height, "
                    f"hfov_deg, vfov_deg, max_range), got {camera!r}"
                )
            camera.check(f"eval.shield.cameras[{i}]")


@dataclass
class EvalConfig:
    """How a policy is evaluated (``python -m diana_lab.evaluate`` and the training runner's evaluations)."""

    episodes: int = 100  # episodes in the suite
    seed: int = 12345  # the suite's own seed (starts, goals, headings and per-episode noise seeds)
    min_distance: float = 8.0  # start-goal straight-line distance range (m)
    max_distance: float = 30.0
    # m/s: a successful episode slower than this (goal-directed: straight-line distance over time) counts in the
    # summary's slow_successes; the paper's minimum, a quarter of its rover's 0.33 m/s cruise
    min_goal_speed: float = 0.083
    every: int = 10000  # training steps between periodic evaluations (the runner); 0 disables them
    deterministic: bool = True  # RL policies act with their mean/mode action
    dynamics: str | None = None  # None: the same dynamics as training; else "kinematic" or "physics"
    sensor_noise: list[float] = field(default_factory=list)  # noise levels to sweep; []: the configured sensor
    video: bool = True  # a GIF of the first episode
    plots: bool = True  # trajectory and tilt plots
    shield: ShieldConfig = field(default_factory=ShieldConfig)  # a slope check on learnt discrete policies

    def __post_init__(self) -> None:
        positive_int("eval.episodes", self.episodes)
        check_seed("eval.seed", self.seed)
        non_negative_int("eval.every", self.every, "0 disables")
        non_negative("eval.min_distance", self.min_distance)
        ordered("eval.min_distance", self.min_distance, "eval.max_distance", self.max_distance)
        non_negative("eval.min_goal_speed", self.min_goal_speed)
        if self.dynamics is not None:
            one_of("eval.dynamics", self.dynamics, DYNAMICS_OPTIONS)
        for i, level in enumerate(self.sensor_noise):
            non_negative(f"eval.sensor_noise[{i}]", level)


register("eval", {"eval": EvalConfig})
