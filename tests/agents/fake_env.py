"""A world-free stand-in for RoverNav: the same Dict observation layout and action space, random content.

Lets the policy and factory tests build every algorithm in milliseconds, without terrain or ray casting.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

SENSOR_SPACES = {
    "depth_image": spaces.Box(0.0, 1.0, (1, 12, 16), np.float32),
    "elevation_map": spaces.Box(0.0, 1.0, (2, 20, 16), np.float32),
    "points": spaces.Box(
        np.tile(np.array([-1, -1, -1, 0], np.float32), (64, 1)),
        np.ones((64, 4), np.float32),
        dtype=np.float32,
    ),
}


class FakeRoverEnv(gym.Env):
    """``candidates``: a ``Discrete`` action space of that many waypoints (``action_space=discrete``), whose
    action 0 plays the part of a positive first action component."""

    def __init__(self, sensor_key: str = "depth_image", episode_steps: int = 8, candidates: int | None = None) -> None:
        self.observation_space = spaces.Dict(
            {
                "goal": spaces.Box(
                    np.array([0, -1, -1, -1, -1, -1, -1], np.float32),
                    np.ones(7, np.float32) * 2,
                    dtype=np.float32,
                ),
                sensor_key: SENSOR_SPACES[sensor_key],
            }
        )
        self.action_space = (
            spaces.Box(-1.0, 1.0, (2,), np.float32) if candidates is None else spaces.Discrete(candidates)
        )
        self.episode_steps, self._t = episode_steps, 0

    def _obs(self) -> dict:
        return {k: s.sample() for k, s in self.observation_space.spaces.items()}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.observation_space.seed(seed)
        self._t = 0
        return self._obs(), {}

    def step(self, action):
        self._t += 1
        done = self._t >= self.episode_steps
        progress = float(action[0]) if isinstance(self.action_space, spaces.Box) else 1.0 - 2.0 * (int(action) != 0)
        success = progress > 0
        info = {"reward_terms": {"progress": progress, "step": -0.05}}
        if done:
            info.update(outcome="success" if success else "timeout", is_success=success)
        return self._obs(), progress - 0.05, done and success, done and not success, info
