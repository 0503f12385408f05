"""``policy=astar_perceived``: the ``astar_memory`` oracle planning on what the rover's own sensor has mapped.

Why it exists: the other oracles plan over cost maps of the *true* terrain and only limit *where* they know
it (``astar_memory``: within 12 m of every pose of the episode). A policy knows less than that: only the
heights its sensor returned, at the resolution of its map. This baseline is the classical stack a learnt
policy should be compared with -- map what the sensor sees, plan on that map -- and it measures what the
observation itself allows: if a planner that trusts the map falls short, no learning on that map will do
better without learning to look first.

Each step it reads the ``elevation_map`` encoding's world-frame memory (:class:`~diana_lab.height_memory.
HeightMemory`: the highest return per cell, fused over the episode), resamples it onto the oracle's cost-map
grid (bilinear between the centres of known cells, else the cell's own height), fills the cells never hit
with the nearest known height (so that the hazard filters see numbers), and builds the very cost maps the
oracle builds from the true terrain (:func:`~diana_lab.planning.costmap.build_costmap`, the wheel-pitch layer
and :func:`~diana_lab.evaluation.oracle.oracle_costmaps`). A cell is known if the sensor hit its memory cell
and it lay within ``knowledge_radius`` of some pose of the episode (``astar_memory``'s horizon); unknown
cells cost the least, as for every knowledge-limited oracle. The sampler's untraversable cells and the world's
obstacle bodies are not used: they come from the truth. World bounds come from the world's size, which a rover
would know. So a rock narrower than the map's cells, which the map smooths into a gentle bump, can be driven
into: that is the map's limit, and what this baseline is for. (Banning the cells around every seen step
higher than the robot can climb, as the oracle bans obstacle bodies, was tried: on the Mars yard it banned
slopes too, 0.57 success against 0.74 on the 100-episode suite, and it did not keep the rover off smoothed
rocks.)

Slow (each step rebuilds the cost maps of the whole world: ~0.2 s on the Mars yard). Needs
``sensor.encoding=elevation_map`` with ``sensor.elevation_map.memory=true`` (e.g. ``+experiment=reference``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from scipy import ndimage as ndi

from diana_lab.config import ConfigError
from diana_lab.evaluation.oracle import AStarOracle, oracle_costmaps, wheel_pitch_deg
from diana_lab.height_memory import HeightMemory
from diana_lab.planning import CostMap
from diana_lab.planning.costmap import build_costmap
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World

__all__ = ["PerceivedMapOracle", "SeenMapOracle", "check_perceivable", "perceived_heights", "sensor_hit"]


def check_perceivable(cfg, who: str = "policy=astar_perceived") -> None:
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


def perceived_heights(memory: HeightMemory, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The memory's heights at world points ``x, y`` and whether each point's cell was hit
    (:meth:`HeightMemory.heights_at`: bilinear between known cell centres, NaN where unknown)."""
    return memory.heights_at(x, y)


class PerceivedMapOracle(AStarOracle):
    """``astar_memory``'s planner (receding, 12 m horizon with memory) on cost maps of the perceived terrain."""

    name = "astar_perceived"

    def __init__(self, knowledge_radius: float = 12.0, spacing: float = 0.8) -> None:
        super().__init__(spacing=spacing, knowledge_radius=knowledge_radius, knowledge_memory=True)
        self.perceived: np.ndarray | None = None  # the last perceived heights on the cost-map grid, NaN unknown
        self._hit: np.ndarray | None = None

    def costmaps(self, env: gym.Env) -> tuple[CostMap, ...]:
        base = env.unwrapped
        memory = _memory(env, "policy=astar_perceived")
        grid, terrain = base.sampler.costmap, base.world.terrain
        ny, nx = grid.shape
        cx, cy = grid.cell_to_world(np.arange(nx), np.arange(ny))
        x, y = np.meshgrid(cx, cy)
        height, hit = perceived_heights(memory, x, y)
        if hit.any():
            _, (iy, ix) = ndi.distance_transform_edt(~hit, return_indices=True)
            filled = height[iy, ix]
        else:  # nothing seen yet: level ground at the rover's height
            filled = np.full(height.shape, float(base.dynamics.state.position[2]))
        world = World(name="perceived", terrain=Terrain(filled, terrain.size_x, terrain.size_y))
        cm = build_costmap(world, base.robot)
        if cm.shape != grid.shape:
            raise ValueError(f"astar_perceived: perceived cost map {cm.shape} != the world's {grid.shape}")
        pitch = wheel_pitch_deg(world, base.robot, cm)
        self.perceived, self._hit = height, hit
        return (*oracle_costmaps(cm, pitch, base.robot.max_slope_deg, self.margin, self.obstacle_margin), cm)

    def knowledge(self, env: gym.Env, grid: CostMap) -> np.ndarray | None:
        horizon = super().knowledge(env, grid)
        return self._hit if horizon is None else horizon & self._hit


class SeenMapOracle(AStarOracle):
    """``astar_memory``'s planner on the *true* cost maps, knowing only the cells the rover's sensor has hit.

    Why: it separates the two things the rover's map lacks. It knows exactly the ground the policy's map
    holds (``astar_memory``'s 12 m horizon, and the sensor hit the cell), but with the true heights, not the
    map's smoothed ones; unknown cells cost the least, as for every knowledge-limited oracle. On the Mars-yard
    suite it keeps ``astar_memory``'s zero tip-overs (0.84 success against 0.92, 100 episodes), so the
    tip-overs of ``astar_perceived`` come from heights the map got wrong, not from ground it never saw. As
    an imitation expert (``train.imitation.expert=astar_seen``) its choices depend only on where the policy's
    map has data. Fast: one mask per step on top of ``astar_memory``.
    """

    name = "astar_seen"

    def __init__(self, knowledge_radius: float = 12.0, spacing: float = 0.8) -> None:
        super().__init__(spacing=spacing, knowledge_radius=knowledge_radius, knowledge_memory=True)

    def knowledge(self, env: gym.Env, grid: CostMap) -> np.ndarray | None:
        hit = sensor_hit(_memory(env, "astar_seen"), grid)
        horizon = super().knowledge(env, grid)
        return hit if horizon is None else horizon & hit
