"""Small envs for the evaluation tests: a 20 m flat world, and the same with a wall of rocks across it."""

from __future__ import annotations

import numpy as np
import pytest

from diana_lab.config import build, compose, to_object
from diana_lab.envs.rover_nav import RoverNavEnv
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import World
from diana_lab.sim.worlds import _rock
from tests.presets import CAMERA_SQUARE

SMALL_FLAT = [*CAMERA_SQUARE, "world=flat", "world.size_x=20", "world.size_y=20"]


def small_env(*overrides: str) -> RoverNavEnv:
    return RoverNavEnv(config=compose([*SMALL_FLAT, *overrides]))


@pytest.fixture(scope="module")
def flat_env():
    env = small_env()
    yield env
    env.close()


def wall_world(size: float = 20.0, half_length: float = 5.0) -> World:
    """Flat ground with a row of 0.6 m rocks along x = 0 from y = -half_length to +half_length."""
    rng = np.random.default_rng(7)
    n = round(size / 0.25) + 1
    terrain = Terrain(np.zeros((n, n)), size, size)
    rocks = [
        _rock(rng, np.array([0.0, y]), 0.6, 0.0, f"rock_{i}")
        for i, y in enumerate(np.arange(-half_length, half_length + 1e-9, 0.4))
    ]
    return World("wall", terrain, rocks)


@pytest.fixture(scope="module")
def wall_env():
    world = wall_world()
    cfg = compose(SMALL_FLAT)
    env = RoverNavEnv(config=cfg, world_instance=world)
    yield env
    env.close()


@pytest.fixture(scope="module")
def flat_world_small():
    return build(to_object("world", compose(SMALL_FLAT).world))
