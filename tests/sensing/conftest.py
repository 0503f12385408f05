"""Small worlds with known geometry, and sensors built from the real ``conf/sensor`` options."""

from __future__ import annotations

import dataclasses
from functools import cache

import numpy as np
import pytest

from diana_lab.config import build, to_object
from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import Obstacle, World


@cache
def _sensor_config(option: str):
    return to_object("sensor", option)


def make_sensor(option: str, world: World, **overrides):
    """The ``conf/sensor/<option>.yaml`` sensor with some keys replaced (checks re-run)."""
    return build(dataclasses.replace(_sensor_config(option), **overrides), world)


def plane_world(height: float = 0.0, size: float = 60.0, obstacles: list[Obstacle] | None = None) -> World:
    return World("plane", Terrain(np.full((31, 31), height), size, size), obstacles or [])


def box(lo: tuple[float, float, float], hi: tuple[float, float, float], name: str = "box") -> Obstacle:
    """A closed axis-aligned box mesh (8 vertices, 12 outward-facing triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
    t = [
        (0, 2, 1),
        (1, 2, 3),
        (4, 5, 6),
        (5, 7, 6),
        (0, 1, 4),
        (1, 5, 4),
        (2, 6, 3),
        (3, 6, 7),
        (0, 4, 2),
        (2, 4, 6),
        (1, 3, 5),
        (3, 7, 5),
    ]
    return Obstacle(np.array(v, dtype=float), np.array(t), name=name)


@pytest.fixture(scope="module")
def flat_plane():
    return plane_world(0.0)
