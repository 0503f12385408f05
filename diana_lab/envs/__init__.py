"""The navigation environment and its parts (action spaces, rewards, episodes, rendering).

:class:`ActionError` lives here, free of imports, so that ``from diana_lab.envs import ActionError`` (or
``from diana_lab import ActionError``) costs nothing and needs no gymnasium.
"""

ENV_ID = "diana_lab/RoverNav-v0"


class ActionError(ValueError):
    """An action the env cannot execute (wrong shape, NaN or infinite values, a candidate index out of range)."""


__all__ = ["ENV_ID", "ActionError"]
