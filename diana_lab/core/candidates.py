"""The candidate waypoints of a discrete action space (numpy only: the env, the exporter and the onboard
runtime share them)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["candidate_offsets", "turned"]


def candidate_offsets(headings: int, distances: Sequence[float]) -> np.ndarray:
    """The ``(headings * len(distances), 2)`` candidate offsets of a discrete action space, in the action frame.

    Heading-major: row ``k`` lies at bearing ``2 pi (k // len(distances)) / headings`` (counter-clockwise from
    +x, so the first is straight ahead in the rover frame) and distance ``distances[k % len(distances)]``.
    """
    bearings = 2.0 * np.pi * np.arange(headings) / headings
    d = np.asarray(distances, dtype=np.float64)
    return np.stack([np.cos(bearings)[:, None] * d, np.sin(bearings)[:, None] * d], axis=-1).reshape(-1, 2)


def turned(table: np.ndarray, yaw: float) -> np.ndarray:
    """Offsets ``(n, 2)`` turned by ``yaw`` (the rover frame's offsets in the world frame)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.stack([c * table[:, 0] - s * table[:, 1], s * table[:, 0] + c * table[:, 1]], axis=-1)
