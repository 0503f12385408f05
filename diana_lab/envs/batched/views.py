"""One rover of the batch seen as a scalar env, for code written against ``RoverNavEnv`` (the DAgger experts).

The planner experts of :mod:`diana_lab.experts.oracle` read a scalar env's ``unwrapped`` parts: the pose
estimate, the goal, the world, the robot, the episode sampler's cost map, the action mapping, the true state and
(``astar_seen``) the sensor's memory map. A :class:`RoverView` gives them the rover's row of the batch's arrays
under those names, without copying the map: what the expert reads is what the rover's observation was built from.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from diana_lab.core.height_memory import HeightMemory
from diana_lab.sim.pose import PoseEstimate
from diana_lab.sim.state import RoverState

if TYPE_CHECKING:
    from diana_lab.envs.batched.vec_env import BatchedRoverEnv

__all__ = ["RoverView"]


class _Dynamics:
    def __init__(self, view: RoverView) -> None:
        self._view = view

    @property
    def state(self) -> RoverState:
        s = self._view.batch.state[self._view.index]
        return RoverState(s[:3].copy(), s[3:6].copy(), time=float(s[6]))


class _Encoder:
    def __init__(self, memory: HeightMemory | None) -> None:
        self.memory = memory


class _Sensor:
    def __init__(self, memory: HeightMemory | None) -> None:
        self.encoder = _Encoder(memory)


class _MemoryView(HeightMemory):
    """A :class:`HeightMemory` whose cells are rover ``index``'s row of the batch's memory array."""

    def __init__(self, batch: BatchedRoverEnv, index: int) -> None:  # no super().__init__: it would allocate a map
        part = batch.parts[batch.world_of[index]]
        m = part.env.cfg["sensor"].elevation_map
        self.cell_size, self.radius = float(m.cell_size), float(m.memory_radius)
        self.height = part.sensor.memory[index]  # a view: the batch writes, the expert reads
        self.n = round(len(self.height) ** 0.5)
        self.mean_height, self.last_world, self.shape = None, None, m.shape
        self._sensor, self._index = part.sensor, index

    @property  # type: ignore[override]
    def origin(self) -> np.ndarray | None:
        s, i = self._sensor, self._index
        return s.mem_origin[i].copy() if s.mem_set[i] else None


class RoverView:
    """Rover ``index`` of ``batch`` with the attributes of a ``RoverNavEnv`` the experts read (read-only)."""

    def __init__(self, batch: BatchedRoverEnv, index: int) -> None:
        self.batch, self.index = batch, index
        part = batch.parts[batch.world_of[index]]
        env = part.env
        self.world, self.robot, self.sampler, self.mapping = env.world, env.robot, env.sampler, env.mapping
        self.action_space, self.observation_space = env.action_space, env.observation_space
        self.episode_cfg, self.cfg = env.episode_cfg, env.cfg
        self.dynamics = _Dynamics(self)
        memory = _MemoryView(batch, index) if part.sensor.memory is not None else None
        self.sensor = _Sensor(memory)

    @property
    def unwrapped(self) -> RoverView:
        return self

    @property
    def goal(self) -> np.ndarray:
        return self.batch.goal[self.index].copy()

    @property
    def pose_estimate(self) -> PoseEstimate:
        x, y, yaw, roll, pitch = self.batch.est[self.index].tolist()
        return PoseEstimate(np.array([x, y]), yaw, roll, pitch)
