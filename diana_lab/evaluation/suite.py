"""The evaluation suite: a fixed list of episodes drawn from the suite's own seed.

Drawing through the env's :class:`~diana_lab.envs.episodes.EpisodeSampler` keeps the guarantee that start and
goal share a traversable region (every episode is solvable), while the generator is the suite's own
``np.random.default_rng(seed)``: the same seed gives the same episodes for every policy, every process and
every periodic evaluation, whatever training has drawn so far. Each episode also carries a seed for the env's
reset, so pose and sensor noise are the same for every policy too.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

__all__ = ["EpisodeSpec", "make_suite"]


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode of the suite: start ``(x, y)``, initial heading (rad), goal ``(x, y)``, reset seed."""

    start: np.ndarray
    yaw: float
    goal: np.ndarray
    seed: int = 0

    def reset_options(self) -> dict:
        return {"start": self.start.copy(), "goal": self.goal.copy(), "yaw": float(self.yaw)}


def make_suite(env: gym.Env, n: int, seed: int, min_distance: float, max_distance: float) -> list[EpisodeSpec]:
    """``n`` episodes with start-goal distances in ``[min_distance, max_distance]`` (see the module docstring).

    The sampler's curriculum counter is restored afterwards, so building a suite inside a training process
    does not change the training episodes' distances.
    """
    sampler = env.unwrapped.sampler
    rng = np.random.default_rng(seed)
    drawn = sampler.episodes_drawn
    try:
        episodes = [sampler.sample(rng, min_distance, max_distance) for _ in range(n)]
    finally:
        sampler.episodes_drawn = drawn
    seeds = rng.integers(0, 2**31 - 1, size=n)
    return [EpisodeSpec(np.asarray(ep.start, dtype=np.float64), float(ep.yaw), np.asarray(ep.goal, dtype=np.float64),
                        int(s)) for ep, s in zip(episodes, seeds)]
