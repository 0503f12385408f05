"""Many rovers as arrays, stepped by compiled calls: the batched simulator behind ``train.vec_env=batched``.

:class:`BatchedRoverEnv` is a Stable-Baselines3 ``VecEnv``; :mod:`~diana_lab.envs.batched.kinematics`,
:mod:`~diana_lab.envs.batched.sensing`, :mod:`~diana_lab.envs.batched.rewards` and
:mod:`~diana_lab.envs.batched.geometry` hold its compiled parts. ``RoverNavEnv(dynamics="kinematic")`` is the
reference it is held to.
"""

import os

import numba

# numba's own thread pool: no TBB to look for (and warn about), no second OpenMP runtime beside torch's; a user's
# NUMBA_THREADING_LAYER still wins
if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"

from diana_lab.envs.batched.vec_env import BatchedRoverEnv

__all__ = ["BatchedRoverEnv"]
