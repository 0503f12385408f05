"""Policies the evaluation can run: two classical baselines and a wrapper around Stable-Baselines3 models.

Every policy turns an observation into the env's normalised action; the baselines read what a classical
stack would know instead (the pose estimate and the goal; the oracle also the whole cost map) and express
their waypoint through ``env.mapping.action_for``, so they drive through exactly the same action space,
controller and dynamics as the learnt policies.

* :class:`StraightLine` -- a blind position controller: the next waypoint lies on the straight line to the
  goal, as far as the action space reaches. It collides with, tips over on or gets stuck at whatever lies
  in between; its success rate is how much of the suite needs no perception at all.
* :class:`AStarOracle` -- knows the map: plans the hazard-weighted least-cost path on the planner's
  traversability cost map at reset and hands its waypoints out one by one (re-planning from the rover's
  pose when the rover is not where the plan expects it). Its success rate is the suite's practical ceiling.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from diana_lab.planning import CostMap, CostMapConfig, build_costmap, plan, simplify

__all__ = ["AStarOracle", "Policy", "SB3Policy", "StraightLine", "waypoint_action"]


@runtime_checkable
class Policy(Protocol):
    """What :func:`~diana_lab.evaluation.runner.run_suite` drives: called once per episode, then per step."""

    def reset(self, env: gym.Env) -> None: ...

    def act(self, obs: Any, env: gym.Env) -> np.ndarray: ...


def waypoint_action(env: gym.Env, target: np.ndarray) -> np.ndarray:
    """The action that sends the rover towards world point ``target``, shortened to the action space's reach.

    The offset is scaled down to the action space's extent along its own direction (the disc inscribed in
    the square, or the circle) before :meth:`WaypointMapping.action_for`, which would otherwise clip each
    axis of a square separately and bend the heading.
    """
    base = env.unwrapped
    est = base.pose_estimate
    offset = np.asarray(target, dtype=np.float64)[:2] - est.xy
    norm = float(np.hypot(*offset))
    reach = base.mapping.extent * (1.0 - 1e-6)
    if norm > reach:
        offset = offset * (reach / norm)
    return base.mapping.action_for(offset, est.yaw).astype(np.float32)


class StraightLine:
    """Waypoints along the straight line to the goal, each as far as the action space reaches."""

    name = "straight"

    def reset(self, env: gym.Env) -> None:
        pass

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        return waypoint_action(env, env.unwrapped.goal)


class AStarOracle:
    """Follows the least-cost path over the traversability cost map (see the module docstring).

    Args:
        costmap: the map to plan on; ``None`` uses ``env.sampler.costmap`` (the one that guarantees every
            suite episode is solvable), or one built with ``costmap_cfg`` when that is given.
        costmap_cfg: a :class:`CostMapConfig` for a stricter private map (e.g. a safety margin).
        spacing: the longest waypoint step as a fraction of the action space's extent; below 1 so that
            the waypoint stays inside the action space whatever the rover's heading.
        replan_distance: re-plan when the rover ends a step farther than this from the waypoint it was
            sent to (the controller stops within its position tolerance, so a reached waypoint is closer).
    """

    name = "astar"

    def __init__(self, costmap: CostMap | None = None, costmap_cfg: CostMapConfig | None = None,
                 spacing: float = 0.95, replan_distance: float = 0.5, snap: float = 1.5) -> None:
        if not 0.0 < spacing <= 1.0:
            raise ValueError(f"AStarOracle.spacing: expected a fraction in (0, 1], got {spacing!r}")
        self._costmap, self.costmap_cfg = costmap, costmap_cfg
        self.spacing, self.replan_distance, self.snap = spacing, replan_distance, snap
        self._maps: dict[int, CostMap] = {}
        self.waypoints = np.zeros((0, 2))
        self.replans = 0
        self._next = 0
        self._sent: np.ndarray | None = None

    def costmap(self, env: gym.Env) -> CostMap:
        if self._costmap is not None:
            return self._costmap
        base = env.unwrapped
        if self.costmap_cfg is None:
            return base.sampler.costmap
        key = id(base.world)
        if key not in self._maps:
            self._maps[key] = build_costmap(base.world, base.robot, self.costmap_cfg)
        return self._maps[key]

    def _plan(self, env: gym.Env, start: np.ndarray) -> None:
        base = env.unwrapped
        path = plan(self.costmap(env), start, base.goal, weighted=True, snap=self.snap)
        if path is None:  # no path from here (e.g. pushed off the map): fall back to the straight line
            self.waypoints = np.asarray(base.goal, dtype=np.float64)[None, :]
        else:
            self.waypoints = simplify(path, self.spacing * base.mapping.extent)
        self._next, self._sent = 0, None

    def reset(self, env: gym.Env) -> None:
        self.replans = 0
        self._plan(env, env.unwrapped.pose_estimate.xy)

    def act(self, obs: Any, env: gym.Env) -> np.ndarray:
        xy = env.unwrapped.pose_estimate.xy
        if self._sent is not None:
            if math.dist(xy, self._sent) > self.replan_distance:
                self.replans += 1
                self._plan(env, xy)
            else:
                self._next = min(self._next + 1, len(self.waypoints) - 1)
        target = self.waypoints[self._next]
        self._sent = target
        return waypoint_action(env, target)


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
        return np.asarray(action, dtype=np.float32).reshape(-1)
