"""The evaluation suite: a fixed list of episodes drawn from the suite's own seed.

Drawing through the env's :class:`~diana_lab.envs.episodes.EpisodeSampler` keeps the guarantee that start and
goal share a traversable region, while the generator is the suite's own ``np.random.default_rng(seed)``: the
same seed gives the same episodes for every policy, every process and every periodic evaluation, whatever
training has drawn so far. Each episode also carries a seed for the env's reset, so pose and sensor noise
are the same for every policy too.

Goals the env cannot reach are redrawn: the sampler admits goals up to ``robot.radius`` from the map edge
(the cost map's border band), but the env clamps waypoints ``robot.radius + episode.map_margin`` inside the
map and the controller stops ``position_tolerance`` short of them, so a goal within about
``map_margin - goal_tolerance + position_tolerance`` of that band can never be reached. A suite only
measures policies on episodes that some policy could solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from diana_lab.core.validation import ConfigError

__all__ = ["EpisodeSpec", "make_suite", "reachable_goal"]

MAX_REDRAWS = 20  # per episode, before the world is declared unsuitable


@dataclass(frozen=True, eq=False)
class EpisodeSpec:
    """One episode of the suite: start ``(x, y)``, initial heading (rad), goal ``(x, y)``, reset seed."""

    start: np.ndarray
    yaw: float
    goal: np.ndarray
    seed: int = 0

    def __eq__(self, other: object) -> bool:  # arrays compare element-wise: the dataclass default would raise
        if not isinstance(other, EpisodeSpec):
            return NotImplemented
        return (
            np.array_equal(self.start, other.start)
            and np.array_equal(self.goal, other.goal)
            and self.yaw == other.yaw
            and self.seed == other.seed
        )

    __hash__ = None  # type: ignore[assignment]  (mutable arrays inside)

    def reset_options(self) -> dict:
        return {"start": self.start.copy(), "goal": self.goal.copy(), "yaw": float(self.yaw)}


def reachable_goal(env: gym.Env, goal: np.ndarray) -> bool:
    """Whether the goal lies inside the region the env lets waypoints reach (see the module docstring)."""
    base = env.unwrapped
    margin = base.robot.radius + base.episode_cfg.map_margin
    x0, x1, y0, y1 = base.world.bounds
    return bool(x0 + margin <= goal[0] <= x1 - margin and y0 + margin <= goal[1] <= y1 - margin)


def make_suite(env: gym.Env, n: int, seed: int, min_distance: float, max_distance: float) -> list[EpisodeSpec]:
    """``n`` episodes, start-goal distances in ``[min_distance, max_distance]`` (see the module docstring).

    The sampler's curriculum counter is restored afterwards, so building a suite inside a training process
    does not change the training episodes' distances.
    """
    sampler = env.unwrapped.sampler
    rng = np.random.default_rng(seed)
    drawn = sampler.episodes_drawn
    episodes = []
    try:
        for _ in range(n):
            for _ in range(MAX_REDRAWS):
                ep = sampler.sample(rng, min_distance, max_distance, keys="eval")
                if reachable_goal(env, ep.goal):
                    break
            else:
                raise ConfigError(
                    f"eval: no reachable goal {min_distance}..{max_distance} m from the start after "
                    f"{MAX_REDRAWS} draws (goals must lie inside episode.map_margin of the edge)"
                )
            episodes.append(ep)
    finally:
        sampler.episodes_drawn = drawn
    seeds = rng.integers(0, 2**31 - 1, size=n)
    return [
        EpisodeSpec(
            np.asarray(ep.start, dtype=np.float64),
            float(ep.yaw),
            np.asarray(ep.goal, dtype=np.float64),
            int(s),
        )
        for ep, s in zip(episodes, seeds)
    ]
