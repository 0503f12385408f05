"""diana_lab: a Hydra-configured platform to train and test RL navigation of planetary rovers.

Importing the package registers the gymnasium env ``diana_lab/RoverNav-v0`` when gymnasium is installed, and
nothing heavy: torch, PyBullet and open3d are imported only by the modules that use them. Without gymnasium
(a rover computer running only :mod:`diana_lab.deploy` with numpy and onnxruntime) the package still imports.
"""

from diana_lab.envs import ENV_ID, ActionError

__version__ = "0.1.0"

try:
    from gymnasium.envs.registration import register as _register
except ImportError:  # pragma: no cover - deployment installs without gymnasium
    pass
else:
    _register(id=ENV_ID, entry_point="diana_lab.envs.rover_nav:RoverNavEnv")

__all__ = ["ENV_ID", "ActionError", "__version__"]
