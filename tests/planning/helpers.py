"""Small worlds and geometry helpers shared by the planning tests."""

from __future__ import annotations

import itertools

import numpy as np

from diana_lab.sim.terrain import Terrain
from diana_lab.sim.world import Obstacle, World


def box(x0: float, x1: float, y0: float, y1: float, height: float, name: str = "box") -> Obstacle:
    """A closed axis-aligned box standing on z = 0."""
    v = np.array([[x, y, z] for z in (0.0, height) for y in (y0, y1) for x in (x0, x1)], dtype=float)
    t = [
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ]
    return Obstacle(v, np.array(t), name=name)


def flat_world(size: float = 20.0, spacing: float = 0.2, obstacles: list[Obstacle] | None = None) -> World:
    n = round(size / spacing) + 1
    return World("flat", Terrain(np.zeros((n, n)), size, size), obstacles or [])


def ramp_world(slope_deg: float, size: float = 20.0, spacing: float = 0.2) -> World:
    n = round(size / spacing) + 1
    x = -size / 2 + np.arange(n) * spacing
    return World("ramp", Terrain(np.tile(np.tan(np.radians(slope_deg)) * x, (n, 1)), size, size))


def dense(points: np.ndarray, step: float = 0.02) -> np.ndarray:
    """Points every ``step`` metres along a polyline."""
    out = [points[:1]]
    for p, q in itertools.pairwise(points):
        n = max(1, int(np.ceil(np.hypot(*(q - p)) / step)))
        out.append(p + (q - p) * (np.arange(1, n + 1) / n)[:, None])
    return np.vstack(out)
