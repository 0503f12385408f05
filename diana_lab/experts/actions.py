"""An action that drives towards a world point: how the planner experts and the blind baselines speak the env's
action space."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

__all__ = ["waypoint_action"]


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
