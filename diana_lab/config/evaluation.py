"""Config schema of the ``eval`` node: the fixed evaluation suite, its conditions and its outputs.

The suite is drawn from its own generator (``eval.seed``), never from training's, so every policy and every
periodic evaluation of one run meets exactly the same episodes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from diana_lab.config.store import register
from diana_lab.config.validation import ConfigError, non_negative, one_of, ordered

DYNAMICS_OPTIONS = ("kinematic", "physics")


@dataclass
class EvalConfig:
    """How a policy is evaluated (``python -m diana_lab.evaluate`` and the training runner's evaluations)."""

    episodes: int = 100  # episodes in the suite
    seed: int = 12345  # the suite's own seed (starts, goals, headings and per-episode noise seeds)
    min_distance: float = 8.0  # start-goal straight-line distance range (m)
    max_distance: float = 30.0
    every: int = 10000  # training steps between periodic evaluations (the runner); 0 disables them
    deterministic: bool = True  # RL policies act with their mean/mode action
    dynamics: str | None = None  # None: the same dynamics as training; else "kinematic" or "physics"
    sensor_noise: list[float] = field(default_factory=list)  # noise levels to sweep; []: the configured sensor
    video: bool = True  # a GIF of the first episode
    plots: bool = True  # trajectory and tilt plots

    def __post_init__(self) -> None:
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes <= 0:
            raise ConfigError(f"eval.episodes: expected a positive integer, got {self.episodes!r}")
        if isinstance(self.every, bool) or not isinstance(self.every, int) or self.every < 0:
            raise ConfigError(f"eval.every: expected an integer >= 0 (0 disables), got {self.every!r}")
        non_negative("eval.min_distance", self.min_distance)
        ordered("eval.min_distance", self.min_distance, "eval.max_distance", self.max_distance)
        if self.dynamics is not None:
            one_of("eval.dynamics", self.dynamics, DYNAMICS_OPTIONS)
        for i, level in enumerate(self.sensor_noise):
            non_negative(f"eval.sensor_noise[{i}]", level)


register("eval", {"eval": EvalConfig})
