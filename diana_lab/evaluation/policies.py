"""Policies the evaluation can run: two classical baselines and a wrapper around Stable-Baselines3 models.

Every policy turns an observation into the env's action (a normalised point, or a candidate index with
``action_space=discrete``); the baselines read what a classical stack would know instead (the pose estimate
and the goal; the oracle also the whole cost map) and express their waypoint through
``env.mapping.action_for``, so they drive through exactly the same action space, controller and dynamics as
the learnt policies.

* :class:`StraightLine` -- a blind position controller: the next waypoint lies on the straight line to the
  goal, as far as the action space reaches. It collides with, tips over on or gets stuck at whatever lies
  in between; its success rate is how much of the suite needs no perception at all.
* :class:`~diana_lab.evaluation.oracle.AStarOracle` (in :mod:`diana_lab.evaluation.oracle`) -- knows the
  map: plans over the traversability cost map and hands out the path's waypoints. Its success rate is the
  suite's practical ceiling.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

__all__ = ["Policy", "SB3Policy", "StraightLine", "waypoint_action"]


@runtime_checkable
class Policy(Protocol):
    """What :func:`~diana_lab.evaluation.runner.run_suite` drives: called once per episode, then per step."""

    def reset(self, env: gym.Env) -> None: ...

    def act(self, obs: Any, env: gym.Env) -> np.ndarray: ...


def waypoint_action(env: gym.Env, target: np.ndarray) -> np.ndarray:
    """The action that sends the rover towards world point ``target``, shortened to the action space's reach.

    The offset is scaled down to the action space's extent along its own direction (the disc inscribed in
    the square, the circle, or the farthest candidate) before :meth:`WaypointMapping.action_for`, which would
    otherwise clip each axis of a square separately and bend the heading. Continuous: a float32 ``(2,)``
    array; discrete: the nearest candidate's index, an int64 array of shape ``()`` (what ``Discrete`` holds).
    """
    base = env.unwrapped
    est = base.pose_estimate
    offset = np.asarray(target, dtype=np.float64)[:2] - est.xy
    norm = float(np.hypot(*offset))
    reach = base.mapping.extent * (1.0 - 1e-6)
    if norm > reach:
        offset = offset * (reach / norm)
    action = base.mapping.action_for(offset, est.yaw)
    return action if base.mapping.discrete else action.astype(np.float32)


class StraightLine:
    """Waypoints along the straight line to the goal, each as far as the action space reaches."""

    name = "straight"

    def reset(self, env: gym.Env) -> None:
        pass

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        return waypoint_action(env, env.unwrapped.goal)


class SB3Policy:
    """A Stable-Baselines3 model as a :class:`Policy`.

    ``vecnormalize`` is the training run's saved ``VecNormalize`` (unpickled; no env needed): its observation
    statistics are applied before ``model.predict``, since the network only ever saw normalised inputs.
    Stochastic evaluation (``deterministic=False``) seeds torch per episode from ``seed``, so it repeats.
    """

    name = "sb3"

    def __init__(self, model: Any, vecnormalize: Any = None, deterministic: bool = True, seed: int = 0) -> None:
        self.model, self.vecnormalize = model, vecnormalize
        self.deterministic, self.seed = deterministic, seed
        self.discrete = isinstance(getattr(model, "action_space", None), gym.spaces.Discrete)
        self._episodes = 0

    def reset(self, env: gym.Env) -> None:
        if not self.deterministic:
            import torch

            torch.manual_seed(self.seed + self._episodes)
        self._episodes += 1

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        if self.vecnormalize is not None and getattr(self.vecnormalize, "norm_obs", False):
            obs = self.vecnormalize.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=self.deterministic)
        if self.discrete:
            return np.asarray(action, dtype=np.int64).reshape(())  # a candidate index, never a float
        return np.asarray(action, dtype=np.float32).reshape(-1)
