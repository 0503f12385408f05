"""The navigation environment and its parts (action spaces, rewards, episodes, rendering).

:class:`ActionError` and :data:`GOAL_KEYS` live here, free of imports, so that
``from diana_lab.envs import ActionError`` (or ``from diana_lab import ActionError``) costs nothing and needs
no gymnasium, and the deploy runtime can read the goal layout without the simulator.
"""

ENV_ID = "diana_lab/RoverNav-v0"

# The order of the observation's "goal" vector. The env builds it, the deploy runtime rebuilds it on the
# rover from a raw pose and goal, and rule-based policies read it by name: one definition for all three.
GOAL_KEYS = ("distance", "sin_heading_error", "cos_heading_error", "roll", "pitch", "sin_yaw", "cos_yaw")


class ActionError(ValueError):
    """An action the env cannot execute (wrong shape, NaN or infinite values, a candidate index out of range)."""


__all__ = ["ENV_ID", "GOAL_KEYS", "ActionError"]
