"""``policy=astar_seen``: the ``astar_memory`` oracle knowing only the ground the rover's own sensor has mapped.

Why it exists: the other oracles plan over cost maps of the *true* terrain and only limit *where* they know it
(``astar_memory``: within 12 m of every pose of the episode). A policy knows less: only the cells its sensor
returned. ``astar_seen`` plans on the true cost maps but knows only the cells the policy's memory map has hit, so
its choices depend only on where that map has data: a baseline of what that knowledge allows, and the DAgger expert
whose labels such a policy can learn (``train.imitation.expert=astar_seen``). Needs ``sensor.encoding=elevation_map``
with ``sensor.elevation_map.memory=true`` (e.g. ``+experiment=reference``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from diana_lab.config import ConfigError
from diana_lab.core.height_memory import HeightMemory
from diana_lab.experts.oracle import AStarOracle
from diana_lab.planning import CostMap

__all__ = ["SeenMapOracle", "check_perceivable", "sensor_hit"]


def check_perceivable(cfg, who: str = "policy=astar_seen") -> None:
    """Raise a :class:`ConfigError` naming the keys unless the sensor config (``cfg["sensor"]``, a config or a
    dict) keeps a memory map; ``who`` is the setting that needs it."""
    sensor = cfg.get("sensor", {}) if hasattr(cfg, "get") else {}
    encoding = sensor.get("encoding")
    memory = (sensor.get("elevation_map") or {}).get("memory")
    if encoding != "elevation_map" or not memory:
        raise ConfigError(
            f"{who} plans on what the rover's sensor mapped: it needs "
            f"sensor.encoding=elevation_map (got {encoding!r}) and sensor.elevation_map.memory=true (got "
            f"{memory!r}), e.g. +experiment=reference"
        )


def _memory(env: gym.Env, who: str) -> HeightMemory:
    memory = getattr(getattr(env.unwrapped.sensor, "encoder", None), "memory", None)
    if memory is None:
        raise ConfigError(
            f"{who}: the env's sensor keeps no map (sensor.encoding=elevation_map with "
            "sensor.elevation_map.memory=true is needed)"
        )
    return memory


def sensor_hit(memory: HeightMemory, grid: CostMap) -> np.ndarray:
    """``grid.shape`` bool: the cells whose centre lies in a memory cell the sensor has hit."""
    ny, nx = grid.shape
    if memory.origin is None:
        return np.zeros((ny, nx), dtype=bool)
    cx, cy = grid.cell_to_world(np.arange(nx), np.arange(ny))
    # perceived_heights' test, by rows and columns (the cells are a product grid): 1 ms, not 10, a step
    n = memory.n
    ix = np.floor((cx - memory.origin[0]) / memory.cell_size).astype(np.int64)
    iy = np.floor((cy - memory.origin[1]) / memory.cell_size).astype(np.int64)
    in_x, in_y = (ix >= 0) & (ix < n), (iy >= 0) & (iy < n)
    known = np.isfinite(memory.height.reshape(n, n))[np.clip(iy, 0, n - 1)[:, None], np.clip(ix, 0, n - 1)[None, :]]
    return known & in_y[:, None] & in_x[None, :]


class SeenMapOracle(AStarOracle):
    """``astar_memory``'s planner on the *true* cost maps, knowing only the cells the rover's sensor has hit.

    It knows exactly the ground the policy's map holds (``astar_memory``'s 12 m horizon, and the sensor hit the
    cell), with the true heights; unknown cells cost the least, as for every knowledge-limited oracle. Fast: one
    mask per step on top of ``astar_memory``.
    """

    name = "astar_seen"

    def __init__(self, knowledge_radius: float = 12.0, spacing: float = 0.8) -> None:
        super().__init__(spacing=spacing, knowledge_radius=knowledge_radius, knowledge_memory=True)

    def knowledge(self, env: gym.Env, grid: CostMap) -> np.ndarray | None:
        hit = sensor_hit(_memory(env, "astar_seen"), grid)
        horizon = super().knowledge(env, grid)
        return hit if horizon is None else horizon & hit
