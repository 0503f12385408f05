"""diana_lab: a Hydra-configured platform to train and test RL navigation of planetary rovers.

Importing the package registers the gymnasium env ``diana_lab/RoverNav-v0`` (and nothing heavy: torch,
PyBullet and open3d are imported only by the modules that use them).
"""

from gymnasium.envs.registration import register as _register

from diana_lab.envs import ENV_ID

__version__ = "0.1.0"

_register(id=ENV_ID, entry_point="diana_lab.envs.rover_nav:RoverNavEnv")

__all__ = ["ENV_ID", "__version__"]
